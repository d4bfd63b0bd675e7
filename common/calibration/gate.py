"""The quality gate a new calibration passes before the calibrator publishes it.

A GA run always returns its best camera, even on control points that lie (a client that
republished the ground truth shifted, scaled or with its axes swapped) or with settings
that make the pipeline blind (a threshold no pixel reaches, top planes far above the
objects). Such a candidate is compared with the calibration in use, on the frame it was
fitted on, and refused when:

* its mean DIPE is not believable for any camera (above
  :data:`~ovis.common.calibration.plausibility.MAX_MEAN_DIPE_PX`), or — unless forced —
  both above :data:`DIPE_FLOOR_PX` and more than :data:`MAX_DIPE_RATIO` times the current
  one's. A refit of the same camera on its own control points misses them by the same
  centroid noise as before; below one pixel every fit is at the precision the pixel grid
  allows, so no ratio is asked there;
* it sees nothing where the current calibration sees objects (forced or not);
* unless forced, it does not see the objects the current calibration sees where that one
  sees them: each must be matched one-to-one by a candidate object inside its footprint
  (its radius, at least :data:`MIN_MATCH_CM`), and the candidate may not see more
  objects than the current one. ``force`` is for a camera that really moved: then the
  current calibration's positions are wrong, and only the absolute checks hold.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy.optimize import linear_sum_assignment

from ovis.common.calibration.plausibility import MAX_MEAN_DIPE_PX

__all__ = [
    "DIPE_FLOOR_PX",
    "MAX_DIPE_RATIO",
    "MIN_MATCH_CM",
    "Seen",
    "dipe_problem",
    "gate_problem",
    "sight_problem",
]

#: A candidate more than this many times worse (mean DIPE) than the current calibration
#: is refused unless forced.
MAX_DIPE_RATIO = 3.0
#: Mean DIPE below which no ratio is asked (px): the pixel grid's own precision.
DIPE_FLOOR_PX = 1.0
#: The smallest distance (cm) within which an object counts as seen at the same place.
MIN_MATCH_CM = 2.0


class Seen(NamedTuple):
    """An object one calibration sees on the calibration frame: floor position, radius."""

    x_cm: float
    y_cm: float
    radius_cm: float


def dipe_problem(candidate_px: float, current_px: float | None, force: bool = False) -> str | None:
    """Why the candidate's mean DIPE is not acceptable next to the current one's (None:
    there is no current calibration), or None."""
    now = "" if current_px is None else f" vs {current_px:.3g} px"
    if not math.isfinite(candidate_px) or candidate_px > MAX_MEAN_DIPE_PX:
        return (
            f"DIPE {candidate_px:.3g} px{now}: above {MAX_MEAN_DIPE_PX:g} px, the camera "
            "does not explain the control points"
        )
    if force or current_px is None:
        return None
    allowed = max(MAX_DIPE_RATIO * current_px, DIPE_FLOOR_PX)
    if candidate_px > allowed:
        return (
            f"DIPE {candidate_px:.3g} px{now}: more than {MAX_DIPE_RATIO:g}x worse than the "
            "current calibration (send force to publish it anyway)"
        )
    return None


def _matches(current: list[Seen], candidate: list[Seen]) -> tuple[int, float]:
    """How many current objects a distinct candidate object sees inside their footprint
    (the most such pairs, then the least total distance), and the largest offset of a
    current object to its nearest candidate object (cm)."""
    if not (current and candidate):
        return 0, math.inf if current else 0.0
    now = np.array([(a.x_cm, a.y_cm) for a in current])
    new = np.array([(b.x_cm, b.y_cm) for b in candidate])
    dist = np.hypot(now[:, None, 0] - new[None, :, 0], now[:, None, 1] - new[None, :, 1])
    gate = np.maximum([a.radius_cm for a in current], MIN_MATCH_CM)[:, None]
    inside = dist <= gate  # (NaN: never)
    # a pair outside costs more than all inside pairs together: the most pairs first
    outside = 1.0 + float(np.sum(dist[inside]))
    rows, cols = linear_sum_assignment(np.where(inside, dist, outside))
    return int(inside[rows, cols].sum()), float(dist.min(axis=1).max())


def sight_problem(candidate: list[Seen], current: list[Seen], force: bool = False) -> str | None:
    """Why the candidate does not see what the current calibration sees, or None."""
    if current and not candidate:
        return f"sees no object on its frame, the current calibration sees {len(current)}"
    if force or not current:
        return None
    matched, offset = _matches(current, candidate)
    if matched < len(current) or len(candidate) > len(current):
        return (
            f"sees {len(candidate)} objects, {matched} of the current calibration's "
            f"{len(current)} where it sees them (largest offset {offset:.1f} cm; send force "
            "if the camera moved)"
        )
    return None


def gate_problem(
    candidate_dipe_px: float,
    current_dipe_px: float | None,
    candidate_seen: list[Seen],
    current_seen: list[Seen],
    force: bool = False,
) -> str | None:
    """Why a candidate must not be published (one line naming the check and its numbers),
    or None. ``current_dipe_px`` None: there is no calibration in use yet."""
    problem = dipe_problem(candidate_dipe_px, current_dipe_px, force) or sight_problem(
        candidate_seen, current_seen, force
    )
    return None if problem is None else f"rejected candidate: {problem}"
