"""Painting simulated frames through a camera model: flat shapes anti-aliased by
supersampling, robots' top faces and their markers, and the finish every frame gets
(lighting, blur, sensor and pepper noise). Shared by the one-camera :class:`Arena` and
the camera grid's renderer (:mod:`ovis.common.sim.gridview`); see
:mod:`ovis.common.sim.arena` for the scene model these implement."""

from __future__ import annotations

import math
from collections.abc import Callable

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.camera.projection import back_project, project
from ovis.common.config import CameraModel, SimulatorConfig

__all__ = [
    "PlaneSamples",
    "PlaneTiles",
    "finish_frame",
    "marker_hand",
    "outline",
    "paint_marker",
    "paint_shape",
    "paint_top_face",
]

FloatArray = NDArray[np.float64]
Inside = Callable[[FloatArray, FloatArray], NDArray[np.bool_]]

OUTLINE_POINTS = 32  # points on a disk's outline (rectangles: 4 per edge)
PEPPER_MAX = 30  # pepper noise: grey levels 0…PEPPER_MAX
_BAND_ROWS = 16  # image rows back-projected at once by PlaneSamples
_TILE_PX = 32  # side of the image tiles PlaneTiles back-projects at a time


def outline(
    is_rect: bool, half_len: float, half_wid: float, x: float, y: float, heading: float
) -> tuple[FloatArray, FloatArray]:
    """World points (cm) on the outline of a top face: a rectangle turned by ``heading``
    (radians), or a disk of radius ``half_len`` (a circumscribed polygon, so the
    outline encloses it)."""
    if is_rect:
        t = np.linspace(-1.0, 1.0, 5)[:-1]
        one = np.ones_like(t)
        u = np.concatenate([t * half_len, one * half_len, -t * half_len, -one * half_len])
        v = np.concatenate([-one * half_wid, t * half_wid, one * half_wid, -t * half_wid])
    else:
        a = np.linspace(0.0, 2.0 * math.pi, OUTLINE_POINTS, endpoint=False)
        r = half_len / math.cos(math.pi / OUTLINE_POINTS)
        u, v = r * np.cos(a), r * np.sin(a)
    ch, sh = math.cos(heading), math.sin(heading)
    return x + u * ch - v * sh, y + u * sh + v * ch


