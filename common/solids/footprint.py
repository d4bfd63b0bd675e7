"""Each frame's footprint of a solid whose shape and height are known, from its blob's
centroid: the footprint centre whose silhouette's image centroid
(:func:`~ovis.common.solids.silhouette.image_moments`) is the blob's (less the offset
between the two measured when the solid was fitted: the threshold's edge is not the
fitted edge). Newton's method on the centre, every solid of a shape at once; the
Jacobian by differences. A moving solid's map is kept and reused while it stays near
(:func:`solve_centres`): over a few cm the map is all but linear."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ovis.common.config import CameraModel
from ovis.common.solids.silhouette import Viewpoint, image_moments

__all__ = ["centroid_at", "centroid_footprints", "centroid_map", "solve_centres"]

FloatArray = NDArray[np.float64]

#: Step (cm) of the difference Jacobian, and Newton steps per frame.
STEP_CM = 0.05
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


def centroid_at(shape: str, theta: FloatArray, view: Viewpoint, camera: CameraModel) -> FloatArray:
    """Each silhouette's image centroid (m, 2) (row, col): :func:`centroid_map` without
    its Jacobian (a solid that turned where it stands: the Jacobian in its centre is
    all but the same)."""
    _, row, col = image_moments(shape, np.asarray(theta, dtype=np.float64), view, camera)
    return np.stack([row, col], -1)


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
