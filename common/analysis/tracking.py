"""Detection with identities over a simulated run, scored against the simulator's
ground truth frame by frame (what ``ovis demo`` reports)."""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ovis.common.analysis.evaluation import TrackingScore
from ovis.common.sim.arena import Arena
from ovis.common.world.detection import Detection, Detector

__all__ = ["TrackingRun", "track_simulated"]


class TrackingRun(NamedTuple):
    """The score of a run, each frame's detection time (s), and the last frame."""

    score: TrackingScore
    detect_s: NDArray[np.float64]
    last_frame: NDArray[np.uint8] | None
    last_detection: Detection | None


def track_simulated(arena: Arena, detector: Detector, frames: int) -> TrackingRun:
    """Step ``arena`` ``frames`` times; detect on each frame (timing only the detection)
    and score it against the frame's truth."""
    score = TrackingScore()
    times: list[float] = []
    frame = det = None
    for _ in range(frames):
        arena.step()
        frame, truth = arena.render()
        t0 = time.perf_counter()
        det = detector.detect(frame)
        times.append(time.perf_counter() - t0)
        score.add(det.objects, truth.objects)
    return TrackingRun(score, np.asarray(times), frame, det)
