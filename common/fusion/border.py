"""Is a blob's disk wholly inside a camera's image? The question of
:func:`~ovis.common.camera.projection.disks_in_image` (its 16 rim points projected,
each at least a margin from the border), answered from a table.

Per plane height, the camera's pixel (row, col) of every node of a floor grid of
``step_cm`` (covering the floor the image sees, plus two steps) is computed once; a
frame's rim points are then bilinear look-ups in it, not projections through the lens
model. Where the look-up can differ from the projection (a rim point within
:attr:`BorderTable.band_px` of the margin: the interpolation error measured at the cells'
centres, doubled) the disk is decided by projecting it, so the answer is exactly
:func:`disks_in_image`'s. A rim point off the grid is outside the image.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ovis.common.camera.projection import back_project, disks_in_image, project
from ovis.common.config import CameraModel

__all__ = ["ANGLES_COS", "ANGLES_SIN", "BorderTable", "bilinear", "floor_seen", "room_px"]

FloatArray = NDArray[np.float64]

#: the rim points of a disk, as disks_in_image takes them
_ANGLES = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
ANGLES_COS, ANGLES_SIN = np.cos(_ANGLES), np.sin(_ANGLES)
#: at most this many plane heights are tabulated; others are projected
MAX_PLANES = 8
#: at most this many grid nodes per plane (a camera seeing the horizon is projected)
MAX_NODES = 4_000_000
#: pixels along each image edge whose floor points bound the grid
EDGE_SAMPLES = 64


def floor_seen(cam: CameraModel, z: float) -> tuple[FloatArray, FloatArray, bool]:
    """Where the image's border meets the plane z (``EDGE_SAMPLES`` pixels along each
    edge, back-projected): the floor points (x, y; cm) that bound what the camera sees
    there, and whether every edge pixel sees the plane (else the view reaches beyond
    its horizon)."""
    rows, cols = cam.rows - 1.0, cam.cols - 1.0
    t = np.linspace(0.0, 1.0, EDGE_SAMPLES)
    r = np.concatenate([t * rows, t * rows, np.zeros_like(t), np.full_like(t, rows)])
    c = np.concatenate([np.zeros_like(t), np.full_like(t, cols), t * cols, t * cols])
    b = back_project(r, c, cam, z)
    valid = np.asarray(b.valid)
    return np.asarray(b.x_cm)[valid], np.asarray(b.y_cm)[valid], bool(valid.all())


class _Plane:
    """One plane height's table: grid origin, step, shape and (row, col) per node."""

    def __init__(self, cam: CameraModel, z: float, step: float) -> None:
        self.step = step
        x, y, self.ok = floor_seen(cam, z)
        if not self.ok:  # the image sees beyond the plane's horizon: project instead
            return
        self.x0, self.y0 = float(x.min()) - 2 * step, float(y.min()) - 2 * step
        self.nx = int(np.ceil((float(x.max()) + 2 * step - self.x0) / step)) + 1
        self.ny = int(np.ceil((float(y.max()) + 2 * step - self.y0) / step)) + 1
        if self.nx * self.ny > MAX_NODES:
            self.ok = False
            return
        gx = self.x0 + step * np.arange(self.nx)
        gy = self.y0 + step * np.arange(self.ny)
        X, Y = np.meshgrid(gx, gy, indexing="ij")
        p = project(X.ravel(), Y.ravel(), z, cam)
        far = -1e9  # an unprojectable node: every rim point near it is outside
        #: (row, col) of each node as row + 1j·col: one gather fetches both
        self.rc = np.where(p.valid, p.row + 1j * p.col, far + 1j * far).ravel()
        # the interpolation error at the cells' centres, where bilinear is worst
        cx, cy = (gx[:-1] + step / 2), (gy[:-1] + step / 2)
        CX, CY = np.meshgrid(cx, cy, indexing="ij")
        exact = project(CX.ravel(), CY.ravel(), z, cam)
        got, inside = self.look_up(CX.ravel(), CY.ravel())
        good = exact.valid & inside & (got.real > far / 2) & (got.imag > far / 2)
        diff = got[good] - (exact.row + 1j * exact.col)[good]
        self.error_px = (
            float(np.maximum(abs(diff.real), abs(diff.imag)).max()) if diff.size else 0.0
        )

    def look_up(self, x: FloatArray, y: FloatArray) -> tuple[FloatArray, NDArray[np.bool_]]:
        """Bilinear row + 1j·col at the points, and whether each is on the grid."""
        return bilinear(self.rc, (self.x0, self.y0, 1.0 / self.step, self.nx, self.ny, 0), x, y)


