"""Accuracy against ground truth: detections matched to known objects.

Used by the demo, the tests and the services' end-of-run summary: each true object is
matched to the nearest detection by an optimal assignment on floor position; an
unmatched true object is *missed*, an unmatched detection is *spurious*. A run's score
(:class:`TrackingScore`) matches a detection whose position is not measurable within the
uncertainty it states (:mod:`~ovis.common.analysis.stated`) and counts it apart.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple, Protocol

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from ovis.common.analysis.stated import leftovers_within_stated, position_sigma

__all__ = ["FrameAccuracy", "TrackingScore", "height_basis", "match_objects", "match_to_truth"]


class FrameAccuracy(NamedTuple):
    """Errors of one frame's detections against its ground truth."""

    position_error_cm: NDArray[np.float64]  # per matched true object
    radius_error_cm: NDArray[np.float64]  # detected − true, per matched true object
    kind_correct: NDArray[np.bool_]  # per matched true object
    truth_index: NDArray[np.int64]  # matched true objects
    detection_index: NDArray[np.int64]  # the detections matched to them
    missed: int
    spurious: int


def match_to_truth(
    detected_xyr: NDArray[np.float64] | Sequence[Sequence[float]],
    detected_kind: Sequence[str],
    true_xyr: NDArray[np.float64] | Sequence[Sequence[float]],
    true_kind: Sequence[str],
    *,
    gate_cm: float = 5.0,
) -> FrameAccuracy:
    """Match detections (N, 3: x, y, r in cm) to true objects (M, 3) within ``gate_cm``."""
    det = np.asarray(detected_xyr, dtype=np.float64).reshape(-1, 3)
    tru = np.asarray(true_xyr, dtype=np.float64).reshape(-1, 3)
    if det.shape[0] == 0 or tru.shape[0] == 0:
        empty = np.zeros(0)
        idx = np.zeros(0, dtype=np.int64)
        return FrameAccuracy(empty, empty, np.zeros(0, bool), idx, idx, tru.shape[0], det.shape[0])
    cost = np.linalg.norm(tru[:, None, :2] - det[None, :, :2], axis=2)
    ti, di = linear_sum_assignment(cost)
    ok = cost[ti, di] <= gate_cm
    ti, di = ti[ok], di[ok]
    kinds_t = np.asarray(true_kind)[ti]
    kinds_d = np.asarray(detected_kind)[di]
    return FrameAccuracy(
        position_error_cm=cost[ti, di],
        radius_error_cm=det[di, 2] - tru[ti, 2],
        kind_correct=kinds_t == kinds_d,
        truth_index=ti.astype(np.int64),
        detection_index=di.astype(np.int64),
        missed=int(tru.shape[0] - ti.size),
        spurious=int(det.shape[0] - di.size),
    )


class FloorObject(Protocol):
    """What both a detection and a ground-truth object have."""

    kind: str
    x_cm: float
    y_cm: float
    radius_cm: float


def match_objects(
    detected: Sequence[FloorObject], truth: Sequence[FloorObject], *, gate_cm: float = 5.0
) -> FrameAccuracy:
    """:func:`match_to_truth` on objects (detections, simulator truth) directly."""
    return match_to_truth(
        [(o.x_cm, o.y_cm, o.radius_cm) for o in detected],
        [o.kind for o in detected],
        [(o.x_cm, o.y_cm, o.radius_cm) for o in truth],
        [o.kind for o in truth],
        gate_cm=gate_cm,
    )


class TrackedObject(FloorObject, Protocol):
    """A floor object with an identity (a detection's id, the simulator's object id) and
    the height of its top (``z_cm``: a detection's measured or configured one)."""

    id: int
    z_cm: float


def height_basis(detection: object) -> str:
    """What a detection's ``z_cm`` rests on: its ``z_source`` ("one camera", "cameras",
    "marker"), or "configured" with why it is not measured ("configured (pending)": its
    fit is still to come, its position then its centroid on its class's plane)."""
    source = str(getattr(detection, "z_source", "configured"))
    why = str(getattr(detection, "z_unmeasured", ""))
    return f"{source} ({why})" if source == "configured" and why else source


class TrackingScore:
    """Detections of many frames against their ground truth, added up: position, radius
    and height errors of the matched objects (height: the detection's ``z_cm`` less the
    true top's) and what each matched detection's height rests on (:func:`height_basis`),
    missed, spurious and mislabelled ones, and identity switches (a true object whose
    matched detection changes id). A detection whose position is not measurable (its
    stated 1σ over :data:`~ovis.common.analysis.stated.POSITION_SIGMA_CM`), left over by
    the gate, is matched within its stated uncertainty: counted in ``within_stated``, its
    error and stated 1σ kept apart (``stated_error_cm``, ``stated_sigma_cm``), not in
    the position errors, nor missed or spurious."""

    def __init__(self) -> None:
        self.position_error_cm: list[float] = []
        self.radius_error_cm: list[float] = []
        self.height_error_cm: list[float] = []
        self.height_basis: list[str] = []
        self.kind_correct: list[bool] = []
        self.matched = self.missed = self.spurious = self.wrong_kind = self.id_switches = 0
        self.within_stated = 0
        self.stated_error_cm: list[float] = []
        self.stated_sigma_cm: list[float] = []
        self._id_of: dict[int, int] = {}  # true id -> the detection id it was matched to

    def add(
        self, detected: Sequence[TrackedObject], truth: Sequence[TrackedObject]
    ) -> FrameAccuracy:
        """Score one frame; its accuracy."""
        acc = match_objects(detected, truth)
        self.position_error_cm.extend(acc.position_error_cm.tolist())
        self.radius_error_cm.extend(acc.radius_error_cm.tolist())
        self.height_error_cm.extend(
            detected[di].z_cm - truth[ti].z_cm
            for ti, di in zip(acc.truth_index, acc.detection_index, strict=True)
        )
        self.height_basis.extend(height_basis(detected[di]) for di in acc.detection_index)
        self.kind_correct.extend(acc.kind_correct.tolist())
        self.matched += int(acc.truth_index.size)
        stated = self._within_stated(detected, truth, acc)
        self.missed += acc.missed - len(stated)
        self.spurious += acc.spurious - len(stated)
        self.wrong_kind += int((~acc.kind_correct).sum())
        for ti, di in zip(acc.truth_index, acc.detection_index, strict=True):
            true_id, det_id = truth[ti].id, detected[di].id
            if self._id_of.setdefault(true_id, det_id) != det_id:
                self.id_switches += 1
                self._id_of[true_id] = det_id
        return acc

    def _within_stated(
        self, detected: Sequence[TrackedObject], truth: Sequence[TrackedObject], acc: FrameAccuracy
    ) -> dict[int, int]:
        """The gate's leftovers whose position is not measurable, matched within their
        stated uncertainty (true index → detection index), counted."""
        if not acc.missed or not acc.spurious:
            return {}
        matched = dict(zip(acc.truth_index.tolist(), acc.detection_index.tolist(), strict=True))
        stated = leftovers_within_stated(detected, truth, matched)
        for i, j in stated.items():
            d, t = detected[j], truth[i]
            self.stated_error_cm.append(float(np.hypot(d.x_cm - t.x_cm, d.y_cm - t.y_cm)))
            self.stated_sigma_cm.append(position_sigma(d))
        self.within_stated += len(stated)
        return stated
