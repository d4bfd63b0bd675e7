"""The calibrator's bookkeeping: the last frames (raw) and their ground truth, which
frame a request calibrates on, its control points and GA settings, and the reply."""

from __future__ import annotations

import collections
import threading
from typing import Any, NamedTuple

from ovis.common.calibration.file import Calibration
from ovis.common.camera.projection import camera_parameters
from ovis.common.config import ControlPoint, OvisConfig, with_ga
from ovis.common.messages import CalibrateReply, CalibrateRequest, TruthFrame
from ovis.common.sim.arena import control_points

__all__ = [
    "KEEP_FRAMES",
    "TRUTH_WAIT_S",
    "FrameKeeper",
    "Picked",
    "calibrate_reply",
    "config_for_request",
    "missing_frame",
    "points_for",
]

KEEP_FRAMES = 64
TRUTH_WAIT_S = 1.0  # how long a named frame's ground truth may trail the frame


def missing_frame(seq: int, first: int, last: int) -> str:
    """Why frame ``seq`` is not among the kept frames ``first``..``last``."""
    if seq < first:
        return f"frame {seq} is gone: the calibrator keeps the last {KEEP_FRAMES} ({first}–{last})"
    return (
        f"frame {seq} never reached the calibrator (it has {first}–{last}; a frame the bus "
        "dropped, or a number from another run); ask without a frame for the newest"
    )


class Picked(NamedTuple):
    """The frame a request calibrates on: its payload and truth, or why there is none."""

    seq: int | None
    payload: bytes | None
    truth: TruthFrame | None
    error: str = ""


class FrameKeeper:
    """The last :data:`KEEP_FRAMES` frames (raw payloads: the image is decoded only when
    a calibration needs it) and ground truths, by sequence number; thread-safe.

    With ``needs_truth`` (control points from the simulator's ground truth), the frame
    chosen by default is the newest that has its truth: the capture publishes a frame
    just before its truth, so the very newest may not have it yet."""

    def __init__(self, needs_truth: bool, keep: int = KEEP_FRAMES) -> None:
        self.needs_truth = needs_truth
        self.keep = keep
        self.frames: collections.OrderedDict[int, bytes] = collections.OrderedDict()
        self.truths: collections.OrderedDict[int, TruthFrame] = collections.OrderedDict()
        self.first_frame = threading.Event()
        self._cond = threading.Condition()  # notified when frames or truths grow

    def _keep(self, store: collections.OrderedDict[int, Any], seq: int, item: Any) -> None:
        with self._cond:
            store[seq] = item
            while len(store) > self.keep:
                store.popitem(last=False)
            self._cond.notify_all()

    def add_frame(self, seq: int, payload: bytes) -> None:
        self._keep(self.frames, seq, payload)
        self.first_frame.set()

    def add_truth(self, truth: TruthFrame) -> None:
        self._keep(self.truths, truth.seq, truth)

    def _newest_usable(self) -> int:
        for seq in reversed(self.frames):
            if not self.needs_truth or seq in self.truths:
                return seq
        return next(reversed(self.frames))

    def pick(self, seq: int | None, truth_wait_s: float = TRUTH_WAIT_S) -> Picked:
        """Frame ``seq`` (None: the newest usable one) with its truth; a truth still on
        its way is waited for up to ``truth_wait_s``."""
        with self._cond:
            if not self.frames:
                return Picked(None, None, None, "no frame received yet from capture")
            if seq is None:
                seq = self._newest_usable()
            if self.needs_truth:
                want = seq
                self._cond.wait_for(
                    lambda: want in self.truths or want not in self.frames, truth_wait_s
                )
            payload, truth = self.frames.get(seq), self.truths.get(seq)
            kept = next(iter(self.frames)), next(reversed(self.frames))
        if payload is None:
            return Picked(seq, None, None, missing_frame(seq, *kept))
        return Picked(seq, payload, truth)


def points_for(
    seq: int, file_points: list[ControlPoint] | None, truth: TruthFrame | None
) -> list[ControlPoint] | str:
    """The control points of frame ``seq``: the points file's, else its ground truth's;
    or why there are none."""
    if file_points is not None:
        return file_points
    if truth is not None:
        return control_points(truth)
    return (
        f"no control points: no ground truth for frame {seq} within "
        f"{TRUTH_WAIT_S:g} s (the simulator sends it); for a real camera set "
        "service.points to a points file"
    )


def config_for_request(config: OvisConfig, request: CalibrateRequest) -> OvisConfig:
    """The configuration with the GA settings the request overrides (seed, population,
    generations)."""
    return with_ga(
        config, seed=request.seed, population=request.population, generations=request.generations
    )


#: The reply's fields that are the calibration's own.
_FROM_CALIBRATION = ("version", "dipe_px", "dipe_mm", "dipe_max_px", "elapsed_s")


def calibrate_reply(calib: Calibration, seq: int, saved_to: str) -> CalibrateReply:
    """The reply to a calibration that worked: version, DIPE, the camera's parameters
    with the threshold and size filter, and where it was saved."""
    params = camera_parameters(calib.camera)
    params["threshold"] = float(calib.image.threshold)
    params["size_filter_cm2"] = calib.image.size_filter_cm2
    same = {name: getattr(calib, name) for name in _FROM_CALIBRATION}
    return CalibrateReply(ok=True, frame_seq=seq, parameters=params, saved_to=saved_to, **same)