def bilinear(
    flat: FloatArray, grid: tuple, x: FloatArray, y: FloatArray
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Values of a grid laid flat (``flat``, 1-D, row by row from ``offset``; complex
    for two values per node) bilinear at the points, and whether each point is on the
    grid (elsewhere: the first cell's value). ``grid``: ``x0, y0, 1/step, nx, ny,
    offset``, numbers or arrays that broadcast with the points (one grid per point)."""
    x0, y0, inv, nx, ny, offset = grid
    fx, fy = (x - x0) * inv, (y - y0) * inv
    i, j = np.floor(fx), np.floor(fy)
    on = (i >= 0) & (i < nx - 1) & (j >= 0) & (j < ny - 1)
    i, j = np.where(on, i, 0.0), np.where(on, j, 0.0)
    tx, ty = fx - i, fy - j
    k = (offset + i * ny + j).astype(np.intp)
    stride = np.asarray(ny).astype(np.intp)
    top = flat[k] * (1 - ty) + flat[k + 1] * ty
    bottom = flat[k + stride] * (1 - ty) + flat[k + stride + 1] * ty
    return top * (1 - tx) + bottom * tx, on


def room_px(
    rc: FloatArray, on: NDArray[np.bool_], last: FloatArray, margin_px: float
) -> FloatArray:
    """Per disk, from its rim points' pixels ``(n, 16)`` as row + 1j·col (``on``: inside
    the table): how far (pixels) its nearest rim point lies inside the margin of an image
    whose last pixel is ``last`` (row + 1j·col); negative: outside."""
    inside = last - rc
    room = np.minimum(np.minimum(rc.real, inside.real), np.minimum(rc.imag, inside.imag))
    room -= margin_px
    return np.where(on, room, -np.inf).min(axis=-1)


class BorderTable:
    """:func:`disks_in_image` of one camera from per-height tables (module docstring)."""

    def __init__(self, cam: CameraModel, step_cm: float = 1.0) -> None:
        self.cam, self.step = cam, step_cm
        self._planes: dict[float, _Plane] = {}
        self._band: float | None = None

    def plane(self, z: float) -> _Plane | None:
        """The table of plane height ``z`` (built on first use), or None when it is
        not tabulated (too many heights, or a view beyond the plane's horizon)."""
        table = self._planes.get(z)
        if table is None:
            if len(self._planes) >= MAX_PLANES:
                return None
            table = self._planes[z] = _Plane(self.cam, z, self.step)
            self._band = None
        return table if table.ok else None

    def prepare(self, *heights_cm: float) -> None:
        """Build the tables of these plane heights now (at start, not on a frame)."""
        for z in heights_cm:
            self.plane(float(z))

    @property
    def band_px(self) -> float:
        """How near the margin (pixels) a looked-up rim point is re-checked by
        projection: twice the largest interpolation error of the tables built."""
        if self._band is None:
            errors = [p.error_px for p in self._planes.values() if p.ok]
            self._band = 2.0 * max(errors, default=0.0) + 1e-9
        return self._band

    def whole(
        self, x_cm: ArrayLike, y_cm: ArrayLike, z_cm: ArrayLike, radius_cm: ArrayLike,
        margin_px: float = 0.0,
    ) -> NDArray[np.bool_]:  # fmt: skip
        """Per disk, what ``disks_in_image(x, y, z, r, cam, margin_px)`` says."""
        x, y, z, r = np.broadcast_arrays(
            *(np.atleast_1d(np.asarray(v, np.float64)) for v in (x_cm, y_cm, z_cm, radius_cm))
        )
        finite = np.isfinite(x) & np.isfinite(y) & np.isfinite(r)
        if not finite.all():  # NaN or infinite: never whole
            x, y, r = (np.where(finite, v, 0.0) for v in (x, y, r))
        out = np.zeros(x.shape, bool)
        lo = float(margin_px)
        last = (self.cam.rows - 1.0) + 1j * (self.cam.cols - 1.0)
        band = self.band_px
        for height in set(z.tolist()):
            sel = z == height
            table = self.plane(height) if height == height else None
            if table is None:
                out[sel] = disks_in_image(x[sel], y[sel], height, r[sel], self.cam, lo)
                continue
            rs = r[sel][:, None]
            rim_x, rim_y = x[sel][:, None] + rs * ANGLES_COS, y[sel][:, None] + rs * ANGLES_SIN
            room = room_px(*table.look_up(rim_x, rim_y), last, lo)
            decided = np.abs(room) > band
            got = room >= 0
            if not decided.all():  # near the margin: as disks_in_image decides
                near = ~decided
                got[near] = disks_in_image(
                    x[sel][near], y[sel][near], height, r[sel][near], self.cam, lo
                )
            out[sel] = got
        return out & finite
