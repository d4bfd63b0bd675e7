"""Shape descriptors of labeled components: compactness (paper eq. 13) and orientation.

Compactness, paper §3 eq. 13::

    compactness = 4π · a / p²

with ``a`` the object image area and ``p`` its estimated perimeter
(:mod:`ovis.common.vision.perimeter`); it is 1 for a disk, π/4 ≈ 0.785 for a square.

Orientation and elongation come from the central second moments of
:class:`ovis.common.vision.labeling.Components`: the eigenvalues of the covariance
``[[mu_rr, mu_rc], [mu_rc, mu_cc]]``,

    λ± = (mu_rr + mu_cc)/2 ± √(((mu_rr − mu_cc)/2)² + mu_rc²),

give ``elongation = √(λ₊/λ₋)``, and the major axis makes the angle
``θ = ½·atan2(2·mu_rc, mu_rr − mu_cc)`` with the +row axis, turning towards +col.

All functions are vectorised and broadcast over their arguments.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["MAX_ELONGATION", "axis_deg", "compactness", "orientation"]

FloatArray = NDArray[np.float64]

#: Elongation reported for degenerate (zero-width) shapes such as one-pixel-wide lines.
MAX_ELONGATION = 1e6


def compactness(area_px: ArrayLike, perimeter_px: ArrayLike) -> FloatArray:
    """Compactness ``4π·a/p²`` (paper eq. 13), ≈ 1 for a disk.

    Parameters
    ----------
    area_px : array_like of float, any shape
        Area a in pixels (>= 0).
    perimeter_px : array_like of float, broadcastable with ``area_px``
        Perimeter p in pixels (>= 0).

    Returns
    -------
    float64 array of the broadcast shape (0-d for scalar inputs)
        Where ``p == 0`` (a single pixel: compactness is undefined) the result is 0.0,
        never NaN or inf.

    Raises
    ------
    ValueError
        If any area or perimeter is negative or not finite.
    """
    a = np.asarray(area_px, dtype=np.float64)
    p = np.asarray(perimeter_px, dtype=np.float64)
    for name, v in (("area_px", a), ("perimeter_px", p)):
        if not ((v >= 0) & (v < np.inf)).all():  # NaN fails both
            raise ValueError(f"{name}: expected finite values >= 0, got {v!r}")
    return 4.0 * np.pi * a / np.where(p > 0, p * p, np.inf)  # a / ∞ = 0 where p = 0


def orientation(
    mu_rr: ArrayLike, mu_cc: ArrayLike, mu_rc: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Major-axis angle and elongation from central second moments.

    Parameters
    ----------
    mu_rr, mu_cc, mu_rc : array_like of float, broadcastable
        Area-normalised central moments (``Components.mu_rr`` …).

    Returns
    -------
    angle_rad : float64 array
        ``½·atan2(2·mu_rc, mu_rr − mu_cc)`` in (−π/2, π/2]: 0 when the major axis lies
        along +row, +π/4 along the row = col diagonal, π/2 along the column axis. For
        an isotropic shape (a disk, a square) the axis is undefined and the angle is 0.
    elongation : float64 array
        ``√(λ₊/λ₋)`` ≥ 1: 1 for a disk or a single pixel (all moments 0), capped at
        :data:`MAX_ELONGATION` for a degenerate line (λ₋ = 0).
    """
    rr = np.asarray(mu_rr, dtype=np.float64)
    cc = np.asarray(mu_cc, dtype=np.float64)
    rc = np.asarray(mu_rc, dtype=np.float64)
    half_diff = 0.5 * (rr - cc)
    angle = 0.5 * np.arctan2(rc, half_diff)
    # atan2 gives -π for mu_rc = -0.0 (or a tiny negative) with mu_rr < mu_cc: fold -π/2
    # onto π/2 so the range is (−π/2, π/2].
    angle += np.where(angle <= -0.5 * np.pi, np.pi, 0.0)
    mean = 0.5 * (rr + cc)
    radius = np.hypot(half_diff, rc)
    lam_max = mean + radius
    # λ₋ ≤ 0 < λ₊ (a line) → past the cap; λ₊ = 0 (a point, all moments 0) → 0 / tiny → 1.
    lam_min = np.maximum(np.maximum(mean - radius, lam_max / (2.0 * MAX_ELONGATION) ** 2), 1e-300)
    return angle, np.clip(np.sqrt(lam_max / lam_min), 1.0, MAX_ELONGATION)


def axis_deg(mu_rr: float, mu_cc: float, mu_rc: float) -> float:
    """:func:`orientation`'s angle of one shape, in degrees, in plain Python (a frame's
    few blobs, one at a time, cost less so than as arrays)."""
    angle = 0.5 * math.atan2(mu_rc, 0.5 * (mu_rr - mu_cc))
    return math.degrees(angle + math.pi if angle <= -0.5 * math.pi else angle)
