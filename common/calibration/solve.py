"""The calibration problem solved on one frame (paper §4): the GA under the exact-count
constraint of eq. 15 (an infeasible run says which setting stopped it), the threshold and
size filter centred in what works, the least-squares polish for the paper's model, and
the result packaged as a :class:`~ovis.common.calibration.file.Calibration` with its
residuals (eq. 14) and GA history. Shared by the paper model (:mod:`.calibrate`) and
the pinhole camera (:mod:`.pinhole`).
"""

from __future__ import annotations

from collections.abc import Callable

import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.calibration.dipe import pixel_error_mm
from ovis.common.calibration.file import (
    Calibration,
    GenerationRecord,
    PointResidual,
    mm_or_none,
    now_iso,
)
from ovis.common.calibration.ga import GAResult, GenerationStats, run_ga
from ovis.common.calibration.infeasible import infeasible_message
from ovis.common.calibration.problem import (
    INFEASIBLE,
    CalibrationProblem,
    InfeasibleCalibrationError,
)
from ovis.common.calibration.refine import refine_for_calibration
from ovis.common.camera.projection import pixel_footprint_cm2, project

__all__ = ["build_calibration", "centre_image_settings", "run_constrained_ga"]


def run_constrained_ga(
    problem: CalibrationProblem,
    fitness: Callable[[NDArray[np.float64]], NDArray[np.float64]],
    bounds: NDArray[np.float64],
    *,
    on_generation: Callable[[GenerationStats], None] | None = None,
    dedupe: bool = True,
) -> GAResult:
    """Run the GA on ``fitness`` over ``bounds`` under the exact-count constraint (eq. 15);
    raise :class:`InfeasibleCalibrationError`, saying which setting stopped it
    (:mod:`ovis.common.calibration.infeasible`), if nothing is feasible."""
    config = problem.config
    result = run_ga(
        fitness,
        bounds,
        config.ga,
        on_generation=on_generation,
        dedupe=dedupe,
        feasible_below=INFEASIBLE,
    )
    if result.best_fitness >= INFEASIBLE:
        raise InfeasibleCalibrationError(infeasible_message(problem, result))
    return result


def centre_image_settings(
    problem: CalibrationProblem, best: NDArray[np.float64]
) -> tuple[NDArray[np.float64], tuple[int, int]]:
    """Move the threshold and the size filter to the middle of what works.

    The constraint of eq. 15 only asks for the right object count, so the GA may return
    a threshold at the edge of the feasible band (objects in darker corners of later
    frames then break up) or a size filter just above a clutter blob. Keeping the camera
    of ``best``: the threshold becomes the middle of the run of integer thresholds around
    the GA's one that still see exactly one blob per control point; then the size filter
    becomes the geometric mean of the largest blob it must reject and the smallest it
    must keep (within its range). Returns the new values and the feasible threshold run.
    """
    lo, hi = (int(v) for v in (np.ceil(problem.bounds[0, 0]), np.floor(problem.bounds[0, 1])))
    thresholds = np.arange(lo, hi + 1)
    trial = np.repeat(best[None, :], thresholds.size, axis=0)
    trial[:, 0] = thresholds
    feasible = problem.evaluate(trial).feasible
    t0 = int(np.clip(np.rint(best[0]), lo, hi)) - lo
    if not feasible[t0]:
        return best, (t0 + lo, t0 + lo)
    a = t0
    while a > 0 and feasible[a - 1]:
        a -= 1
    b = t0
    while b < feasible.size - 1 and feasible[b + 1]:
        b += 1
    out = best.copy()
    out[0] = lo + (a + b) // 2
    # Size filter: between the largest rejected and the smallest kept blob (cm²).
    table = problem.blobs_at(int(out[0]))
    cam = problem.camera_for(out)
    area = table.area_px * pixel_footprint_cm2(table.row, table.col, cam, problem.size_plane_cm)
    order = np.sort(area)[::-1]
    n = problem.n_points
    smallest_kept = order[n - 1]
    largest_rejected = order[n] if order.size > n else 0.0
    a_lo, a_hi = problem.bounds[1]
    if largest_rejected > 0:
        middle = float(np.sqrt(largest_rejected * smallest_kept))
    else:
        middle = 0.5 * float(smallest_kept)
    out[1] = float(np.clip(middle, max(a_lo, largest_rejected), min(a_hi, smallest_kept)))
    if not problem.evaluate(out[None, :]).feasible[0]:  # never trade feasibility
        return best, (a + lo, b + lo)
    return out, (a + lo, b + lo)


def build_calibration(
    problem: CalibrationProblem, result: GAResult, *, elapsed: float, source: str
) -> Calibration:
    """Package the GA's best string as a self-contained :class:`Calibration` (with the
    threshold and size filter centred, :func:`centre_image_settings`, when configured)."""
    config = problem.config
    best = result.best_values
    band = None
    if config.calibration.centre_image_settings:
        best, band = centre_image_settings(problem, best)
    refined: dict = {}
    if config.camera.model == "paper":  # least-squares polish, `[ga] polish` (refine.py)
        best, refined = refine_for_calibration(problem, best, apply=config.ga.polish)
    ev = problem.evaluate(best[None, :])
    cam = problem.camera_for(best)
    pred = project(*problem.points_xyz.T, cam)
    residuals = []
    for i, p in enumerate(problem.points):
        d_row = ev.blob_row[0, i] - pred.row[i]
        d_col = ev.blob_col[0, i] - pred.col[i]
        residuals.append(
            PointResidual(
                name=p.name,
                x_cm=p.x_cm,
                y_cm=p.y_cm,
                z_cm=p.z_cm,
                detected_row=float(ev.blob_row[0, i]),
                detected_col=float(ev.blob_col[0, i]),
                predicted_row=float(pred.row[i]),
                predicted_col=float(pred.col[i]),
                dipe_px=float(ev.dipe_px[0, i]),
                dipe_mm=mm_or_none(pixel_error_mm(d_row, d_col, cam.d_x_mm, cam.d_y_mm)),
            )
        )
    dipe_px = np.array([r.dipe_px for r in residuals])
    dipe_mm = np.array([np.nan if r.dipe_mm is None else r.dipe_mm for r in residuals])
    image = msgspec.structs.replace(
        config.image, threshold=int(np.rint(best[0])), size_filter_cm2=float(best[1])
    )
    return Calibration(
        created=now_iso(),
        dipe_px=float(dipe_px.mean()),
        dipe_mm=mm_or_none(dipe_mm.mean()),
        dipe_max_px=float(dipe_px.max()),
        dipe_max_mm=mm_or_none(dipe_mm.max()),
        camera=cam,
        image=image,
        pose=config.pose,
        points=residuals,
        ga=config.ga,
        ranges=config.calibration,
        history=[
            GenerationRecord(
                h.generation,
                h.best,
                h.mean if np.isfinite(h.mean) else None,
                h.best_so_far,
                h.feasible_fraction,
            )
            for h in result.history
        ],
        evaluations=result.evaluations,
        elapsed_s=elapsed,
        source_image=source,
        ga_threshold=int(np.rint(result.best_values[0])),
        ga_size_filter_cm2=float(result.best_values[1]),
        feasible_thresholds=band,
        **refined,
    )