class PlaneSamples:
    """The back-projection of every sub-pixel sample (``supersample²`` per pixel) of
    ``cam``'s image onto the plane Z = ``z``, computed once (float32), so that painting
    many frames of shapes on that plane costs a look-up instead of back-projecting
    (iteratively undistorting) their samples each frame."""

    def __init__(self, cam: CameraModel, z: float, supersample: int) -> None:
        self.z, self.s = float(z), int(supersample)
        off = (np.arange(self.s) + 0.5) / self.s - 0.5
        cc = (np.arange(int(cam.cols))[:, None] + off).reshape(1, -1)
        shape = (int(cam.rows) * self.s, cc.size)
        self.x = np.empty(shape, np.float32)
        self.y = np.empty(shape, np.float32)
        self.valid = np.empty(shape, bool)
        for r0 in range(0, int(cam.rows), _BAND_ROWS):  # bands that stay in cache
            rows = np.arange(r0, min(r0 + _BAND_ROWS, int(cam.rows)))
            rr = (rows[:, None] + off).reshape(-1, 1)
            bp = back_project(rr, cc, cam, self.z)
            band = slice(r0 * self.s, r0 * self.s + rr.size)
            self.x[band], self.y[band] = bp.x_cm, bp.y_cm
            self.valid[band] = bp.valid

    def window(
        self, r0: int, r1: int, c0: int, c1: int
    ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
        """Plane points and validity of the samples of pixel rows r0…r1−1, cols c0…c1−1."""
        s = self.s
        win = (slice(r0 * s, r1 * s), slice(c0 * s, c1 * s))
        return self.x[win], self.y[win], self.valid[win]


def _sample_grid(r0: int, r1: int, c0: int, c1: int, s: int) -> tuple[FloatArray, FloatArray]:
    """The sub-pixel samples (``s``² per pixel, at their centres) of pixel rows
    r0…r1−1 and cols c0…c1−1: a column of rows and a row of cols, to broadcast."""
    off = (np.arange(s) + 0.5) / s - 0.5
    rr = (np.arange(r0, r1)[:, None] + off).reshape(-1, 1)
    cc = (np.arange(c0, c1)[:, None] + off).reshape(1, -1)
    return rr, cc


class PlaneTiles:
    """The back-projection of ``cam``'s sub-pixel samples onto the plane Z = ``z``,
    worked out tile by tile (:data:`_TILE_PX` pixels a side) the first time a shape is
    painted over it and kept: a moving shape costs a look-up once its tiles have been
    seen, with no start-up cost and only the memory of the tiles seen. The values are
    those :func:`paint_shape` computes without it (float64, each sample on its own), so
    a frame is the same either way."""

    def __init__(self, cam: CameraModel, z: float, supersample: int) -> None:
        self.cam, self.z, self.s = cam, float(z), int(supersample)
        rows, cols = int(cam.rows), int(cam.cols)
        shape = (rows * self.s, cols * self.s)
        # untouched pages of these cost no memory until a tile is written into them
        self.x, self.y = np.empty(shape), np.empty(shape)
        self.valid = np.empty(shape, bool)
        self.done = np.zeros((-(-rows // _TILE_PX), -(-cols // _TILE_PX)), bool)

    def window(
        self, r0: int, r1: int, c0: int, c1: int
    ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
        """Plane points and validity of the samples of pixel rows r0…r1−1, cols c0…c1−1."""
        t = _TILE_PX
        tiles = (slice(r0 // t, -(-r1 // t)), slice(c0 // t, -(-c1 // t)))
        for i, j in np.argwhere(~self.done[tiles]):
            self._tile(tiles[0].start + int(i), tiles[1].start + int(j))
        s = self.s
        win = (slice(r0 * s, r1 * s), slice(c0 * s, c1 * s))
        return self.x[win], self.y[win], self.valid[win]

    def _tile(self, i: int, j: int) -> None:
        t, s = _TILE_PX, self.s
        r0, c0 = i * t, j * t
        r1, c1 = min(r0 + t, int(self.cam.rows)), min(c0 + t, int(self.cam.cols))
        bp = back_project(*_sample_grid(r0, r1, c0, c1, s), self.cam, self.z)
        win = (slice(r0 * s, r1 * s), slice(c0 * s, c1 * s))
        self.x[win], self.y[win], self.valid[win] = bp.x_cm, bp.y_cm, bp.valid
        self.done[i, j] = True


def paint_shape(
    level: NDArray[np.float32],
    cam: CameraModel,
    supersample: int,
    px: FloatArray,
    py: FloatArray,
    z: float,
    inside: Inside,
    value: float,
    samples: PlaneSamples | PlaneTiles | None = None,
) -> None:
    """Composite one flat shape of intensity ``value`` into ``level`` (in place).

    ``px, py``: its outline (world cm) on the plane Z = ``z``, for the bounding box;
    ``inside(X, Y)``: membership of plane points. Coverage is the fraction of the
    ``supersample²`` sub-pixel samples whose back-projection lies inside (looked up in
    ``samples`` when given: they must be of this camera, plane and supersampling).
    """
    rows, cols = level.shape
    p = project(px, py, z, cam)
    if not p.valid.all():
        return
    r0 = max(math.floor(p.row.min()) - 1, 0)
    r1 = min(math.ceil(p.row.max()) + 2, rows)
    c0 = max(math.floor(p.col.min()) - 1, 0)
    c1 = min(math.ceil(p.col.max()) + 2, cols)
    if r0 >= r1 or c0 >= c1:
        return
    s = supersample
    if samples is not None:
        X, Y, valid = samples.window(r0, r1, c0, c1)
    else:
        bp = back_project(*_sample_grid(r0, r1, c0, c1, s), cam, z)
        X, Y, valid = bp.x_cm, bp.y_cm, bp.valid
    hit = inside(X, Y) & valid
    cov = hit.reshape(r1 - r0, s, c1 - c0, s).mean(axis=(1, 3), dtype=np.float32)
    sub = level[r0:r1, c0:c1]
    sub += cov * (np.float32(value) - sub)


def paint_top_face(
    level: NDArray[np.float32],
    cam: CameraModel,
    sim: SimulatorConfig,
    *,
    x: float,
    y: float,
    z: float,
    heading: float,
    half_len: float,
    half_wid: float,
    is_rect: bool,
    samples: PlaneSamples | PlaneTiles | None = None,
) -> None:
    """Paint an object's top face (``sim.object_level``): a rectangle turned by
    ``heading`` (radians) or a disk of radius ``half_len``, centred on (x, y) at Z = z."""
    px, py = outline(is_rect, half_len, half_wid, x, y, heading)
    ch, sh = math.cos(heading), math.sin(heading)

    def inside(X: FloatArray, Y: FloatArray) -> NDArray[np.bool_]:
        dx, dy = X - x, Y - y
        if is_rect:
            return (np.abs(dx * ch + dy * sh) <= half_len) & (np.abs(dy * ch - dx * sh) <= half_wid)
        return dx * dx + dy * dy <= half_len * half_len

    paint_shape(level, cam, sim.supersample, px, py, z, inside, sim.object_level, samples)


def marker_hand(cam: CameraModel, x: float, y: float, z: float) -> float:
    """+1 when ``cam`` sees the floor round (x, y, z) as a real camera does from above
    (the image's (col, row) turn the other way from the world's (x, y)), else −1: the
    ``hand`` that makes a painted marker look unmirrored in the image."""
    p = project(np.array([x, x + 1.0, x]), np.array([y, y, y + 1.0]), z, cam)
    det = (p.col[1] - p.col[0]) * (p.row[2] - p.row[0]) - (p.col[2] - p.col[0]) * (
        p.row[1] - p.row[0]
    )
    return 1.0 if float(det) < 0.0 else -1.0


def paint_marker(
    level: NDArray[np.float32],
    cam: CameraModel,
    sim: SimulatorConfig,
    *,
    cells: NDArray[np.bool_],
    side_cm: float,
    hand: float,
    x: float,
    y: float,
    z: float,
    heading: float,
    samples: PlaneSamples | PlaneTiles | None = None,
) -> None:
    """Paint the black cells (``sim.marker_level``) of a marker (``cells``: True where
    white) of side ``side_cm`` centred on (x, y) at Z = z, its top edge towards
    ``heading`` (radians); ``hand`` = ±1 turns it so the camera sees it unmirrored."""
    k = cells.shape[0]
    up = np.array([math.cos(heading), math.sin(heading)])
    right = hand * np.array([up[1], -up[0]])
    half = side_cm / 2.0
    u = np.array([-half, half, half, -half])
    v = np.array([half, half, -half, -half])
    px, py = x + u * right[0] + v * up[0], y + u * right[1] + v * up[1]

    def inside(X: FloatArray, Y: FloatArray) -> NDArray[np.bool_]:
        dx, dy = X - x, Y - y
        uu, vv = dx * right[0] + dy * right[1], dx * up[0] + dy * up[1]
        col = np.floor((uu + half) / side_cm * k).astype(np.int64)
        row = np.floor((half - vv) / side_cm * k).astype(np.int64)
        ok = (col >= 0) & (col < k) & (row >= 0) & (row < k)
        white = cells[np.clip(row, 0, k - 1), np.clip(col, 0, k - 1)]
        return ok & ~white

    paint_shape(level, cam, sim.supersample, px, py, z, inside, sim.marker_level, samples)


def finish_frame(
    level: NDArray[np.float32],
    light: NDArray[np.float32],
    sim: SimulatorConfig,
    rng: np.random.Generator | None,
) -> NDArray[np.uint8]:
    """The camera frame of a painted scene: ``level × light``, then (unless ``rng`` is
    None: the clean scene) Gaussian blur, Gaussian sensor noise and pepper noise drawn
    from ``rng``; clipped and rounded to uint8."""
    img = level * light
    if rng is not None:
        if sim.blur_sigma_px > 0.0:
            img = cv2.GaussianBlur(
                img, (0, 0), sigmaX=sim.blur_sigma_px, borderType=cv2.BORDER_REFLECT
            )
        if sim.noise_sigma > 0.0:
            img += rng.standard_normal(img.shape, dtype=np.float32) * np.float32(sim.noise_sigma)
        n_pepper = round(sim.pepper_fraction * img.size)
        if n_pepper > 0:
            where = rng.choice(img.size, size=n_pepper, replace=False)
            img.reshape(-1)[where] = rng.integers(0, PEPPER_MAX + 1, size=n_pepper)
    np.clip(img, 0.0, 255.0, out=img)
    return np.rint(img).astype(np.uint8)
