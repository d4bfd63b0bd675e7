"""A general camera: pinhole with 6-DoF pose and Brown–Conrady distortion (OpenCV's model).

World point (cm) → pixel, exactly as ``cv2.projectPoints`` computes it (Bradski &
Kaehler, *Learning OpenCV*; Brown 1966; Conrady 1919)::

    p_cam  = R(rvec)·p_world + tvec_cm                       (world → camera, OpenCV)
    x', y' = X_c / Z_c,  Y_c / Z_c                           (normalised, Z_c > 0)
    r²     = x'² + y'²
    x''    = x'·(1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x'y' + p2 (r² + 2x'²)
    y''    = y'·(1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y'²) + 2 p2 x'y'
    col    = fx·x'' + cx                                     (OpenCV u = x = column)
    row    = fy·y'' + cy                                     (OpenCV v = y = row)

Pixel → plane Z = h is the inverse: undistort (the fixed-point iteration of
``cv2.undistortPoints``, then Newton steps on the full 2×2 distortion map, with a
convergence check), then intersect the ray from the camera centre ``C = −Rᵀ·tvec`` with
the plane.

ovis names pixel coordinates ``row``/``col`` everywhere; OpenCV's x is the column and y
the row. Conversions happen only in this module and in :mod:`ovis.common.camera.export`.

Validity: a point is projectable when it lies in front of the camera (``Z_c > 0``) and
within the radius where the radial distortion is still one-to-one (``d/dr [r·(1 + k1 r² +
k2 r⁴ + k3 r⁶)] > 0`` on the whole of ``[0, r]``); beyond it distorted images fold back
and the inverse is ambiguous. Invalid points get ``valid = False`` and 0 coordinates,
never NaN.

Every function broadcasts: camera fields may be scalars (one camera) or arrays of shape
``(P, 1)`` (a GA population; ``rvec``/``tvec_cm`` then hold three such arrays) against
points of shape ``(N,)``.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ovis.common.camera.paper_model import BackProjection, Projection
from ovis.common.config import PinholeParams

__all__ = [
    "Undistorted",
    "back_project",
    "camera_centre_cm",
    "camera_matrix",
    "distort_normalised",
    "distortion_coefficients",
    "project",
    "rays_on_plane",
    "rodrigues",
    "undistort_normalised",
    "world_to_camera",
]

FloatArray = NDArray[np.float64]

#: Undistortion: fixed-point iterations (as cv2.undistortPoints), then Newton steps.
FIXED_POINT_ITERATIONS = 8
NEWTON_ITERATIONS = 8
#: An undistorted point is accepted when it re-distorts to within this (normalised
#: units; ~1e-9 px for focal lengths below 1e3 px).
UNDISTORT_TOL = 1e-12
#: Points nearer than this (cm) to the camera's image plane are not projectable.
MIN_DEPTH_CM = 1e-9


def _f(value: ArrayLike) -> FloatArray:
    return np.asarray(value, dtype=np.float64)


def camera_matrix(cam: PinholeParams) -> FloatArray:
    """K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (OpenCV: x = column, y = row)."""
    return np.array([[cam.fx, 0.0, cam.cx], [0.0, cam.fy, cam.cy], [0.0, 0.0, 1.0]])


def distortion_coefficients(cam: PinholeParams) -> FloatArray:
    """(k1, k2, p1, p2, k3): OpenCV's order of the distortion coefficients."""
    return np.array([cam.k1, cam.k2, cam.p1, cam.p2, cam.k3], dtype=np.float64)


