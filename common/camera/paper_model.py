"""The paper's camera model (eqs. 4–10): world point (cm) ⇄ pixel (row, col).

Chain, with every length in millimetres inside (world centimetres × 10):

* eq. 4 (geometrically coherent form, see ``shared/spec/model-notes.md`` §2): the camera
  centre in world coordinates is ``C = (X0 − L + r1, Y0 + r2, Z0 + r3)`` and the camera
  frame is the world frame turned about the X axis, ``p_cam = Rᵀ · (P − C)`` with
  ``R = Rot_x(θ + 90°)``. θ is the tilt of the optical axis below the horizontal
  (70° in the paper: the camera looks down and towards −Y); at θ = 90° it looks straight
  down. Camera x is world X, so image rows follow world X.
* eqs. 5–6 (perspective): ``x_u = λ·x/(λ − z)``, ``y_u = λ·y/(λ − z)``; the lens is at
  ``(0, 0, λ)`` and visible points have ``z > λ`` (the image is inverted).
* eqs. 7–8 (radial distortion): ``x_u = x_d·(1 + k1ρ² + k2ρ⁴ + k3ρ⁶)``, ρ = |(x_d, y_d)|;
  world → pixel solves this for ρ (:mod:`ovis.common.camera.distortion`).
* eqs. 9–10 (frame memory): ``row = s_x·(N_fx/d_x)·x_d + c_x``,
  ``col = s_y·(N_fy/d_y)·y_d + c_y`` (the paper's x_f is the row, y_f the column).

Every function broadcasts: camera parameters may be scalars (one camera) or arrays of
shape ``(P, 1)`` (a GA population) against points of shape ``(N,)``. Points that cannot
be projected (behind the lens, on the focal plane, or beyond the distortion model's
reach) are reported in a boolean ``valid`` mask, never as silent NaN/inf.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ovis.common.camera.distortion import distort_radius, on_rising_branch, undistort_factor
from ovis.common.config import CameraParams

__all__ = [
    "BackProjection",
    "PixelJacobian",
    "Projection",
    "back_project",
    "camera_centre_mm",
    "pixel_footprint_cm2",
    "pixel_jacobian",
    "project",
    "rotation_world_cam",
]

CM_TO_MM = 10.0

FloatArray = NDArray[np.float64]


class Projection(NamedTuple):
    """Pixel coordinates of world points; ``valid`` is False where not projectable."""

    row: FloatArray
    col: FloatArray
    valid: NDArray[np.bool_]


class BackProjection(NamedTuple):
    """Floor-plane coordinates (cm) of pixels; ``valid`` is False where the ray misses."""

    x_cm: FloatArray
    y_cm: FloatArray
    valid: NDArray[np.bool_]


def _f(value: ArrayLike) -> FloatArray:
    return np.asarray(value, dtype=np.float64)


def camera_centre_mm(cam: CameraParams) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Camera centre C = (X0 − L + r1, Y0 + r2, Z0 + r3) in world millimetres (eq. 2)."""
    cx = (_f(cam.X0_cm) - _f(cam.L_cm) + _f(cam.r1_cm)) * CM_TO_MM
    cy = (_f(cam.Y0_cm) + _f(cam.r2_cm)) * CM_TO_MM
    cz = (_f(cam.Z0_cm) + _f(cam.r3_cm)) * CM_TO_MM
    return cx, cy, cz


