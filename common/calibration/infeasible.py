"""Why a GA calibration found no feasible string, named by the setting that decides it.

The constraint of eq. 15 (exactly one object per control point) fails for one of four
reasons, each with its own cure:

* **the GA is too small**: strings that see the right count exist in the search ranges
  but are rare, and population × generations strings did not reach one (raise them, or
  narrow the camera ranges);
* **the camera ranges**: only strings close to the configured camera see the right
  count, and random strings of the ranges never do (narrow the ranges);
* **the threshold or size-filter range**: with the configured camera only thresholds
  (or size filters) outside the configured range see the right count (widen it);
* **the frame**: no threshold and no size filter sees the right count (objects out of
  view or touching, clutter, the wrong polarity).

:func:`diagnose` tells them apart by evaluating :data:`SAMPLES` random strings of the
search ranges (seeded: the same answer every time) and by scanning every threshold with
the configured camera, where the size filter that keeps exactly N objects follows from
the blobs' sizes; :func:`infeasible_message` says which, with the numbers that show it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import NDArray

from ovis.common.camera.projection import pixel_footprint_cm2

if TYPE_CHECKING:
    from ovis.common.calibration.ga import GAResult
    from ovis.common.calibration.problem import CalibrationProblem

__all__ = ["SAMPLES", "Diagnosis", "diagnose", "infeasible_message"]

#: Random strings of the search ranges evaluated to tell "rare" from "none".
SAMPLES = 4000
#: Strings evaluated at once (bounds the (strings × blobs) arrays of the fitness).
_CHUNK = 250
#: Threshold modes whose threshold the GA searches (the others compute one level).
_SEARCHED = ("fixed", "adaptive")


class Band(NamedTuple):
    """A run of thresholds (inclusive) that keep exactly N objects, and at its middle
    threshold the size filters (cm²) that do."""

    threshold_lo: int
    threshold_hi: int
    middle: int
    filter_lo: float  # exclusive: a blob of this size is dropped
    filter_hi: float


class Diagnosis(NamedTuple):
    """What the search ranges and the frame allow (see the module docstring)."""

    sampled: int
    feasible_sampled: int
    #: of as many strings with the camera fixed at the configured one (threshold and size
    #: filter random): many more means the camera ranges make feasible strings rare
    feasible_fixed_camera: int
    #: thresholds and size filters in the configured ranges that keep N with the
    #: configured camera (None: none do)
    band: Band | None
    #: thresholds outside the configured range that would (the size filter in range)
    outside_thresholds: Band | None
    #: size filters outside the configured range that would (thresholds in range)
    outside_filter: Band | None
    #: the nearest counts to N with the configured camera over the configured ranges:
    #: (fewer, its threshold) and (more, its threshold); None where no count lies there
    below: tuple[int, int] | None
    above: tuple[int, int] | None


def _sizes(problem: CalibrationProblem, threshold: int, cam) -> NDArray[np.float64]:
    """The blobs' floor sizes (cm²) at ``threshold`` through ``cam``, largest first."""
    table = problem.blobs_at(threshold)
    size = table.area_px * pixel_footprint_cm2(table.row, table.col, cam, problem.size_plane_cm)
    return np.sort(size[size > 0])[::-1]


def _exact(sizes: NDArray[np.float64], n: int, lo: float, hi: float) -> tuple[float, float] | None:
    """The size filters f in [lo, hi] that keep exactly ``n`` blobs (a blob is kept when
    its size ≥ f): (exclusive lower end, upper end), or None."""
    if sizes.size < n or n < 1:
        return None
    top = float(sizes[n - 1])
    below = float(sizes[n]) if sizes.size > n else 0.0
    a, b = max(below, lo), min(top, hi)
    if below >= top or a > b or (a == below and a == b):
        return None
    return a, b


def _counts(sizes: NDArray[np.float64], lo: float, hi: float) -> set[int]:
    """Every number of blobs some size filter in [lo, hi] keeps."""
    inside = sizes[(sizes >= lo) & (sizes <= hi)]
    filters = np.concatenate([[lo, hi], inside, np.nextafter(inside, np.inf)])
    filters = filters[filters <= hi]
    return {int(np.count_nonzero(sizes >= f)) for f in filters}


