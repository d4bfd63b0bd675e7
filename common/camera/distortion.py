"""Radial lens distortion, paper eqs. 7–8.

``x_u = x_d·(1 + k1ρ² + k2ρ⁴ + k3ρ⁶)`` (same for y), with ρ = √(x_d² + y_d²) the
*distorted* radius in millimetres on the image plane. Pixel → world applies the factor
directly; world → pixel must solve ``g(ρ) = ρ·(1 + k1ρ² + k2ρ⁴ + k3ρ⁶) = ρ_u`` for ρ,
which :func:`distort_radius` does by safeguarded Newton iteration on the radius.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["distort_radius", "on_rising_branch", "undistort_factor"]

FloatArray = NDArray[np.float64]

_MAX_ITER = 50
_RTOL = 1e-13


def undistort_factor(rho_d: ArrayLike, k1: ArrayLike, k2: ArrayLike, k3: ArrayLike) -> FloatArray:
    """Eqs. 7–8 factor ``1 + k1ρ² + k2ρ⁴ + k3ρ⁶`` at distorted radius ρ (mm)."""
    s = np.square(np.asarray(rho_d, dtype=np.float64))
    return 1.0 + s * (np.asarray(k1) + s * (np.asarray(k2) + s * np.asarray(k3)))


def on_rising_branch(
    rho_d: ArrayLike, k1: ArrayLike, k2: ArrayLike, k3: ArrayLike
) -> NDArray[np.bool_]:
    """True where ``d/dρ [ρ·(1 + k1ρ² + k2ρ⁴ + k3ρ⁶)] > 0``: pixels the lens can image.

    Beyond the first turning point the model folds back on itself (strong barrel
    distortion, or the ρ⁶ term far outside the frame): such pixels see no world point.
    """
    s = np.square(np.asarray(rho_d, dtype=np.float64))
    k1, k2, k3 = (np.asarray(k) for k in (k1, k2, k3))
    return 1.0 + s * (3.0 * k1 + s * (5.0 * k2 + s * 7.0 * k3)) > 0


def distort_radius(
    rho_u: ArrayLike, k1: ArrayLike, k2: ArrayLike, k3: ArrayLike
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Solve eqs. 7–8 for the distorted radius: ``ρ·(1 + k1ρ² + k2ρ⁴ + k3ρ⁶) = ρ_u``.

    Newton's method from ρ = ρ_u, kept inside a bracket ``[lo, hi]`` on which g rises
    (bisection where a Newton step leaves it or g' ≤ 0). Returns ``(rho_d, ok)``; ``ok``
    is False where no root on the rising branch of g exists (strong barrel distortion
    folds the image back: such a point cannot be imaged) or the iteration did not
    converge. All inputs broadcast.
    """
    rho_u = np.asarray(rho_u, dtype=np.float64)
    k1, k2, k3 = (np.asarray(k, dtype=np.float64) for k in (k1, k2, k3))
    shape = np.broadcast_shapes(rho_u.shape, k1.shape, k2.shape, k3.shape)
    target = np.broadcast_to(rho_u, shape)

    def g(r: FloatArray) -> FloatArray:
        s = r * r
        return r * (1.0 + s * (k1 + s * (k2 + s * k3))) - target

    def dg(r: FloatArray) -> FloatArray:
        s = r * r
        return 1.0 + s * (3.0 * k1 + s * (5.0 * k2 + s * 7.0 * k3))

    # Bracket: g(0) = −ρ_u ≤ 0. Grow hi until g(hi) ≥ 0 while g stays rising.
    lo = np.zeros(shape)
    hi = np.maximum(target, 1e-12) * 1.0
    grow = np.ones(shape, dtype=bool)
    for _ in range(60):
        grow = (g(hi) < 0) & (dg(hi) > 0)
        if not grow.any():
            break
        lo = np.where(grow, hi, lo)
        hi = np.where(grow, hi * 2.0, hi)
    # Where the doubling overshot the top of the rising branch (g' ≤ 0 at hi), find that
    # top by bisection on the sign of g'; a root exists only if g reaches ρ_u there.
    overshot = (g(hi) < 0) & (dg(hi) <= 0)
    if overshot.any():
        a, b = lo.copy(), hi.copy()
        for _ in range(80):
            mid = 0.5 * (a + b)
            rising = dg(mid) > 0
            a = np.where(overshot & rising, mid, a)
            b = np.where(overshot & ~rising, mid, b)
        hi = np.where(overshot, a, hi)
    bracketed = g(hi) >= 0
    r = np.where(bracketed, np.clip(target, lo, hi), lo)
    converged = target == 0
    for _ in range(_MAX_ITER):
        gr = g(r)
        d = dg(r)
        lo = np.where(gr < 0, r, lo)
        hi = np.where(gr > 0, r, hi)
        step_ok = d > 0
        newton = r - gr / np.where(step_ok, d, 1.0)
        inside = step_ok & (newton >= lo) & (newton <= hi)
        r_new = np.where(inside, newton, 0.5 * (lo + hi))
        converged = np.abs(r_new - r) <= _RTOL * np.maximum(np.abs(target), 1e-12)
        r = r_new
        if converged.all():
            break
    ok = bracketed & converged & (dg(r) > 0)
    return np.where(ok, r, 0.0), ok
