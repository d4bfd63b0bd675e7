"""A detection matched to the truth within the uncertainty it states.

A detection whose stated footprint uncertainty (its covariance's longest axis, 1σ) is
over :data:`POSITION_SIGMA_CM` says its position is not measurable (a solid whose foot
is hidden behind another: the frame bounds where it stands, it does not show it), and
the plain gate (:data:`GATE_CM`) cannot judge it: left unmatched by the gate, it is
matched to a true object left unmatched within its stated uncertainty (the truth's
Mahalanobis distance under that covariance, :data:`STATED_FLOOR_CM` added, within
:data:`STATED_CHI2`; no farther than :data:`STATED_CAP_CM`, its 1σ at most half that)
rather than counted spurious. Used alike by issue 36's scenes
(:mod:`~ovis.common.analysis.footprints`) and the live runs' score
(:class:`~ovis.common.analysis.evaluation.TrackingScore`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = [
    "GATE_CM",
    "POSITION_SIGMA_CM",
    "STATED_CAP_CM",
    "STATED_CHI2",
    "STATED_FLOOR_CM",
    "Located",
    "Stated",
    "leftovers_within_stated",
    "position_sigma",
    "stated_distance",
    "within_stated",
]


class Stated(Protocol):
    """A detection's footprint centre (cm) and the covariance of (x, y, h) it states
    (cm², row-major; None: none stated)."""

    x_cm: float
    y_cm: float
    covariance_cm2: list[float] | None


class Located(Protocol):
    """A true object's footprint centre (cm)."""

    x_cm: float
    y_cm: float


#: A detection more than this far (cm) from a true footprint centre is not it.
GATE_CM = 5.0
#: A detection whose footprint's stated 1σ (its covariance's longest axis) is over this
#: (cm) has a position not measurable: its 99 % ellipse (:data:`STATED_CHI2`) reaches
#: beyond :data:`GATE_CM`.
STATED_CHI2 = 9.21  # χ² of 2 degrees of freedom at 99 %
POSITION_SIGMA_CM = GATE_CM / math.sqrt(STATED_CHI2)
#: Whatever its stated uncertainty, a detection is no true object farther than this
#: (cm), and one stating a 1σ over half of it is none (it says too little).
STATED_CAP_CM = 4.0 * GATE_CM
#: Added (1σ, cm) across every direction to a stated covariance matched against the
#: truth: the footprint's target (issue 36), which a fit's covariance does not include
#: (it leaves out how far the shape fitted may be off).
STATED_FLOOR_CM = 0.5


def position_sigma(detection: Stated) -> float:
    """A detection's stated footprint uncertainty: its covariance's longest axis in the
    floor's plane (1σ, cm); NaN where it states none."""
    cov = detection.covariance_cm2
    if cov is None:
        return math.nan
    xy = np.array(cov, dtype=np.float64).reshape(3, 3)[:2, :2]
    return float(math.sqrt(max(float(np.linalg.eigvalsh(xy)[-1]), 0.0)))


def stated_distance(detection: Stated, x_cm: float, y_cm: float) -> float:
    """How far a floor point is from a detection's footprint under its stated uncertainty:
    the squared Mahalanobis distance under its covariance with :data:`STATED_FLOOR_CM`
    added across every direction (a fit's covariance leaves out how far its shape's
    footprint may be off); inf beyond :data:`STATED_CAP_CM`, with no covariance, or
    where the stated 1σ is over half that cap (it says too little to be one object)."""
    e = np.array([x_cm - detection.x_cm, y_cm - detection.y_cm])
    too_vague = not position_sigma(detection) <= 0.5 * STATED_CAP_CM  # NaN: none stated
    if too_vague or math.hypot(*e) > STATED_CAP_CM:
        return math.inf
    cov = np.array(detection.covariance_cm2, dtype=np.float64).reshape(3, 3)[:2, :2]
    return float(e @ np.linalg.solve(cov + STATED_FLOOR_CM**2 * np.eye(2), e))


def within_stated(
    objects: Sequence[Stated],
    truth: Sequence[Located],
    detections: list[int],
    truths: list[int],
) -> dict[int, int]:
    """Detections whose position is not measurable matched (optimally) to true objects
    within their stated uncertainty (:func:`stated_distance` within
    :data:`STATED_CHI2`): true index → detection index."""
    if not detections or not truths:
        return {}
    cost = np.array(
        [
            [stated_distance(objects[j], truth[i].x_cm, truth[i].y_cm) for j in detections]
            for i in truths
        ]
    )
    cost[cost > STATED_CHI2] = np.inf
    if not np.isfinite(cost).any():
        return {}
    rows, cols = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e12))
    return {
        truths[a]: detections[b] for a, b in zip(rows, cols, strict=True) if np.isfinite(cost[a, b])
    }


def leftovers_within_stated(
    objects: Sequence[Stated], truth: Sequence[Located], matched: dict[int, int]
) -> dict[int, int]:
    """:func:`within_stated` of what the gate left (``matched``: true index → detection
    index): the detections left over whose position is not measurable (stated 1σ over
    :data:`POSITION_SIGMA_CM`) against the true objects left over."""
    taken = set(matched.values())
    vague = [
        j
        for j, d in enumerate(objects)
        if j not in taken
        and getattr(d, "covariance_cm2", None) is not None
        and position_sigma(d) > POSITION_SIGMA_CM
    ]
    if not vague:
        return {}
    return within_stated(objects, truth, vague, [i for i in range(len(truth)) if i not in matched])
