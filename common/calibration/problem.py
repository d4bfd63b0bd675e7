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

from collections.abc import Sequence
from typing import NamedTuple

import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.calibration.dipe import match_points
from ovis.common.calibration.errors import InfeasibleCalibrationError
from ovis.common.camera.projection import pixel_footprint_cm2, project
from ovis.common.config import (
    CALIBRATED_VARIABLES,
    CameraParams,
    ControlPoint,
    OvisConfig,
)
from ovis.common.vision.frames import as_gray, read_mask
from ovis.common.vision.labeling import label_components
from ovis.common.vision.segmentation import prepare
from ovis.common.vision.smoothing import smooth
from ovis.common.vision.threshold import binarize

__all__ = [
    "INFEASIBLE",
    "CalibrationProblem",
    "Evaluation",
    "InfeasibleCalibrationError",
    "camera_with",
]

#: Fitness of a string that does not see exactly one blob per control point.
INFEASIBLE = 1.0e6


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
