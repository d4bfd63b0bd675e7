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

import functools
import math
import threading
from collections.abc import Iterable
from concurrent.futures import Future, ThreadPoolExecutor

import msgspec
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ovis.common.camera import pinhole
from ovis.common.camera.paper_model import PixelJacobian, five_points, jacobian_of
from ovis.common.camera.projection import back_project
from ovis.common.config import CameraModel, PinholeParams

__all__ = ["PlaneTable", "PlaneTables", "frame_rays", "warm_rays"]

#: Cameras whose undistorted rays are kept: every camera of a host's stage process, and
#: a recalibrated one's new model beside the old.
RAYS_KEPT = 16
_RAYS: dict[bytes, pinhole.Undistorted] = {}  # the newest cameras'
_RAYS_LOCK = threading.Lock()


def frame_rays(camera: PinholeParams) -> pinhole.Undistorted:
    """Every pixel centre of a pinhole camera's frame, undistorted: the costly half of
    back-projecting the whole frame, the same for every plane, so made once per camera
    (kept for the last :data:`RAYS_KEPT` cameras: a recalibration brings a new one)."""
    key = msgspec.msgpack.encode(camera)
    with _RAYS_LOCK:
        rays = _RAYS.get(key)
    if rays is None:
        r, c = np.mgrid[0 : camera.rows, 0 : camera.cols]
        rays = pinhole.undistort_normalised(r.astype(np.float64), c.astype(np.float64), camera)
        with _RAYS_LOCK:
            while len(_RAYS) >= RAYS_KEPT:
                del _RAYS[next(iter(_RAYS))]
            _RAYS[key] = rays
    return rays


def warm_rays(camera: CameraModel) -> None:
    """Make a pinhole camera's :func:`frame_rays` now (a spare process, before it takes
    over from a stage that died: its tables are then made in a fraction of the time)."""
    if isinstance(camera, PinholeParams):
        frame_rays(camera)


class PlaneTable:
    """The plane point of every pixel centre of ``camera``'s frame on z = ``z_cm``, as
    x + iy (cm; NaN where the pixel does not see the plane)."""

    def __init__(self, camera: CameraModel, z_cm: float) -> None:
        self.rows, self.cols = camera.rows, camera.cols
        if isinstance(camera, PinholeParams):
            b = pinhole.rays_on_plane(frame_rays(camera), camera, z_cm)
        else:
            r, c = np.mgrid[0 : self.rows, 0 : self.cols]
            b = back_project(r.astype(np.float64), c.astype(np.float64), camera, z_cm)
        xy = np.asarray(b.x_cm) + 1j * np.asarray(b.y_cm)
        self._xy = np.where(np.asarray(b.valid), xy, np.nan).ravel()
        w = self.cols
        #: :meth:`at_pixels`' flat offsets: each half-pixel point's two neighbours
        self._around = np.array([0, -w, 0, -1, w, 0, 1, 0])[:, None]

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

    @functools.cached_property
    def _whole_ok(self) -> NDArray[np.bool_]:
        """Per pixel (flat), whether :meth:`at_pixels` reads it: a pixel at least 1 px
        inside the frame whose three 2 × 2 blocks of pixels the five points fall in (its
        own, the one above, the one to its left) all see the plane."""
        seen = np.isfinite(self._xy).reshape(self.rows, self.cols)
        block = seen[:-1, :-1] & seen[:-1, 1:] & seen[1:, :-1] & seen[1:, 1:]
        ok = np.zeros_like(seen)
        ok[1:-1, 1:-1] = block[1:, 1:] & block[:-1, 1:] & block[1:, :-1]
        return ok.ravel()

    def at_pixels(self, row: NDArray[np.integer], col: NDArray[np.integer]) -> PixelJacobian:
        """The :class:`~ovis.common.camera.paper_model.PixelJacobian` of whole pixels of
        the frame from this table, as :func:`~ovis.common.camera.paper_model.jacobian_of`
        makes it from :meth:`__call__` at their five points (the same numbers), valid
        where :attr:`_whole_ok` (elsewhere its numbers mean nothing). At a whole pixel
        each of the five points lies on a pixel centre or halfway between two, so the
        bilinear reading is the table's value there or the mean of two neighbours'
        (worked out as :meth:`__call__` does, the nearer-to-the-origin one plus half
        the difference): a few gathers instead of the weights and corners of each."""
        w = self.cols
        i = np.asarray(row, dtype=np.intp) * w + np.asarray(col, dtype=np.intp)
        ok = self._whole_ok[i]
        # the pixel, above, the pixel, left, then below, the pixel, right, the pixel (a
        # pixel not read: one inside the frame)
        near = self._xy[np.where(ok, i, w + 1) + self._around]
        lo, hi = near[:4], near[4:]
        half = lo + (hi - lo) * 0.5  # row + ½, row − ½, col + ½, col − ½
        d_row, d_col = half[0] - half[1], half[2] - half[3]
        here = near[0]
        return PixelJacobian(
            here.real, here.imag, d_row.real, d_row.imag, d_col.real, d_col.imag, ok
        )

    def points(self, rc: list[list[float]]) -> list[complex]:
        """:meth:`__call__` at a few points (row, col), in plain Python (NaN where not
        valid): for a handful of points (a marker's corners) a dozen array calls cost
        more than the arithmetic."""
        t = self._xy.item
        w = self.cols
        last_row, last_col = self.rows - 1, w - 1
        out = []
        for row, col in rc:
            if not (0.0 <= row <= last_row and 0.0 <= col <= last_col):
                out.append(complex(math.nan, math.nan))
                continue
            r0 = int(row) if row < last_row else last_row - 1
            c0 = int(col) if col < last_col else last_col - 1
            fr, fc = row - r0, col - c0
            i = r0 * w + c0
            a, b = t(i), t(i + 1)
            top = a + (b - a) * fc
            lower_a, lower_b = t(i + w), t(i + w + 1)
            out.append(top + (lower_a + (lower_b - lower_a) * fc - top) * fr)
        return out


