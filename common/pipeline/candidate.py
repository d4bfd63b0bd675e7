"""The calibrator's publishing decision: the candidate calibration's DIPE against the
current one's first (cheap), then what each sees on the frame the candidate was fitted
on, through the live stages' own steps, passed through the quality gate
(:mod:`ovis.common.calibration.gate`)."""

from __future__ import annotations

import time

import numpy as np
from numpy.typing import NDArray

from ovis.common.calibration.file import Calibration
from ovis.common.calibration.gate import Seen, dipe_problem, gate_problem
from ovis.common.messages import Frame
from ovis.common.pipeline.stages import (
    SizeFilter,
    binary_frame,
    blob_list,
    obstacle_frame,
    wrong_size,
)
from ovis.common.vision.frames import ImageError, as_gray
from ovis.common.world.detection import Detector
from ovis.common.world.marker_search import BlobMarkers

__all__ = ["judge_candidate", "seen_by"]


def seen_by(calib: Calibration, image: NDArray[np.uint8]) -> list[Seen]:
    """The objects ``calib`` sees on ``image`` (robots and obstacles alike) as the live
    stages would: the preprocess stage's binarization, the label stage's blobs and
    markers, the pose stage's objects."""
    gray = as_gray(image)
    frame = Frame.from_image(gray, seq=0, stamp_ns=time.time_ns(), copy=False)
    problem = wrong_size(frame, calib.camera, "calibration frame")
    if problem is not None:
        raise ImageError(problem)
    markers = BlobMarkers()
    binary = binary_frame(frame, gray, calib, markers)
    blobs = blob_list(binary, calib, SizeFilter().min_area_px(calib), markers)
    detector = Detector(calib.camera, calib.image, calib.pose)
    seen = obstacle_frame(blobs, detector, calib.version, "", frame.stamp_ns)
    objects = ([seen.robot] if seen.robot is not None else []) + seen.obstacles
    return [Seen(o.x_cm, o.y_cm, o.radius_cm) for o in objects]


def judge_candidate(
    candidate: Calibration,
    current: Calibration | None,
    image: NDArray[np.uint8],
    force: bool = False,
) -> str | None:
    """Why ``candidate`` must not replace ``current`` (None: no calibration in use yet),
    judged on ``image``, the frame it was fitted on; or None. A DIPE refused needs no
    detection."""
    now_dipe = current.dipe_px if current is not None else None
    if dipe_problem(candidate.dipe_px, now_dipe, force) is not None:
        return gate_problem(candidate.dipe_px, now_dipe, [], [], force)
    now_seen = seen_by(current, image) if current is not None else []
    return gate_problem(candidate.dipe_px, now_dipe, seen_by(candidate, image), now_seen, force)