def rodrigues(rvec: ArrayLike) -> FloatArray:
    """Rotation matrix of a Rodrigues vector, ``(..., 3) → (..., 3, 3)`` (as cv2.Rodrigues).

    ``R = cos θ·I + (1 − cos θ)·k kᵀ + sin θ·[k]×`` with ``θ = |rvec|``, ``k = rvec/θ``;
    written as ``I + a·[r]× + b·[r]×²`` with ``a = sin θ/θ``, ``b = (1 − cos θ)/θ²``
    (Taylor series below θ = 1e-4, so the map is smooth through 0).
    """
    r = _f(rvec)
    rx, ry, rz = r[..., 0], r[..., 1], r[..., 2]
    t2 = rx * rx + ry * ry + rz * rz
    t = np.sqrt(t2)
    small = t < 1e-4
    safe_t = np.where(small, 1.0, t)
    a = np.where(small, 1.0 - t2 / 6.0, np.sin(safe_t) / safe_t)
    b = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(safe_t)) / (safe_t * safe_t))
    zero = np.zeros_like(rx)
    K = np.stack(
        [
            np.stack([zero, -rz, ry], axis=-1),
            np.stack([rz, zero, -rx], axis=-1),
            np.stack([-ry, rx, zero], axis=-1),
        ],
        axis=-2,
    )
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye + a[..., None, None] * K + b[..., None, None] * (K @ K)


def _scalars(values: tuple[object, ...]) -> bool:
    """Whether these camera fields are plain numbers (one camera, not a GA population)."""
    return all(isinstance(v, float | int) for v in values)


@functools.lru_cache(maxsize=256)
def _rotation_of(rvec: tuple[float, float, float]) -> FloatArray:
    R = rodrigues(np.array(rvec, dtype=np.float64))
    R.flags.writeable = False
    return R


def _rotation(cam: PinholeParams) -> FloatArray:
    """R of the camera, (..., 3, 3) over the camera fields' broadcast shape; one
    camera's is computed once (per-frame calls project a few points, where the fixed
    cost of the Rodrigues formula would dominate)."""
    if _scalars(cam.rvec):
        return _rotation_of(tuple(float(v) for v in cam.rvec))
    rx, ry, rz = np.broadcast_arrays(*(_f(v) for v in cam.rvec))
    return rodrigues(np.stack([rx, ry, rz], axis=-1))


