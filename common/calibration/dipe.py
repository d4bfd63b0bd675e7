"""Distorted Image Plane Error, paper eq. 14, with optimal blob-to-point matching.

DIPE of one control point is the pixel distance between where its object was detected
(the blob centroid after thresholding and size filtering) and where the camera model
projects it: ``√((x'_f − x_f)² + (y'_f − y_f)²)``. Blobs are matched to control points
by the assignment that minimises the total error (model-notes §4), not by label order.
In millimetres, an error is ``√((Δrow·d_x)² + (Δcol·d_y)²)``.
"""

from __future__ import annotations

import itertools
from functools import cache
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

__all__ = ["Matching", "match_points", "pixel_error_mm"]

#: Up to this many points, every permutation is tried at once (vectorised over the
#: population); above it, one Hungarian solve per candidate.
MAX_PERMUTATION_POINTS = 6


class Matching(NamedTuple):
    """Per candidate (F) and control point (N): the matched blob and its DIPE in pixels."""

    blob_index: NDArray[np.int64]  # (F, N)
    dipe_px: NDArray[np.float64]  # (F, N)


@cache
def _permutations(n: int) -> NDArray[np.int64]:
    return np.array(list(itertools.permutations(range(n))), dtype=np.int64).reshape(-1, n)


def match_points(
    pred_row: NDArray[np.float64],
    pred_col: NDArray[np.float64],
    blob_row: NDArray[np.float64],
    blob_col: NDArray[np.float64],
) -> Matching:
    """Optimal one-to-one matching of N predicted points to N blobs, per candidate.

    All inputs have shape (F, N): F candidates (e.g. GA strings), N control points and
    exactly N blobs each. Returns the blob index matched to each point and the DIPE
    (eq. 14) of each point in pixels.
    """
    F, N = pred_row.shape
    dr = pred_row[:, :, None] - blob_row[:, None, :]
    dc = pred_col[:, :, None] - blob_col[:, None, :]
    cost = np.hypot(dr, dc)  # (F, point, blob)
    if N <= MAX_PERMUTATION_POINTS:
        perms = _permutations(N)  # (K, N): perms[k, i] = blob of point i
        totals = cost[:, np.arange(N), perms].sum(axis=2)  # (F, K)
        best = perms[np.argmin(totals, axis=1)]
    else:
        best = np.empty((F, N), dtype=np.int64)
        for f in range(F):  # large N only: one Hungarian solve per candidate
            _, cols = linear_sum_assignment(cost[f])
            best[f] = cols
    dipe = np.take_along_axis(cost, best[:, :, None], axis=2)[:, :, 0]
    return Matching(best, dipe)


def pixel_error_mm(
    d_row: NDArray[np.float64], d_col: NDArray[np.float64], d_x_mm: float, d_y_mm: float
) -> NDArray[np.float64]:
    """Pixel offsets (Δrow, Δcol) as a length on the image plane, mm (pixels × d)."""
    return np.hypot(np.asarray(d_row) * d_x_mm, np.asarray(d_col) * d_y_mm)
