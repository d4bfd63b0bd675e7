"""Honest accuracy of a calibration: held-out errors and what the data determine.

The paper reports the DIPE (eq. 14) of the four control points the camera was fitted
to. With N = 4 points (8 numbers) and 7 continuous camera parameters that number is
optimistic, and it says nothing about which parameters are pinned down. This module
adds (beyond the paper):

* **Leave-one-out** (:func:`leave_one_out`): for each control point i, refit the
  camera on the other points by the bounded least squares of
  :mod:`ovis.common.calibration.refine` (starting from the calibration, blobs and matching fixed)
  and report how far the refit misses point i: in pixels (detected centroid vs
  projection) and in cm on the plane of the point's top face (back-projected centroid
  vs the point).
* **Check points** (:func:`check_errors`): extra points of known position, in the
  calibration frame or another one (:func:`load_checks`), detected with the calibrated
  threshold and size filter and compared with the calibration's projection.
* **Identifiability** (:func:`determination`): per continuous parameter, how far
  sweeping it over its whole range moves the points (``sweep_px``), its standard error
  from the Jacobian of the pixel residuals, σ·√diag((JᵀJ)⁻¹), with every other
  determinable parameter free, and its spread across GA restarts with other seeds
  (:func:`restarts`). With the paper's ranges the k's move no point by even 0.01 px
  (ρ is about 1 mm on the image plane and |k| ≤ 1e−6), so they are not identifiable;
  λ trades off against s_x and s_y (only λ·s_x and λ·s_y, the scale, are sharp).
* **World error against a known camera** (:func:`floor_error_grid`,
  :func:`arena_world_error`): for simulated data, where the true camera is known.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NamedTuple

import msgspec
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from ovis.common.calibration.file import Calibration
from ovis.common.calibration.ga import run_ga
from ovis.common.calibration.problem import INFEASIBLE, CalibrationProblem, camera_with
from ovis.common.calibration.quality import (
    AccuracyReport,
    HeldOut,
    HeldOutPoint,
    ParameterDetermination,
)
from ovis.common.calibration.refine import (
    CONTINUOUS,
    CONTINUOUS_SLICE,
    dipe_of,
    fit_camera,
    matched_blobs,
    polish,
    residuals_px,
)
from ovis.common.calibration.solve import centre_image_settings
from ovis.common.camera.projection import back_project, pixel_footprint_cm2, project
from ovis.common.config import CameraModel, ConfigError, ControlPoint, OvisConfig
from ovis.common.vision.frames import as_gray
from ovis.common.vision.labeling import label_components
from ovis.common.vision.segmentation import segment
from ovis.common.vision.smoothing import smooth

__all__ = [
    "CheckSet",
    "arena_world_error",
    "assess",
    "calibration_values",
    "check_errors",
    "determination",
    "floor_error_grid",
    "leave_one_out",
    "load_checks",
    "restarts",
]

#: A parameter whose whole range moves no control point by this much (px) cannot be
#: told from the data (blob centroids are good to about 0.1 px at best).
SWEEP_MIN_PX = 0.1
#: A determinable parameter counts as determined when its standard error is below this
#: fraction of its search range.
DETERMINED_RELATIVE = 0.05
#: A check point whose projection is farther than this from every blob is "missing".
CHECK_GATE_PX = 20.0

_NAMES = {
    "Z0_cm": "Z0",
    "lam_mm": "λ",
    "k1": "k1",
    "k2": "k2",
    "k3": "k3",
    "s_x": "s_x",
    "s_y": "s_y",
}


def calibration_values(calibration: Calibration) -> NDArray[np.float64]:
    """The nine GA variables (threshold, A^f, Z0, λ, k1..k3, s_x, s_y) of a calibration."""
    cam = calibration.camera
    head = [float(calibration.image.threshold), float(calibration.image.size_filter_cm2)]
    return np.array(head + [float(getattr(cam, n)) for n in CONTINUOUS])


def _held_out_stats(points: list[HeldOutPoint]) -> dict[str, float | None]:
    if not points:
        return {"mean_px": None, "max_px": None, "mean_cm": None, "max_cm": None}
    px = np.array([p.error_px for p in points])
    cm = np.array([p.error_cm for p in points if p.error_cm is not None])
    return {
        "mean_px": float(px.mean()),
        "max_px": float(px.max()),
        "mean_cm": float(cm.mean()) if cm.size else None,
        "max_cm": float(cm.max()) if cm.size else None,
    }


def _held_out_point(
    point: ControlPoint,
    detected: tuple[float, float],
    predicted: tuple[float, float],
    cam: CameraModel,
    in_sample_px: float | None = None,
) -> HeldOutPoint:
    """How far ``cam`` misses ``point``: in the image (detected vs predicted row/col) and
    on the floor (the back-projected detection vs the point; None if not on the plane)."""
    (d_row, d_col), (p_row, p_col) = detected, predicted
    b = back_project(d_row, d_col, cam, point.z_cm)
    error_cm = (
        float(np.hypot(float(b.x_cm) - point.x_cm, float(b.y_cm) - point.y_cm))
        if bool(b.valid)
        else None
    )
    return HeldOutPoint(
        name=point.name,
        x_cm=point.x_cm,
        y_cm=point.y_cm,
        z_cm=point.z_cm,
        detected_row=d_row,
        detected_col=d_col,
        predicted_row=p_row,
        predicted_col=p_col,
        error_px=float(np.hypot(d_row - p_row, d_col - p_col)),
        error_cm=error_cm,
        in_sample_px=in_sample_px,
    )


def leave_one_out(problem: CalibrationProblem, values: NDArray[np.float64]) -> HeldOut | None:
    """Leave-one-out errors of the control points (None with fewer than 2 points).

    Blobs and matching are those of ``values`` (9,); each refit is the bounded least
    squares of :func:`ovis.common.calibration.refine.fit_camera` from ``values`` on the other
    points.
    ``in_sample_px`` is each point's residual in the same least squares on all points.
    """
    n = problem.n_points
    if n < 2:
        return None
    values = np.asarray(values, dtype=np.float64)
    blob_row, blob_col = matched_blobs(problem, values)
    full = fit_camera(problem, values, blob_row, blob_col)
    r_in = residuals_px(problem, full.values, blob_row, blob_col).reshape(2, n)
    in_sample = np.hypot(r_in[0], r_in[1])
    out: list[HeldOutPoint] = []
    for i, p in enumerate(problem.points):
        use = np.ones(n, dtype=bool)
        use[i] = False
        fit = fit_camera(problem, values, blob_row, blob_col, use=use)
        cam = camera_with(problem.config.camera, fit.values)
        pred = project(p.x_cm, p.y_cm, p.z_cm, cam)
        if not bool(pred.valid):
            continue
        out.append(
            _held_out_point(
                p,
                (float(blob_row[i]), float(blob_col[i])),
                (float(pred.row), float(pred.col)),
                cam,
                in_sample_px=float(in_sample[i]),
            )
        )
    return HeldOut(
        method="leave-one-out",
        source=f"{n} control points, each refitted without it (least squares from the calibration)",
        points=out,
        **_held_out_stats(out),
    )


class CheckSet(NamedTuple):
    """Check points and the frame they are seen in (None: the calibration frame)."""

    points: list[ControlPoint]
    image: Path | None
    source: str


class _CheckFile(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    points: list[ControlPoint]
    image: str | None = None
    note: str | None = None


def load_checks(path: Path | str) -> CheckSet:
    """Load a check-points TOML file.

    ``[[points]]`` tables (``name``, ``x_cm``, ``y_cm``, ``z_cm``, as in a points file)
    and an optional top-level ``image = "frame_0009.png"`` (relative to the file) for
    points seen in another frame than the calibration frame.
    """
    import tomllib

    path = Path(path)
    try:
        data = tomllib.loads(path.read_text("utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"check-points file {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read check-points file {path}: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"check-points file {path} is not valid TOML: {exc}") from None
    try:
        checks = msgspec.convert(data, _CheckFile)
    except msgspec.ValidationError as exc:
        raise ConfigError(
            f"check-points file {path}: {exc}. Expected [[points]] tables with name, x_cm, "
            'y_cm, z_cm and an optional image = "FRAME.png"'
        ) from None
    if not checks.points:
        raise ConfigError(f"check-points file {path} has no [[points]]")
    image = None if checks.image is None else (path.parent / checks.image)
    return CheckSet(checks.points, image, str(path))


def check_errors(
    image: NDArray[np.uint8],
    points: Sequence[ControlPoint],
    calibration: Calibration,
    *,
    median: str | None = None,
    gate_px: float = CHECK_GATE_PX,
    source: str = "",
) -> HeldOut:
    """Errors of the calibration on check points seen in ``image``.

    Blobs are found with the calibration's threshold and size filter (as ``ovis detect``
    does: the size filter in cm² on the obstacles' top-face plane); each check point is
    matched to a blob by an optimal assignment on its projection, within ``gate_px``.
    """
    cam, img = calibration.camera, calibration.image
    gray = smooth(as_gray(image), median or img.median)
    comp = label_components(segment(gray, img))
    foot = pixel_footprint_cm2(comp.row, comp.col, cam, calibration.pose.obstacle_height_cm)
    keep = comp.area_px * foot >= img.size_filter_cm2
    b_row, b_col = comp.row[keep], comp.col[keep]
    xyz = np.array([[p.x_cm, p.y_cm, p.z_cm] for p in points], dtype=np.float64)
    pred = project(xyz[:, 0], xyz[:, 1], xyz[:, 2], cam)
    out: list[HeldOutPoint] = []
    missing: list[str] = []
    matched: dict[int, int] = {}
    if b_row.size:
        cost = np.hypot(pred.row[:, None] - b_row[None, :], pred.col[:, None] - b_col[None, :])
        cost = np.where(pred.valid[:, None], cost, 1e9)
        pi, bi = linear_sum_assignment(cost)
        matched = {int(i): int(j) for i, j in zip(pi, bi, strict=True) if cost[i, j] <= gate_px}
    for i, p in enumerate(points):
        j = matched.get(i)
        if j is None:
            missing.append(p.name)
            continue
        out.append(
            _held_out_point(
                p,
                (float(b_row[j]), float(b_col[j])),
                (float(pred.row[i]), float(pred.col[i])),
                cam,
            )
        )
    return HeldOut(
        method="check points",
        source=source,
        points=out,
        missing=missing,
        **_held_out_stats(out),
    )


class Restart(NamedTuple):
    """One GA restart: its seed, final values (9,) and mean DIPE (px)."""

    seed: int
    values: NDArray[np.float64]
    dipe_px: float


def restarts(
    problem: CalibrationProblem,
    seeds: Sequence[int],
    *,
    polish_them: bool = False,
    on_restart: Callable[[int], None] | None = None,
) -> list[Restart]:
    """Rerun the GA (and the centring of threshold and size filter) with other seeds.

    Infeasible restarts are left out. The spread of the GA's values is what shows the
    undetermined parameters: the polish (``polish_them``) would drive each of them
    towards the same bound of its range and so hide that spread.
    """
    cfg = problem.config
    out: list[Restart] = []
    for k, seed in enumerate(seeds):
        ga = msgspec.structs.replace(cfg.ga, seed=int(seed))
        result = run_ga(problem.fitness, problem.bounds, ga, feasible_below=INFEASIBLE)
        if result.best_fitness < INFEASIBLE:
            best = result.best_values
            if cfg.calibration.centre_image_settings:
                best, _ = centre_image_settings(problem, best)
            if polish_them:
                best = polish(problem, best).values
            out.append(Restart(int(seed), best, dipe_of(problem, best)[0]))
        if on_restart is not None:
            on_restart(k + 1)
    return out


class Determination(NamedTuple):
    """What :func:`determination` found."""

    parameters: list[ParameterDetermination]
    sigma_px: float
    condition_all: float
    condition_determined: float
    correlations: list[tuple[str, str, float]]
    #: relative standard errors of the scale products λ·s_x and λ·s_y with λ held
    #: (None if not all three are determinable)
    product_relative_error: tuple[float, float] | None = None


def _jacobian(
    problem: CalibrationProblem,
    values: NDArray[np.float64],
    blob_row: NDArray[np.float64],
    blob_col: NDArray[np.float64],
) -> NDArray[np.float64]:
    """∂(residuals px)/∂(continuous parameter, physical units), central differences."""
    lo, hi = problem.bounds[CONTINUOUS_SLICE].T
    h = 1e-4 * np.where(hi > lo, hi - lo, 1.0)
    cols = []
    for j in range(len(CONTINUOUS)):
        plus, minus = values.copy(), values.copy()
        plus[2 + j] += h[j]
        minus[2 + j] -= h[j]
        r_p = residuals_px(problem, plus, blob_row, blob_col)
        r_m = residuals_px(problem, minus, blob_row, blob_col)
        cols.append((r_p - r_m) / (2.0 * h[j]))
    return np.stack(cols, axis=1)


def determination(
    problem: CalibrationProblem,
    values: NDArray[np.float64],
    *,
    restart_values: Sequence[NDArray[np.float64]] = (),
) -> Determination:
    """Which continuous camera parameters the control points determine.

    Linearised at the least-squares fit from ``values`` (blobs and matching of
    ``values``): sweep of each parameter over its range, standard errors
    σ·√diag((JᵀJ)⁻¹) over the determinable parameters (those whose sweep moves a point by
    at least :data:`SWEEP_MIN_PX`), σ² = SSR / (2N − p), correlations, condition numbers;
    plus the spread of ``restart_values`` (each (9,)).
    """
    values = np.asarray(values, dtype=np.float64)
    n = problem.n_points
    blob_row, blob_col = matched_blobs(problem, values)
    fit = fit_camera(problem, values, blob_row, blob_col)
    at = fit.values
    lo, hi = problem.bounds[CONTINUOUS_SLICE].T
    width = np.where(hi > lo, hi - lo, 1.0)

    sweep = np.zeros(len(CONTINUOUS))
    for j in range(len(CONTINUOUS)):
        a, b = values.copy(), values.copy()
        a[2 + j], b[2 + j] = lo[j], hi[j]
        pa = project(*problem.points_xyz.T, camera_with(problem.config.camera, a))
        pb = project(*problem.points_xyz.T, camera_with(problem.config.camera, b))
        ok = pa.valid & pb.valid
        moved = np.hypot(pa.row - pb.row, pa.col - pb.col)
        sweep[j] = float(moved[ok].max()) if ok.any() else float("inf")

    J = _jacobian(problem, at, blob_row, blob_col)
    Jn = J * width[None, :]  # px per whole range
    active = sweep >= SWEEP_MIN_PX
    p = int(active.sum())
    r = residuals_px(problem, at, blob_row, blob_col)
    ssr = float(r @ r)
    dof = 2 * n - p
    sigma = float(np.sqrt(ssr / dof)) if dof > 0 else float(np.sqrt(ssr / max(2 * n, 1)))
    se = np.full(len(CONTINUOUS), np.nan)
    corr = np.full((len(CONTINUOUS), len(CONTINUOUS)), np.nan)
    if p:
        Ja = Jn[:, active]
        cov_n = np.linalg.pinv(Ja.T @ Ja, rcond=1e-15) * sigma**2
        se_n = np.sqrt(np.clip(np.diag(cov_n), 0.0, None))
        se[active] = se_n * width[active]
        with np.errstate(invalid="ignore", divide="ignore"):
            c = cov_n / np.outer(se_n, se_n)
        idx = np.flatnonzero(active)
        corr[np.ix_(idx, idx)] = c
    cond_all = float(np.linalg.cond(Jn))
    cond_det = float(np.linalg.cond(Jn[:, active])) if p else float("inf")

    rv = np.array([np.asarray(v)[CONTINUOUS_SLICE] for v in restart_values])
    params: list[ParameterDetermination] = []
    for j, name in enumerate(CONTINUOUS):
        rel = float(se[j] / width[j]) if np.isfinite(se[j]) else None
        entry = ParameterDetermination(
            name=name,
            value=float(values[2 + j]),
            range_lo=float(lo[j]),
            range_hi=float(hi[j]),
            sweep_px=float(sweep[j]),
            standard_error=float(se[j]) if np.isfinite(se[j]) else None,
            relative_error=rel,
            determined=bool(active[j] and rel is not None and rel < DETERMINED_RELATIVE),
        )
        if rv.size:
            entry.restart_min = float(rv[:, j].min())
            entry.restart_max = float(rv[:, j].max())
            entry.restart_spread = float((rv[:, j].max() - rv[:, j].min()) / width[j])
        params.append(entry)

    pairs: list[tuple[str, str, float]] = []
    idx = np.flatnonzero(active)
    for a_i, a in enumerate(idx):
        for b in idx[a_i + 1 :]:
            if np.isfinite(corr[a, b]):
                pairs.append((CONTINUOUS[a], CONTINUOUS[b], float(corr[a, b])))
    pairs.sort(key=lambda t: -abs(t[2]))
    products = None
    i_lam, i_sx, i_sy = (CONTINUOUS.index(n) for n in ("lam_mm", "s_x", "s_y"))
    if active[[i_lam, i_sx, i_sy]].all():
        # Reparametrise (λ, s_x, s_y) → (λ, log a_x, log a_y), a = λ·s: well conditioned.
        lam, sx, sy = at[2 + i_lam], at[2 + i_sx], at[2 + i_sy]
        Jr = J.copy()
        Jr[:, i_lam] = J[:, i_lam] - (sx / lam) * J[:, i_sx] - (sy / lam) * J[:, i_sy]
        Jr[:, i_sx] = J[:, i_sx] * sx  # ∂r/∂log a_x = s_x·∂r/∂s_x (λ fixed)
        Jr[:, i_sy] = J[:, i_sy] * sy
        # λ held at its value (the search ranges hold it; free, it moves the scales only
        # through the tiny perspective term λ/(λ − z), and so by a few per cent).
        keep = active.copy()
        keep[i_lam] = False
        Ja = Jr[:, keep]
        scale = np.linalg.norm(Ja, axis=0)
        scale = np.where(scale > 0, scale, 1.0)
        cov_r = np.linalg.pinv((Ja / scale).T @ (Ja / scale), rcond=1e-15) * sigma**2
        cov_r /= np.outer(scale, scale)
        pos = {int(k): i for i, k in enumerate(np.flatnonzero(keep))}
        products = (
            float(np.sqrt(max(cov_r[pos[i_sx], pos[i_sx]], 0.0))),
            float(np.sqrt(max(cov_r[pos[i_sy], pos[i_sy]], 0.0))),
        )
    return Determination(params, sigma, cond_all, cond_det, pairs[:3], products)


def _notes(
    params: list[ParameterDetermination],
    correlations: list[tuple[str, str, float]],
    products: tuple[float, float] | None,
    loo: HeldOut | None,
    check: HeldOut | None,
    calibration: Calibration,
) -> list[str]:
    notes: list[str] = []
    free = [q for q in params if q.sweep_px < SWEEP_MIN_PX]
    if free:
        names = ", ".join(_NAMES.get(q.name, q.name) for q in free)
        worst = max(q.sweep_px for q in free)
        spread = [q.restart_spread for q in free if q.restart_spread is not None]
        text = (
            f"{names}: not determined by these data - over the whole search range each "
            f"moves no control point by more than {worst:.3g} px, so the values found are "
            "arbitrary"
        )
        if spread:
            lo_s, hi_s = round(100 * min(spread)), round(100 * max(spread))
            span = f"{lo_s}" if lo_s == hi_s else f"{lo_s}-{hi_s}"
            text += f" (GA restarts spread over {span} % of the range)"
        notes.append(text)
    by_name = {q.name: q for q in params}
    c_sx = next((c for a, b, c in correlations if {a, b} == {"lam_mm", "s_x"}), None)
    c_sy = next((c for a, b, c in correlations if {a, b} == {"lam_mm", "s_y"}), None)
    lam, sx, sy = by_name["lam_mm"], by_name["s_x"], by_name["s_y"]
    tied = c_sx is not None and c_sy is not None and min(abs(c_sx), abs(c_sy)) >= 0.95
    if tied:
        text = (
            f"λ trades off against s_x and s_y (correlations {c_sx:+.4f}, {c_sy:+.4f}): "
            "only the scales λ·s_x and λ·s_y are determined"
        )
        if products is not None:
            text += (
                f" (to ±{100 * products[0]:.2g} % and ±{100 * products[1]:.2g} % at the λ found)"
            )
        if lam.standard_error is not None:
            text += f"; λ alone only to ±{lam.standard_error:.3g} mm"
        # What the search ranges leave of λ, the scale products held fixed.
        ax, ay = lam.value * sx.value, lam.value * sy.value
        lam_lo = max(lam.range_lo, ax / sx.range_hi, ay / sy.range_hi)
        lam_hi = min(lam.range_hi, ax / sx.range_lo, ay / sy.range_lo)
        if lam_lo <= lam_hi:
            text += (
                f", and in practice it is held by the search ranges of s_x, s_y to "
                f"{lam_lo:.2f}-{lam_hi:.2f} mm"
            )
        notes.append(text)
    for a, b, c in correlations:
        if abs(c) < 0.95 or (tied and "lam_mm" in (a, b)) or (tied and {a, b} == {"s_x", "s_y"}):
            continue
        notes.append(
            f"{_NAMES.get(a, a)} trades off against {_NAMES.get(b, b)} (correlation "
            f"{c:+.3f}): the data fix a combination of them, not each"
        )
    sharp = [q for q in params if q.determined]
    if sharp:
        notes.append(
            "well determined: "
            + ", ".join(
                f"{_NAMES.get(q.name, q.name)} ± {q.standard_error:.3g}"
                for q in sharp
                if q.standard_error is not None
            )
        )
    if loo is not None and loo.mean_px is not None:
        ins = [p.in_sample_px for p in loo.points if p.in_sample_px is not None]
        ratio = loo.mean_px / max(float(np.mean(ins)), 1e-9) if ins else float("nan")
        cm = f" = {loo.mean_cm:.2f} cm on the floor" if loo.mean_cm is not None else ""
        notes.append(
            f"leave-one-out error {loo.mean_px:.2f} px{cm} (mean; max {loo.max_px:.2f} px) "
            f"against {float(np.mean(ins)):.2f} px in-sample for the same fit "
            f"({ratio:.1f}x): the fitted DIPE {calibration.dipe_px:.2f} px is optimistic"
        )
    if check is not None and check.mean_px is not None:
        cm = f" = {check.mean_cm:.2f} cm" if check.mean_cm is not None else ""
        notes.append(
            f"check points: {len(check.points)} found, error {check.mean_px:.2f} px{cm} "
            f"(max {check.max_px:.2f} px)"
            + (f"; not found: {', '.join(check.missing)}" if check.missing else "")
        )
    return notes


def assess(
    image: NDArray[np.uint8],
    points: Sequence[ControlPoint],
    config: OvisConfig,
    calibration: Calibration,
    *,
    n_restarts: int = 4,
    checks: CheckSet | None = None,
    check_image: NDArray[np.uint8] | None = None,
    on_step: Callable[[str, int, int], None] | None = None,
) -> AccuracyReport:
    """Held-out errors and identifiability of ``calibration`` (made from ``image`` and
    ``points`` with ``config``); ``n_restarts`` GA restarts with seeds after the
    calibration's. ``checks`` are evaluated in ``check_image`` (default ``image``).
    ``on_step(stage, done, total)`` reports progress."""
    check = None
    if checks is not None:
        check = check_errors(
            image if check_image is None else check_image,
            checks.points,
            calibration,
            median=config.image.median,
            source=checks.source,
        )
    if calibration.camera.model != "paper":  # LOO and identifiability: paper model only
        return AccuracyReport(
            check=check,
            notes=[
                "leave-one-out and parameter identifiability are computed for the paper's "
                f"camera model only (this calibration is {calibration.camera.model})"
            ],
        )
    problem = CalibrationProblem(image, points, config)
    values = calibration_values(calibration)
    if not problem.evaluate(values[None, :]).feasible[0]:
        raise ValueError(
            "the calibration's threshold and size filter do not see one object per control "
            "point in this frame; assess it on the frame it was made from"
        )
    base_seed = calibration.ga.seed if calibration.ga is not None else config.ga.seed
    seeds = [base_seed + 1 + k for k in range(max(0, int(n_restarts)))]

    def step(stage: str, done: int, total: int) -> None:
        if on_step is not None:
            on_step(stage, done, total)

    runs = restarts(
        problem, seeds, on_restart=lambda k: step("restarts", k, len(seeds))
    ) if seeds else []  # fmt: skip
    step("leave-one-out", 0, 1)
    loo = leave_one_out(problem, values)
    step("leave-one-out", 1, 1)
    det = determination(problem, values, restart_values=[r.values for r in runs])
    return AccuracyReport(
        leave_one_out=loo,
        check=check,
        parameters=det.parameters,
        sigma_px=det.sigma_px,
        condition_all=det.condition_all,
        condition_determined=det.condition_determined,
        correlations=det.correlations,
        restart_seeds=[r.seed for r in runs],
        restart_dipe_px=[r.dipe_px for r in runs],
        notes=_notes(
            det.parameters, det.correlations, det.product_relative_error, loo, check, calibration
        ),
    )


def floor_error_grid(
    cam: CameraModel,
    true_cam: CameraModel,
    *,
    z_cm: float = 0.0,
    step_px: int = 8,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """World error map: each pixel of a grid back-projected with both cameras.

    Returns ``(x_cm, y_cm, error_cm)`` of shape (R, C): the floor point the true camera
    sees at each grid pixel (plane Z = ``z_cm``) and the distance to where the calibrated
    camera puts that pixel (NaN where either ray misses the plane).
    """
    rows = np.arange(step_px / 2.0, true_cam.rows, step_px)
    cols = np.arange(step_px / 2.0, true_cam.cols, step_px)
    r, c = np.meshgrid(rows, cols, indexing="ij")
    bt = back_project(r, c, true_cam, z_cm)
    bc = back_project(r, c, cam, z_cm)
    ok = bt.valid & bc.valid
    err = np.where(ok, np.hypot(bc.x_cm - bt.x_cm, bc.y_cm - bt.y_cm), np.nan)
    return np.where(bt.valid, bt.x_cm, np.nan), np.where(bt.valid, bt.y_cm, np.nan), err


def arena_world_error(
    cam: CameraModel,
    true_cam: CameraModel,
    x_range: tuple[float, float],
    y_range: tuple[float, float],
    *,
    z_cm: float = 0.0,
    step_cm: float = 2.0,
) -> NDArray[np.float64]:
    """Floor errors (cm) over a grid of the arena: each grid point is imaged by the true
    camera and the pixel back-projected by ``cam`` onto the same plane (inf where a
    camera cannot image or back-project it)."""
    xs = np.arange(x_range[0], x_range[1] + 1e-9, step_cm)
    ys = np.arange(y_range[0], y_range[1] + 1e-9, step_cm)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    p = project(X, Y, z_cm, true_cam)
    b = back_project(p.row, p.col, cam, z_cm)
    ok = p.valid & b.valid
    return np.where(ok, np.hypot(b.x_cm - X, b.y_cm - Y), np.inf).ravel()
