"""Calibration as an optimisation problem solved by the GA (paper §4, eqs. 14–16).

Minimise the mean DIPE over the control points by choosing the threshold, the size
filter A^f and the camera parameters Z0, λ, k1, k2, k3, s_x, s_y within their ranges,
subject to the constraint that thresholding and size filtering the frame yields
*exactly* as many objects as there are control points (eq. 15). A string that breaks
the constraint is infeasible and ranks below every feasible one
(fitness = ``INFEASIBLE`` + |count − N|, so nearer misses still rank higher).

Speed-up (same results): the frame is smoothed once; the blobs (area, centroid) of each
integer threshold are labelled once and cached, so a string costs only the size filter
(pixel footprints through its camera), a projection of the control points and the
matching, all vectorised over the population.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import NamedTuple

import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.calibration.dipe import match_points, pixel_error_mm
from ovis.common.calibration.file import (
    Calibration,
    GenerationRecord,
    PointResidual,
    mm_or_none,
    now_iso,
)
from ovis.common.calibration.ga import GAResult, GenerationStats, run_ga
from ovis.common.camera.projection import pixel_footprint_cm2, project
from ovis.common.config import (
    CALIBRATED_VARIABLES,
    CameraParams,
    ControlPoint,
    OvisConfig,
)
from ovis.common.vision.labeling import label_components
from ovis.common.vision.preprocess import as_gray, binarize, read_mask, smooth
from ovis.common.vision.segmentation import prepare

__all__ = [
    "INFEASIBLE",
    "CalibrationProblem",
    "Evaluation",
    "InfeasibleCalibrationError",
    "calibrate",
    "camera_with",
]

#: Fitness of a string that does not see exactly one blob per control point.
INFEASIBLE = 1.0e6


class InfeasibleCalibrationError(RuntimeError):
    """No string in the ranges sees exactly one object per control point."""


class Evaluation(NamedTuple):
    """Fitness of P strings, with what each saw."""

    fitness: NDArray[np.float64]  # (P,) mean DIPE in px, or INFEASIBLE + |count − N|
    count: NDArray[np.int64]  # (P,) objects left after the size filter
    feasible: NDArray[np.bool_]  # (P,)
    dipe_px: NDArray[np.float64]  # (P, N), NaN where infeasible
    blob_row: NDArray[np.float64]  # (P, N) centroid matched to each point, NaN if infeasible
    blob_col: NDArray[np.float64]


class _BlobTable(NamedTuple):
    area_px: NDArray[np.float64]
    row: NDArray[np.float64]
    col: NDArray[np.float64]


def camera_with(camera: CameraParams, values: NDArray[np.float64]) -> CameraParams:
    """The camera with its calibrated parameters taken from ``values`` (…, 9).

    ``values`` of shape (P, 9) gives a population camera whose parameters are (P, 1)
    arrays (they broadcast against points); of shape (9,), an ordinary camera.
    """
    names = CALIBRATED_VARIABLES
    if values.ndim == 1:
        fields = {n: float(values[i]) for i, n in enumerate(names) if n in _CAMERA_VARIABLES}
    else:
        fields = {n: values[:, i : i + 1] for i, n in enumerate(names) if n in _CAMERA_VARIABLES}
    return msgspec.structs.replace(camera, **fields)


_CAMERA_VARIABLES = frozenset(CALIBRATED_VARIABLES[2:])


class CalibrationProblem:
    """Fitness of GA strings for one frame and a set of control points.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8
        The calibration frame, with exactly one object per control point in view.
    points : sequence of ControlPoint
        World positions (cm) of the centres of the objects' top faces.
    config : OvisConfig
        Camera constants, image settings, ranges. The size filter converts blob areas
        to cm² on the plane ``pose.obstacle_height_cm``.
    """

    def __init__(
        self, image: NDArray[np.uint8], points: Sequence[ControlPoint], config: OvisConfig
    ) -> None:
        gray = as_gray(image)
        cam = config.camera
        if gray.shape != (cam.rows, cam.cols):
            raise ValueError(
                f"the frame is {gray.shape[1]}x{gray.shape[0]} (cols x rows) but the camera "
                f"is configured for {cam.cols}x{cam.rows}; set camera.rows/cols (and c_x, "
                "c_y, N_fx, N_fy) to match the frame"
            )
        if not points:
            raise ValueError("calibration needs at least one control point")
        self.config = config
        self.smoothed = smooth(gray, config.image.median)
        img = config.image
        background = None
        if img.background:
            background = read_mask(img.background, gray.shape, "background")
        #: what the threshold applies to (background subtracted, local contrast)
        self.prepared = prepare(
            self.smoothed, img.threshold_mode, img.block_px, background, img.polarity
        )
        self.roi = None if not img.roi else read_mask(img.roi, gray.shape, "region-of-interest")
        self.points = list(points)
        self.points_xyz = np.array([[p.x_cm, p.y_cm, p.z_cm] for p in points], dtype=np.float64)
        self.bounds = np.array(config.calibration.bounds(), dtype=np.float64)
        self.bounds[0] = self.threshold_bounds()
        self.size_plane_cm = config.pose.obstacle_height_cm
        self._tables: dict[int, _BlobTable] = {}

    def threshold_bounds(self) -> tuple[float, float]:
        """The threshold gene's range: the configured one, or Otsu's level alone in the
        "otsu" and "auto" modes (the level is computed, not searched)."""
        mode = self.config.image.threshold_mode
        if mode in ("otsu", "auto"):
            level = float(self.prepared.level(mode, 0))
            return level, level
        return tuple(self.config.calibration.threshold)  # type: ignore[return-value]

    @property
    def n_points(self) -> int:
        return len(self.points)

    def blobs_at(self, threshold: int) -> _BlobTable:
        """Blobs (area, centroid) of the smoothed frame at one threshold, cached."""
        table = self._tables.get(threshold)
        if table is None:
            binary = binarize(self.prepared.image, threshold, self.config.image.polarity)
            if self.roi is not None:
                binary &= (self.roi > 0).astype(np.uint8)
            comp = label_components(binary)
            table = _BlobTable(comp.area_px, comp.row, comp.col)
            self._tables[threshold] = table
        return table

    def _gather(self, thresholds: NDArray[np.int64]):
        """Padded (P, B) blob arrays for each string's threshold."""
        uniq, inverse = np.unique(thresholds, return_inverse=True)
        tables = [self.blobs_at(int(t)) for t in uniq]  # one per distinct threshold
        width = max(1, max(t.area_px.size for t in tables))
        area = np.zeros((uniq.size, width))
        row = np.zeros((uniq.size, width))
        col = np.zeros((uniq.size, width))
        for u, t in enumerate(tables):
            n = t.area_px.size
            area[u, :n], row[u, :n], col[u, :n] = t.area_px, t.row, t.col
        inverse = inverse.reshape(-1)
        return area[inverse], row[inverse], col[inverse]

    def evaluate(self, values: NDArray[np.float64]) -> Evaluation:
        """Fitness (eq. 16: f = mean DIPE, px) of (P, 9) decoded strings, vectorised."""
        values = np.atleast_2d(np.asarray(values, dtype=np.float64))
        P, N = values.shape[0], self.n_points
        thresholds = np.clip(np.rint(values[:, 0]), 0, 255).astype(np.int64)
        size_filter = values[:, 1:2]
        cam = self.camera_for(values)
        area, row, col = self._gather(thresholds)
        footprint = pixel_footprint_cm2(row, col, cam, self.size_plane_cm)
        keep = (area > 0) & (footprint > 0) & (area * footprint >= size_filter)
        count = keep.sum(axis=1)
        X, Y, Z = (self.points_xyz[:, i][None, :] for i in range(3))
        pred = project(X, Y, Z, cam)
        feasible = (count == N) & pred.valid.all(axis=1)

        fitness = INFEASIBLE + np.abs(count - N).astype(np.float64)
        fitness[(count == N) & ~feasible] = INFEASIBLE + 0.5
        dipe = np.full((P, N), np.nan)
        blob_row = np.full((P, N), np.nan)
        blob_col = np.full((P, N), np.nan)
        if feasible.any():
            order = np.argsort(~keep[feasible], axis=1, kind="stable")[:, :N]
            f_row = np.take_along_axis(row[feasible], order, axis=1)
            f_col = np.take_along_axis(col[feasible], order, axis=1)
            match = match_points(pred.row[feasible], pred.col[feasible], f_row, f_col)
            dipe[feasible] = match.dipe_px
            blob_row[feasible] = np.take_along_axis(f_row, match.blob_index, axis=1)
            blob_col[feasible] = np.take_along_axis(f_col, match.blob_index, axis=1)
            fitness[feasible] = match.dipe_px.mean(axis=1)
        return Evaluation(fitness, count, feasible, dipe, blob_row, blob_col)

    def camera_for(self, values: NDArray[np.float64]) -> CameraParams:
        """The camera of decoded strings (…, V): :func:`camera_with` for the paper model
        (subclasses for other camera models override it, and :meth:`nominal_values`)."""
        return camera_with(self.config.camera, values)

    def nominal_values(self) -> NDArray[np.float64]:
        """The configured camera (and 0 for the image settings) as a string's values."""
        return np.array([getattr(self.config.camera, n, 0.0) for n in CALIBRATED_VARIABLES])

    def fitness(self, values: NDArray[np.float64]) -> NDArray[np.float64]:
        """Fitness only (the GA's objective)."""
        return self.evaluate(values).fitness


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
        from ovis.common.calibration.infeasible import infeasible_message

        raise InfeasibleCalibrationError(infeasible_message(problem, result))
    return result


def calibrate(
    image: NDArray[np.uint8],
    points: Sequence[ControlPoint],
    config: OvisConfig,
    *,
    on_generation: Callable[[GenerationStats], None] | None = None,
    source: str = "",
    dedupe: bool = True,
) -> tuple[Calibration, GAResult]:
    """Run the GA calibration of paper §4 on one frame; return the calibration and GA run.

    Raises :class:`InfeasibleCalibrationError` when no string in the ranges sees exactly one
    object per control point, with what was seen and what to change.
    """
    if config.camera.model == "pinhole":  # the general camera: GA + least squares
        from ovis.common.calibration.pinhole import calibrate_pinhole

        return calibrate_pinhole(
            image, points, config, on_generation=on_generation, source=source, dedupe=dedupe
        )
    t0 = time.perf_counter()
    problem = CalibrationProblem(image, points, config)
    result = run_constrained_ga(
        problem, problem.fitness, problem.bounds, on_generation=on_generation, dedupe=dedupe
    )
    elapsed = time.perf_counter() - t0
    return build_calibration(problem, result, elapsed=elapsed, source=source), result


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
        from ovis.common.calibration.refine import refine_for_calibration

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