def world_to_camera(
    x_cm: ArrayLike, y_cm: ArrayLike, z_cm: ArrayLike, cam: PinholeParams
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``p_cam = R·p_world + tvec_cm`` (cm), component by component."""
    R = _rotation(cam)
    X, Y, Z = _f(x_cm), _f(y_cm), _f(z_cm)
    tx, ty, tz = (_f(v) for v in cam.tvec_cm)
    xc = R[..., 0, 0] * X + R[..., 0, 1] * Y + R[..., 0, 2] * Z + tx
    yc = R[..., 1, 0] * X + R[..., 1, 1] * Y + R[..., 1, 2] * Z + ty
    zc = R[..., 2, 0] * X + R[..., 2, 1] * Y + R[..., 2, 2] * Z + tz
    return xc, yc, zc


def camera_centre_cm(cam: PinholeParams) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Camera centre in world cm, ``C = −Rᵀ·tvec_cm``."""
    R = _rotation(cam)
    tx, ty, tz = (_f(v) for v in cam.tvec_cm)
    return tuple(  # type: ignore[return-value]
        -(R[..., 0, i] * tx + R[..., 1, i] * ty + R[..., 2, i] * tz) for i in range(3)
    )


def distort_normalised(
    x: ArrayLike, y: ArrayLike, cam: PinholeParams
) -> tuple[FloatArray, FloatArray]:
    """Brown–Conrady: undistorted normalised (x', y') → distorted (x'', y'')."""
    x, y = _f(x), _f(y)
    k1, k2, k3, p1, p2 = (_f(v) for v in (cam.k1, cam.k2, cam.k3, cam.p1, cam.p2))
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return xd, yd


def _monotonic_radius2(cam: PinholeParams, r2: FloatArray) -> NDArray[np.bool_]:
    """Whether ``g(s) = 1 + 3k1 s + 5k2 s² + 7k3 s³`` (d/dr of r·radial(r), s = r²) stays
    positive on ``[0, r2]``: the radial distortion is one-to-one out to that radius.

    The minimum of the cubic on the interval is at an end or at a root of
    ``g'(s) = 3k1 + 10k2 s + 21k3 s²`` (closed form), so the test is exact.
    """
    if _scalars((cam.k1, cam.k2, cam.k3)):
        return np.asarray(r2) < _one_to_one_limit(float(cam.k1), float(cam.k2), float(cam.k3))
    k1, k2, k3 = (_f(v) for v in (cam.k1, cam.k2, cam.k3))

    def g(s: FloatArray) -> FloatArray:
        return 1.0 + s * (3.0 * k1 + s * (5.0 * k2 + s * 7.0 * k3))

    ok = g(r2) > 0.0
    a, b, c = 21.0 * k3, 10.0 * k2, 3.0 * k1
    a, b, c, r2b = np.broadcast_arrays(a, b, c, r2)
    quad = np.abs(a) > 1e-300
    disc = b * b - 4.0 * a * c
    sq = np.sqrt(np.maximum(disc, 0.0))
    safe_a = np.where(quad, a, 1.0)
    safe_b = np.where(np.abs(b) > 1e-300, b, 1.0)
    roots = [
        np.where(quad & (disc >= 0), (-b - sq) / (2.0 * safe_a), -1.0),
        np.where(quad & (disc >= 0), (-b + sq) / (2.0 * safe_a), -1.0),
        np.where(~quad & (np.abs(b) > 1e-300), -c / safe_b, -1.0),
    ]
    for s in roots:
        inside = (s > 0.0) & (s < r2b)
        ok = ok & ~(inside & (g(np.where(inside, s, 0.0)) <= 0.0))
    return ok


@functools.lru_cache(maxsize=256)
def _one_to_one_limit(k1: float, k2: float, k3: float) -> float:
    """One camera's :func:`_monotonic_radius2` as a bound: ``g`` is 1 at 0, so it stays
    positive on ``[0, r²]`` exactly when ``r²`` lies below its smallest positive root
    (∞ when it has none)."""
    coeffs = np.array([7.0 * k3, 5.0 * k2, 3.0 * k1, 1.0])
    while abs(coeffs[0]) <= 1e-12 * np.abs(coeffs).max():  # a vanishing leading term
        coeffs = coeffs[1:]
    roots = np.roots(coeffs)
    real = roots.real[(np.abs(roots.imag) <= 1e-12 * np.maximum(1.0, np.abs(roots.real)))]
    positive = real[real > 0.0]
    return float(positive.min()) if positive.size else math.inf


def project(x_cm: ArrayLike, y_cm: ArrayLike, z_cm: ArrayLike, cam: PinholeParams) -> Projection:
    """World point (cm) → pixel (row, col), the same numbers as ``cv2.projectPoints``.

    Points behind the camera (``Z_c ≤ 0``) or beyond the radius where the radial
    distortion is one-to-one get ``valid = False`` and row/col 0.
    """
    xc, yc, zc = world_to_camera(x_cm, y_cm, z_cm, cam)
    in_front = zc > MIN_DEPTH_CM
    safe = np.where(in_front, zc, 1.0)
    x, y = xc / safe, yc / safe
    xd, yd = distort_normalised(x, y, cam)
    valid = in_front & _monotonic_radius2(cam, x * x + y * y)
    col = np.where(valid, _f(cam.fx) * xd + _f(cam.cx), 0.0)
    row = np.where(valid, _f(cam.fy) * yd + _f(cam.cy), 0.0)
    return Projection(row, col, valid)


class Undistorted(NamedTuple):
    """Undistorted normalised coordinates of pixels; ``valid`` False where none exists."""

    x: FloatArray  # OpenCV x' (along columns)
    y: FloatArray  # OpenCV y' (along rows)
    valid: NDArray[np.bool_]


def undistort_normalised(row: ArrayLike, col: ArrayLike, cam: PinholeParams) -> Undistorted:
    """Pixel (row, col) → undistorted normalised (x', y'), the inverse of the distortion.

    Starts with the fixed-point iteration of ``cv2.undistortPoints``
    (``x ← (x'' − Δx_tangential)/radial``), then takes Newton steps on the full 2×2
    distortion map, and accepts a point only if it re-distorts to its pixel within
    :data:`UNDISTORT_TOL` and lies where the distortion is one-to-one.
    """
    fx, fy, cx, cy = (_f(v) for v in (cam.fx, cam.fy, cam.cx, cam.cy))
    xd = (_f(col) - cx) / fx
    yd = (_f(row) - cy) / fy
    xd, yd = np.broadcast_arrays(xd, yd)
    k1, k2, k3, p1, p2 = (_f(v) for v in (cam.k1, cam.k2, cam.k3, cam.p1, cam.p2))
    x, y = xd.copy(), yd.copy()
    with np.errstate(all="ignore"):
        for _ in range(FIXED_POINT_ITERATIONS):
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            ok = np.isfinite(radial) & (np.abs(radial) > 1e-12)
            inv = np.where(ok, 1.0 / np.where(ok, radial, 1.0), 1.0)
            x = np.where(ok, (xd - dx) * inv, x)
            y = np.where(ok, (yd - dy) * inv, y)
            bad = ~(np.isfinite(x) & np.isfinite(y))
            x, y = np.where(bad, xd, x), np.where(bad, yd, y)
        for _ in range(NEWTON_ITERATIONS):
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dradial = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2))  # (∂radial/∂x) / x
            fxd, fyd = distort_normalised(x, y, cam)
            ex, ey = fxd - xd, fyd - yd
            # Jacobian of (x'', y'') w.r.t. (x, y)
            j11 = radial + x * dradial * x + 2.0 * p1 * y + p2 * 6.0 * x
            j12 = x * dradial * y + 2.0 * p1 * x + p2 * 2.0 * y
            j21 = y * dradial * x + p1 * 2.0 * x + 2.0 * p2 * y
            j22 = radial + y * dradial * y + p1 * 6.0 * y + 2.0 * p2 * x
            det = j11 * j22 - j12 * j21
            ok = np.isfinite(det) & (np.abs(det) > 1e-12)
            sdet = np.where(ok, det, 1.0)
            x = np.where(ok, x - (j22 * ex - j12 * ey) / sdet, x)
            y = np.where(ok, y - (-j21 * ex + j11 * ey) / sdet, y)
        fxd, fyd = distort_normalised(x, y, cam)
        err = np.hypot(fxd - xd, fyd - yd)
    finite = np.isfinite(x) & np.isfinite(y) & np.isfinite(err)
    tol = UNDISTORT_TOL * np.maximum(1.0, np.hypot(xd, yd))
    x, y = np.where(finite, x, 0.0), np.where(finite, y, 0.0)
    valid = finite & (np.where(finite, err, np.inf) <= tol) & _monotonic_radius2(cam, x * x + y * y)
    return Undistorted(np.where(valid, x, 0.0), np.where(valid, y, 0.0), valid)


