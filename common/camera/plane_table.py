"""Where every pixel of the frame lands on one horizontal plane, back-projected once.

Some per-frame work back-projects only a handful of sub-pixel points (a marker's four
corners): there the fixed cost of a whole back-projection, dozens of array operations,
outweighs the arithmetic. A :class:`PlaneTable` back-projects every pixel centre onto
the plane z = ``z_cm`` once (per calibration), and reads a point between pixel centres
by bilinear interpolation of its four neighbours. The pixel → plane map is smooth (a
perspective division and a radial polynomial), so over one pixel it is all but linear:
``tests/test_robots.py`` checks the interpolation against :func:`back_project`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ovis.common.camera.projection import back_project
from ovis.common.config import CameraModel

__all__ = ["PlaneTable"]


class PlaneTable:
    """The plane point of every pixel centre of ``camera``'s frame on z = ``z_cm``, as
    x + iy (cm; NaN where the pixel does not see the plane)."""

    def __init__(self, camera: CameraModel, z_cm: float) -> None:
        self.rows, self.cols = camera.rows, camera.cols
        r, c = np.mgrid[0 : self.rows, 0 : self.cols]
        b = back_project(r.astype(np.float64), c.astype(np.float64), camera, z_cm)
        xy = np.asarray(b.x_cm) + 1j * np.asarray(b.y_cm)
        self._xy = np.where(np.asarray(b.valid), xy, np.nan).ravel()

    def __call__(
        self, row: ArrayLike, col: ArrayLike
    ) -> tuple[NDArray[np.complex128], NDArray[np.bool_]]:
        """Plane points x + iy (cm) at sub-pixel (row, col), and where they are valid
        (inside the frame, all four neighbouring pixels seeing the plane)."""
        r, c = np.asarray(row, dtype=np.float64), np.asarray(col, dtype=np.float64)
        w = self.cols
        r0 = np.minimum(np.maximum(np.floor(r), 0.0), self.rows - 2)
        c0 = np.minimum(np.maximum(np.floor(c), 0.0), w - 2)
        fr, fc = r - r0, c - c0
        i = (r0 * w + c0).astype(np.intp)
        t = self._xy
        a, b, lower_a, lower_b = t[i], t[i + 1], t[i + w], t[i + w + 1]
        top = a + (b - a) * fc
        xy = top + (lower_a + (lower_b - lower_a) * fc - top) * fr
        inside = (fr >= 0.0) & (fr <= 1.0) & (fc >= 0.0) & (fc <= 1.0)
        return xy, inside & np.isfinite(xy)