def rotation_world_cam(theta_deg: float) -> FloatArray:
    """R = Rot_x(θ + 90°) (eq. 3): columns are the camera axes in world coordinates.

    The camera z axis (optical axis) is ``(0, −cos θ, −sin θ)``: tilted θ below the
    horizontal, looking towards −Y.
    """
    a = np.deg2rad(float(theta_deg) + 90.0)
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def world_to_camera(
    x_cm: ArrayLike, y_cm: ArrayLike, z_cm: ArrayLike, cam: CameraParams
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Eq. 4: world point (cm) → camera coordinates (mm), ``p_cam = Rᵀ·(P − C)``."""
    R = rotation_world_cam(cam.theta_deg)
    cx, cy, cz = camera_centre_mm(cam)
    dx = _f(x_cm) * CM_TO_MM - cx
    dy = _f(y_cm) * CM_TO_MM - cy
    dz = _f(z_cm) * CM_TO_MM - cz
    x = R[0, 0] * dx + R[1, 0] * dy + R[2, 0] * dz
    y = R[0, 1] * dx + R[1, 1] * dy + R[2, 1] * dz
    z = R[0, 2] * dx + R[1, 2] * dy + R[2, 2] * dz
    return x, y, z


def _pixels_per_mm(cam: CameraParams) -> tuple[FloatArray, FloatArray]:
    """Eqs. 9–10 scale: ``s·N/d`` pixels per millimetre on the image plane."""
    return (
        _f(cam.s_x) * _f(cam.N_fx) / _f(cam.d_x_mm),
        _f(cam.s_y) * _f(cam.N_fy) / _f(cam.d_y_mm),
    )


def project(x_cm: ArrayLike, y_cm: ArrayLike, z_cm: ArrayLike, cam: CameraParams) -> Projection:
    """World point (cm) → pixel (row, col) through eqs. 4–10.

    Non-projectable points (``z ≤ λ``: behind or on the lens plane, or a distorted radius
    the model cannot reach) get ``valid = False`` and row/col of 0.
    """
    x, y, z = world_to_camera(x_cm, y_cm, z_cm, cam)
    lam = _f(cam.lam_mm)
    denom = lam - z  # eqs. 5–6; negative for visible points
    in_front = z > lam
    safe = np.where(in_front, denom, -1.0)
    x_u = lam * x / safe
    y_u = lam * y / safe
    rho_u = np.hypot(x_u, y_u)
    rho_d, ok = distort_radius(rho_u, cam.k1, cam.k2, cam.k3)
    scale = np.divide(rho_d, rho_u, out=np.ones_like(rho_d), where=rho_u > 0)
    x_d, y_d = x_u * scale, y_u * scale
    px, py = _pixels_per_mm(cam)
    valid = in_front & ok
    row = np.where(valid, px * x_d + _f(cam.c_x), 0.0)
    col = np.where(valid, py * y_d + _f(cam.c_y), 0.0)
    return Projection(row, col, valid)


def back_project(
    row: ArrayLike, col: ArrayLike, cam: CameraParams, z_cm: ArrayLike = 0.0
) -> BackProjection:
    """Pixel (row, col) → point on the horizontal plane Z = ``z_cm`` (inverse of eqs. 4–10).

    Inverts eqs. 9–10, applies eqs. 7–8 directly (no solve in this direction), and
    intersects the ray through the lens centre with the plane. Pixels whose ray is
    parallel to the plane or meets it behind the camera, or that lie beyond the radius
    the distortion model can image, get ``valid = False``.
    """
    px, py = _pixels_per_mm(cam)
    x_d = (_f(row) - _f(cam.c_x)) / px
    y_d = (_f(col) - _f(cam.c_y)) / py
    rho_d = np.hypot(x_d, y_d)
    factor = undistort_factor(rho_d, cam.k1, cam.k2, cam.k3)
    imageable = on_rising_branch(rho_d, cam.k1, cam.k2, cam.k3)
    x_u, y_u = x_d * factor, y_d * factor
    lam = _f(cam.lam_mm)
    # Camera point on the ray at depth z: (x_u·(λ − z)/λ, y_u·(λ − z)/λ, z).
    # World Z of it is linear in z: Z(z) = cz + a·(λ − z) + R[2,2]·z.
    R = rotation_world_cam(cam.theta_deg)
    cx, cy, cz = camera_centre_mm(cam)
    a = (R[2, 0] * x_u + R[2, 1] * y_u) / lam
    slope = R[2, 2] - a
    target = _f(z_cm) * CM_TO_MM - cz - a * lam
    ok = np.abs(slope) > 1e-12
    z = np.where(ok, target / np.where(ok, slope, 1.0), 0.0)
    valid = ok & (z > lam) & imageable
    t = (lam - z) / lam
    x, y = x_u * t, y_u * t
    X = cx + R[0, 0] * x + R[0, 1] * y + R[0, 2] * z
    Y = cy + R[1, 0] * x + R[1, 1] * y + R[1, 2] * z
    x_cm = np.where(valid, X / CM_TO_MM, 0.0)
    y_cm = np.where(valid, Y / CM_TO_MM, 0.0)
    return BackProjection(x_cm, y_cm, valid)


class PixelJacobian(NamedTuple):
    """The pixel → floor map near (row, col): the floor point itself (cm) and the floor
    cm per pixel step, ∂(X, Y)/∂row and ∂(X, Y)/∂col."""

    x_cm: FloatArray
    y_cm: FloatArray
    dx_drow: FloatArray
    dy_drow: FloatArray
    dx_dcol: FloatArray
    dy_dcol: FloatArray
    valid: NDArray[np.bool_]

    @property
    def area_cm2(self) -> FloatArray:
        """|det J|: floor area of one pixel (0 where the pixel does not see the plane)."""
        det = self.dx_drow * self.dy_dcol - self.dy_drow * self.dx_dcol
        return np.where(self.valid, np.abs(det), 0.0)


#: The five points of the central differences, ±½ px around (row, col): the point, then
#: row + ½, row − ½, col + ½, col − ½.
_ROW_STEP = np.array([0.0, 0.5, -0.5, 0.0, 0.0])
_COL_STEP = np.array([0.0, 0.0, 0.0, 0.5, -0.5])


def five_points(row: ArrayLike, col: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """(row, col) and its four ±½ px neighbours, stacked on a new leading axis of 5 (the
    points :func:`pixel_jacobian` back-projects; built by broadcasting, not by stacking)."""
    r, c = _f(row), _f(col)
    lead = (5,) + (1,) * max(r.ndim, c.ndim)
    return r + _ROW_STEP.reshape(lead), c + _COL_STEP.reshape(lead)


def jacobian_of(x: FloatArray, y: FloatArray, valid: NDArray[np.bool_]) -> PixelJacobian:
    """The :class:`PixelJacobian` from the back-projections of :func:`five_points`."""
    return PixelJacobian(
        x[0], y[0], x[1] - x[2], y[1] - y[2], x[3] - x[4], y[3] - y[4], valid.all(axis=0)
    )


def pixel_jacobian(
    row: ArrayLike, col: ArrayLike, cam: CameraParams, z_cm: ArrayLike = 0.0
) -> PixelJacobian:
    """The pixel → plane Z = ``z_cm`` map at (row, col) and its Jacobian (central
    differences, ±½ px), in one back-projection of the five points.

    It maps small image offsets (and second moments) to the floor: blob areas in cm²
    (size filter A^f, radius) and world orientations of elongated blobs.
    """
    rows, cols = five_points(row, col)
    b = back_project(rows, cols, cam, z_cm)
    return jacobian_of(b.x_cm, b.y_cm, b.valid)


def pixel_footprint_cm2(
    row: ArrayLike, col: ArrayLike, cam: CameraParams, z_cm: ArrayLike = 0.0
) -> FloatArray:
    """Floor area (cm²) covered by one pixel at (row, col) on the plane Z = ``z_cm``.

    The absolute Jacobian determinant of the pixel → plane map; 0 where the pixel does
    not see the plane.
    """
    return pixel_jacobian(row, col, cam, z_cm).area_cm2
