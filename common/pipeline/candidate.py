"""The calibrator's publishing decision: run detection with the candidate calibration and
with the current one on the frame the candidate was fitted on, and pass both, with their
DIPEs, through the quality gate (:mod:`ovis.common.calibration.gate`)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ovis.common.calibration.file import Calibration
from ovis.common.calibration.gate import Seen, gate_problem
from ovis.common.world.detection import Detector

__all__ = ["judge_candidate", "seen_by"]


def seen_by(calib: Calibration, image: NDArray[np.uint8]) -> list[Seen]:
    """The objects ``calib`` sees on ``image`` (robots and obstacles alike)."""
    detection = Detector(calib.camera, calib.image, calib.pose).detect(image)
    return [Seen(o.x_cm, o.y_cm, o.radius_cm) for o in detection.objects]


def judge_candidate(
    candidate: Calibration,
    current: Calibration | None,
    image: NDArray[np.uint8],
    force: bool = False,
) -> str | None:
    """Why ``candidate`` must not replace ``current`` (None: no calibration in use yet),
    judged on ``image``, the frame it was fitted on; or None."""
    now_seen = seen_by(current, image) if current is not None else []
    return gate_problem(
        candidate.dipe_px,
        current.dipe_px if current is not None else None,
        seen_by(candidate, image),
        now_seen,
        force,
    )