class PlaneTables:
    """The :class:`PlaneTable` of each plane height of one camera (the newest asked
    for; a new calibration replaces them), for the per-frame pixel → plane maps of a
    pinhole camera, whose back-projection iterates to undo the lens distortion.

    With ``background``, a table is made on a thread of its own while the frames asked
    for meanwhile are back-projected directly: a running stage never stalls for it."""

    def __init__(self, *, background: bool = False) -> None:
        self._camera: CameraModel | None = None
        self._tables: dict[float, Future[PlaneTable]] = {}
        self._pool = ThreadPoolExecutor(max_workers=1) if background else None
        self._lock = threading.Lock()  # the frame thread and a calibration's thread

    def table(self, camera: CameraModel, z_cm: float) -> PlaneTable | None:
        """``camera``'s table of the plane z = ``z_cm``; None while it is being made."""
        with self._lock:
            if camera is not self._camera:
                self._camera, self._tables = camera, {}
            made = self._tables.get(z_cm)
            if made is None:
                if self._pool is None:
                    made = Future()
                    made.set_result(PlaneTable(camera, z_cm))
                else:
                    made = self._pool.submit(PlaneTable, camera, z_cm)
                self._tables[z_cm] = made
        return made.result() if made.done() else None

    def pixel_jacobian(
        self, row: NDArray[np.integer], col: NDArray[np.integer], camera: CameraModel, z_cm: float
    ) -> PixelJacobian:
        """:meth:`jacobian` at whole pixels (an outline's pixel chain), the same numbers:
        read by :meth:`PlaneTable.at_pixels` where it can, by :meth:`jacobian` elsewhere
        (the frame's edge, pixels not seeing the plane) and while the table is made."""
        table = self.table(camera, z_cm)
        if table is None:
            return self.jacobian(row, col, camera, z_cm)
        j = table.at_pixels(row, col)
        if not j.valid.all():
            rest = ~j.valid
            theirs = self.jacobian(row[rest], col[rest], camera, z_cm)
            for mine, other in zip(j, theirs, strict=True):
                mine[rest] = other
        return j

    def prepare(
        self, camera: CameraModel, heights_cm: Iterable[float], *, wait: bool = False
    ) -> None:
        """Start making ``camera``'s tables of these plane heights now (at start or on a
        new calibration), so that no frame waits or falls back for them; with ``wait``,
        return once they are made (at start: the first frames then run at full speed
        instead of sharing the interpreter with the thread making them)."""
        heights = list(heights_cm)
        for z in heights:
            self.table(camera, z)
        if wait:
            with self._lock:
                made = [self._tables[z] for z in heights if z in self._tables]
            for future in made:
                future.result()

    def jacobian(
        self, row: ArrayLike, col: ArrayLike, camera: CameraModel, z_cm: float
    ) -> PixelJacobian:
        """:func:`~ovis.common.camera.projection.pixel_jacobian` at (row, col) on
        z = ``z_cm``, read from the table; the points the table does not cover (within
        ½ px of the frame's edge, or beyond it) are back-projected."""
        rows, cols = five_points(row, col)
        table = self.table(camera, z_cm)
        if table is None:
            b = back_project(rows, cols, camera, z_cm)
            return jacobian_of(np.asarray(b.x_cm), np.asarray(b.y_cm), np.asarray(b.valid))
        xy, valid = table(rows, cols)
        x, y = xy.real.copy(), xy.imag.copy()
        rest = ~valid
        if rest.any():
            b = back_project(rows[rest], cols[rest], camera, z_cm)
            x[rest], y[rest], valid[rest] = b.x_cm, b.y_cm, b.valid
        return jacobian_of(x, y, valid)