def _run(hits: list[tuple[int, float, float]]) -> Band | None:
    """The longest run of consecutive thresholds in ``hits`` (threshold, lo, hi)."""
    if not hits:
        return None
    best: list[tuple[int, float, float]] = []
    run: list[tuple[int, float, float]] = []
    for hit in hits:
        run = [*run, hit] if run and hit[0] == run[-1][0] + 1 else [hit]
        if len(run) > len(best):
            best = run
    middle = best[len(best) // 2]
    return Band(best[0][0], best[-1][0], *middle)


def _sample(problem: CalibrationProblem, fixed_camera: bool) -> int:
    """How many of :data:`SAMPLES` random strings of the ranges are feasible (seeded);
    with ``fixed_camera`` only the threshold and the size filter are random."""
    rng = np.random.default_rng(0)
    lo, hi = problem.bounds[:, 0].copy(), problem.bounds[:, 1].copy()
    if fixed_camera:
        lo[2:] = hi[2:] = problem.nominal_values()[2:]
    found = 0
    for start in range(0, SAMPLES, _CHUNK):
        values = lo + (hi - lo) * rng.random((min(_CHUNK, SAMPLES - start), lo.size))
        found += int(problem.evaluate(values).feasible.sum())
    return found


def diagnose(problem: CalibrationProblem) -> Diagnosis:
    """What the ranges and the frame allow (see the module docstring)."""
    n = problem.n_points
    cam = problem.camera_for(problem.nominal_values())
    f_lo, f_hi = (float(v) for v in problem.bounds[1])
    t_lo, t_hi = int(np.ceil(problem.bounds[0, 0])), int(np.floor(problem.bounds[0, 1]))
    inside: list[tuple[int, float, float]] = []
    wider_filter: list[tuple[int, float, float]] = []
    below: tuple[int, int] | None = None
    above: tuple[int, int] | None = None
    for t in range(t_lo, t_hi + 1):
        sizes = _sizes(problem, t, cam)
        exact = _exact(sizes, n, f_lo, f_hi)
        if exact is not None:
            inside.append((t, *exact))
        anywhere = _exact(sizes, n, 0.0, np.inf)
        if anywhere is not None:
            wider_filter.append((t, *anywhere))
        for c in _counts(sizes, f_lo, f_hi):
            if c < n and (below is None or c > below[0]):
                below = (c, t)
            if c > n and (above is None or c < above[0]):
                above = (c, t)
    outside: list[tuple[int, float, float]] = []
    if not inside and problem.config.image.threshold_mode in _SEARCHED:
        for t in [*range(0, t_lo), *range(t_hi + 1, 256)]:
            exact = _exact(_sizes(problem, t, cam), n, f_lo, f_hi)
            if exact is not None:
                outside.append((t, *exact))
    return Diagnosis(
        sampled=SAMPLES,
        feasible_sampled=_sample(problem, fixed_camera=False),
        feasible_fixed_camera=_sample(problem, fixed_camera=True),
        band=_run(inside),
        outside_thresholds=_run(outside),
        outside_filter=None if inside else _run(wider_filter),
        below=below,
        above=above,
    )


def _thresholds(lo: int, hi: int) -> str:
    return f"threshold {lo}" if lo == hi else f"thresholds {lo}-{hi}"


def _band_text(band: Band) -> str:
    return (
        f"{_thresholds(band.threshold_lo, band.threshold_hi)} (at {band.middle}: a size "
        f"filter above {band.filter_lo:.3g} and up to {band.filter_hi:.3g} cm²)"
    )


def infeasible_message(problem: CalibrationProblem, result: GAResult) -> str:
    """Why the GA found no string that sees one object per control point, and what to try."""
    d = diagnose(problem)
    n = problem.n_points
    ga = problem.config.ga
    t_lo, t_hi = int(np.ceil(problem.bounds[0, 0])), int(np.floor(problem.bounds[0, 1]))
    f_lo, f_hi = (float(v) for v in problem.bounds[1])
    mode = problem.config.image.threshold_mode
    pinhole = ".pinhole" if problem.config.camera.model == "pinhole" else ""
    searched = _thresholds(t_lo, t_hi) + (
        "" if mode in _SEARCHED else f" (image.threshold_mode = {mode})"
    )
    ranges = f"{searched} and size filters {f_lo:g}-{f_hi:g} cm²"
    ga_text = (
        f"the GA (population {ga.population}, {ga.generations} generations: "
        f"{result.evaluations} strings tried) found none that sees exactly {n} objects "
        "(one per control point)"
    )
    bigger = (
        "raise the population and the generations (--population, --generations, or [ga] "
        "in the configuration; the presets use 100 and 90)"
    )
    camera = (
        f"with the camera fixed at the configured one {d.feasible_fixed_camera} of "
        f"{d.sampled} do" + (f" ({_band_text(d.band)})" if d.band is not None else "")
    )
    narrow = f"narrow the camera's ranges in [calibration{pinhole}] around the configured camera"
    if d.feasible_sampled:
        share = d.feasible_sampled / d.sampled
        text = (
            f"{ga_text}, though such strings exist: {d.feasible_sampled} of {d.sampled} "
            f"random strings of the search ranges see {n} (about {100 * share:.2g} %: a "
            f"random search would need about {int(np.ceil(1 / share))} strings); {bigger}"
        )
        if d.feasible_fixed_camera > 2 * d.feasible_sampled:
            text += f", or {narrow}: {camera}"
        return text
    if d.band is not None or d.feasible_fixed_camera:
        return (
            f"{ga_text}, and neither do {d.sampled} random strings of the search ranges; "
            f"{camera}: {narrow}, or {bigger}"
        )
    if d.outside_thresholds is not None:
        return (
            f"no threshold in the configured range {t_lo}-{t_hi} sees exactly {n} objects "
            f"(one per control point) with the configured camera, but "
            f"{_band_text(d.outside_thresholds)} do: widen [calibration] threshold to "
            "include them"
        )
    if d.outside_filter is not None:
        return (
            f"no size filter in the configured range {f_lo:g}-{f_hi:g} cm² sees exactly "
            f"{n} objects (one per control point) with the configured camera, but "
            f"{_band_text(d.outside_filter)} do: set [calibration] size_filter_cm2 to "
            "include them"
        )
    seen = []
    if d.below is not None and d.below[0] > 0:
        seen.append(f"at most {d.below[0]} (threshold {d.below[1]})")
    if d.above is not None:
        seen.append(f"at least {d.above[0]} (threshold {d.above[1]})")
    shows = " or ".join(seen) + " objects" if seen else "no object at all"
    return (
        f"the frame is infeasible: with the configured camera no setting in {ranges} "
        f"sees exactly {n} objects (one per control point); it shows {shows}"
        + (f", never {n}. " if seen else ". ")
        + "Check that every control point's object is in view and no other large object "
        "is, the image polarity (image.polarity), and the calibration ranges"
    )