def back_project(
    row: ArrayLike, col: ArrayLike, cam: PinholeParams, z_cm: ArrayLike = 0.0
) -> BackProjection:
    """Pixel (row, col) → point on the horizontal plane Z = ``z_cm`` (world cm).

    Undistorts (:func:`undistort_normalised`), then intersects the ray
    ``C + s·Rᵀ·(x', y', 1)``, ``s > 0``, with the plane. Pixels with no undistorted
    point, whose ray is parallel to the plane or meets it behind the camera get
    ``valid = False`` and 0 coordinates.
    """
    return rays_on_plane(undistort_normalised(row, col, cam), cam, z_cm)


def rays_on_plane(und: Undistorted, cam: PinholeParams, z_cm: ArrayLike = 0.0) -> BackProjection:
    """Where the rays of undistorted pixels (:func:`undistort_normalised`) meet the
    plane Z = ``z_cm``: the second half of :func:`back_project`, so that one
    undistortion serves several planes."""
    R = _rotation(cam)
    # Ray direction in the world: Rᵀ·(x', y', 1).
    dX = R[..., 0, 0] * und.x + R[..., 1, 0] * und.y + R[..., 2, 0]
    dY = R[..., 0, 1] * und.x + R[..., 1, 1] * und.y + R[..., 2, 1]
    dZ = R[..., 0, 2] * und.x + R[..., 1, 2] * und.y + R[..., 2, 2]
    CX, CY, CZ = camera_centre_cm(cam)
    ok = np.abs(dZ) > 1e-12
    s = np.where(ok, (_f(z_cm) - CZ) / np.where(ok, dZ, 1.0), 0.0)
    valid = und.valid & ok & (s > 0.0)
    x_cm = np.where(valid, CX + s * dX, 0.0)
    y_cm = np.where(valid, CY + s * dY, 0.0)
    return BackProjection(x_cm, y_cm, valid)
