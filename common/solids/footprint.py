"""Each frame's footprint of a solid whose shape and height are known, from its blob's
centroid: the footprint centre whose silhouette's image centroid
(:func:`~ovis.common.solids.silhouette.image_moments`) is the blob's (less the offset
between the two measured when the solid was fitted: the threshold's edge is not the
fitted edge). Newton's method on the centre, every solid of a shape at once; the
Jacobian by differences. A moving solid's map is kept and reused while it stays near
(:func:`solve_centres`): over a few cm the map is all but linear."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ovis.common.config import CameraModel
from ovis.common.solids.fit import solve_small
from ovis.common.solids.shapes import yaw_index
from ovis.common.solids.silhouette import Viewpoint, image_axis, image_moments

__all__ = [
    "PoseMap",
    "centroid_footprints",
    "centroid_map",
    "solve_centres",
    "turn_between",
]

FloatArray = NDArray[np.float64]

#: Step (cm, and rad for a yaw) of the difference Jacobian, and Newton steps per frame.
STEP_CM = 0.05
STEP_RAD = 0.005
NEWTON_STEPS = 2


def centroid_map(
    shape: str, theta: FloatArray, view: Viewpoint, camera: CameraModel
) -> tuple[FloatArray, FloatArray]:
    """Each silhouette's image centroid (m, 2) (row, col) and its Jacobian (m, 2, 2) with
    respect to the footprint centre (x, y), by differences: one projection."""
    theta = np.asarray(theta, dtype=np.float64)
    trial = np.repeat(theta[None], 3, axis=0)
    trial[1, :, 0] += STEP_CM
    trial[2, :, 1] += STEP_CM
    _, row, col = image_moments(shape, trial, view, camera)
    g = np.stack([row, col], -1)  # (3, m, 2)
    jac = np.stack([(g[1] - g[0]) / STEP_CM, (g[2] - g[0]) / STEP_CM], -1)
    return g[0], jac


class PoseMap(NamedTuple):
    """A turning polygon's silhouette's image centroid and major axis and how they move
    with its footprint centre and yaw: where the map was worked out (x, y, yaw), the
    centroid and axis there (row, col, rad: :func:`~ovis.common.solids.silhouette.
    image_axis`) and their Jacobian (row by row) with respect to (x, y, yaw), by
    differences. Its blob's centroid and axis then put it (x, y and yaw) in each frame
    by one linear step (a robot that turns as it drives), as
    :func:`solve_centres` puts a solid that does not turn."""

    at: tuple[float, float, float]
    image: tuple[float, float, float]
    jac: tuple[tuple[float, float, float], ...]

    @classmethod
    def of(cls, shape: str, theta: FloatArray, view: Viewpoint, camera: CameraModel) -> PoseMap:
        """The map of a solid (parameter vector ``theta``): one projection."""
        theta = np.asarray(theta, dtype=np.float64)
        k = yaw_index(shape)
        if k is None:
            raise ValueError(f"a {shape} has no yaw to follow")
        trial = np.repeat(theta[None], 4, axis=0)
        trial[1, 0] += STEP_CM
        trial[2, 1] += STEP_CM
        trial[3, k] += STEP_RAD
        row, col, axis = image_axis(shape, trial, view, camera)
        f = np.stack([row, col, axis], -1)  # (4, 3)
        d = f[1:] - f[0]
        d[:, 2] = turn_between(f[0, 2], f[1:, 2])
        jac = (d / np.array([STEP_CM, STEP_CM, STEP_RAD])[:, None]).T
        at = (float(theta[0]), float(theta[1]), float(theta[k]))
        return cls(at, tuple(f[0].tolist()), tuple(tuple(r) for r in jac.tolist()))

    def solve(
        self, target: tuple[float, float, float | None], yaw: float
    ) -> tuple[float, float, float] | None:
        """(x, y, yaw) whose silhouette's image centroid and axis are ``target`` (row,
        col, rad; the axis None: the yaw kept at ``yaw``), by one linear step; None
        where the map is singular."""
        (r0, c0, a0), (x0, y0, w0) = self.image, self.at
        j = self.jac
        e = [target[0] - r0, target[1] - c0]
        if target[2] is None:  # the centroid alone: 2 × 2, the yaw's share moved over
            e = [e[0] - j[0][2] * (yaw - w0), e[1] - j[1][2] * (yaw - w0)]
            rows = [[j[0][0], j[0][1], e[0]], [j[1][0], j[1][1], e[1]]]
        else:
            e.append(float(turn_between(a0, target[2])))
            rows = [[*j[k], e[k]] for k in range(3)]
        d = solve_small(rows)
        if d is None:
            return None
        return x0 + d[0], y0 + d[1], (w0 + d[2]) if target[2] is not None else yaw

    def image_at(
        self, centre: tuple[float, float] | FloatArray, yaw: float
    ) -> tuple[float, float, float]:
        """The silhouette's image centroid and axis (row, col, rad) with its footprint
        centre and yaw there, by the map (linear)."""
        d = (float(centre[0]) - self.at[0], float(centre[1]) - self.at[1], yaw - self.at[2])
        r, c, a = (
            v + sum(j * e for j, e in zip(row, d, strict=True))
            for v, row in zip(self.image, self.jac, strict=True)
        )
        return r, c, a

    @property
    def slope(self) -> float:
        """How fast the silhouette's axis turns with the yaw (rad per rad)."""
        return abs(self.jac[2][2])


def turn_between(a: FloatArray | float, b: FloatArray | float) -> FloatArray:
    """How far (rad) axis ``b`` is turned from axis ``a`` (axes: angles modulo π), in
    [−π/2, π/2)."""
    return (np.asarray(b) - a + 0.5 * np.pi) % np.pi - 0.5 * np.pi


def solve_centres(
    centre: FloatArray, g: FloatArray, jac: FloatArray, target: FloatArray
) -> FloatArray:
    """The footprint centres (m, 2) whose image centroids are ``target`` (m, 2), by one
    linear step from ``centre`` where the centroid is ``g`` with Jacobian ``jac``; a
    singular Jacobian keeps the centre."""
    det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
    ok = np.isfinite(det) & (np.abs(det) > 1e-9) & np.isfinite(g).all(-1)
    err = np.where(ok[:, None], target - g, 0.0)
    safe = np.where(ok, det, 1.0)
    dx = (jac[:, 1, 1] * err[:, 0] - jac[:, 0, 1] * err[:, 1]) / safe
    dy = (-jac[:, 1, 0] * err[:, 0] + jac[:, 0, 0] * err[:, 1]) / safe
    return centre + np.stack([dx, dy], -1)


def centroid_footprints(
    shape: str,
    theta: FloatArray,
    target: FloatArray,
    view: Viewpoint,
    camera: CameraModel,
) -> FloatArray:
    """``theta`` (m, P) with its centres moved so that each silhouette's image centroid
    is ``target`` (m, 2) (row, col): :data:`NEWTON_STEPS` Newton steps."""
    theta = np.array(theta, dtype=np.float64)
    for _ in range(NEWTON_STEPS if len(theta) else 0):
        g, jac = centroid_map(shape, theta, view, camera)
        theta[:, 0:2] = solve_centres(theta[:, 0:2], g, jac, target)
    return theta
