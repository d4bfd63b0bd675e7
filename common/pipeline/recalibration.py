"""The calibrator's bookkeeping: the last frames (raw) and their ground truth, which
frame a request calibrates on, its control points and GA settings, the limits a request
must respect, the one running calibration (its progress, cancel and time budget) and
the replies."""

from __future__ import annotations

import collections
import math
import threading
import time
from collections.abc import Callable
from typing import Any, NamedTuple

from ovis.common.calibration.file import Calibration
from ovis.common.camera.projection import camera_parameters
from ovis.common.config import ControlPoint, OvisConfig, with_ga
from ovis.common.messages import CalibrateReply, CalibrateRequest, TruthFrame
from ovis.common.sim.arena import control_points

__all__ = [
    "KEEP_FRAMES",
    "TRUTH_WAIT_S",
    "CalibrationCancelledError",
    "CalibrationJob",
    "FrameKeeper",
    "Picked",
    "calibrate_reply",
    "config_for_request",
    "missing_frame",
    "points_for",
    "too_big",
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


def too_big(config: OvisConfig) -> str | None:
    """Why the GA of ``config`` (with a query's overrides) is larger than the
    calibrator runs (``[service] max_population``, ``max_evaluations``), or None."""
    ga, limits = config.ga, config.service
    if ga.population > limits.max_population:
        return (
            f"refused: population {ga.population} is above this calibrator's limit "
            f"{limits.max_population} ([service] max_population)"
        )
    if ga.population * ga.generations > limits.max_evaluations:
        return (
            f"refused: population x generations = {ga.population} x {ga.generations} = "
            f"{ga.population * ga.generations} is above this calibrator's limit "
            f"{limits.max_evaluations} ([service] max_evaluations)"
        )
    return None


class CalibrationCancelledError(Exception):
    """A running calibration was stopped (a cancel query, its time budget, shutdown)."""


class CalibrationJob:
    """The one calibration that may run at a time: claimed when a query is accepted,
    then its progress per GA generation (for the "busy" answer to other queries), and
    the reason to stop it, checked after every generation (thread-safe)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._lock = threading.Lock()
        self.running = False
        self.frame_seq: int | None = None
        self.generations = 0
        self.generation = 0
        self.started = 0.0
        self.budget_s = math.inf
        self._stop_reason = ""

    def claim(self) -> bool:
        """Take the job for a new calibration; False when one is already running."""
        with self._lock:
            if self.running:
                return False
            self.running, self.frame_seq, self.generation, self._stop_reason = True, None, 0, ""
            self.started = self._clock()
            return True

    def start(self, frame_seq: int, generations: int, budget_s: float) -> None:
        """The claimed calibration starts on ``frame_seq``."""
        with self._lock:
            self.frame_seq, self.generations, self.budget_s = frame_seq, generations, budget_s
            self.generation, self.started = 0, self._clock()

    def done(self) -> None:
        with self._lock:
            self.running = False

    def cancel(self, reason: str) -> bool:
        """Ask the running calibration to stop after its current generation."""
        with self._lock:
            if not self.running:
                return False
            self._stop_reason = reason
            return True

    def after_generation(self, generation: int) -> None:
        """Called by the GA after each generation: raises CalibrationCancelledError when
        asked to stop, or when the time budget is spent."""
        with self._lock:
            self.generation = generation
            elapsed = self._clock() - self.started
            reason = self._stop_reason
            if not reason and elapsed > self.budget_s:
                reason = (
                    f"its time budget of {self.budget_s:g} s is spent "
                    "([service] calibration_budget_s)"
                )
        if reason:
            raise CalibrationCancelledError(
                f"calibration cancelled after {elapsed:.1f} s, generation {generation} of "
                f"{self.generations}: {reason}"
            )

    def busy_reply(self) -> CalibrateReply:
        """The answer to a query while a calibration runs: what it does and when it
        should be done."""
        with self._lock:
            elapsed = self._clock() - self.started
            if self.frame_seq is None or not self.generations:
                what, progress, eta = "preparing a calibration", 0.0, None
            else:
                progress = min(1.0, self.generation / self.generations)
                eta = elapsed * (1 - progress) / progress if progress > 0 else None
                what = (
                    f"calibrating on frame {self.frame_seq}: generation {self.generation} "
                    f"of {self.generations}"
                )
        eta_text = f", about {eta:.0f} s to go" if eta is not None else ""
        return CalibrateReply(
            ok=False,
            busy=True,
            frame_seq=self.frame_seq if self.frame_seq is not None else -1,
            progress=round(progress, 4),
            eta_s=None if eta is None else round(eta, 2),
            error=(
                f"busy: {what}{eta_text}; ask again then, or send a cancel request "
                "(`ovis recalibrate --cancel`)"
            ),
        )
