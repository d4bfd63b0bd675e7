"""Health that tells the truth. A stage's own verdict (:func:`stage_verdict`): input that
yields no output, or fails mostly, makes it "failing" or "degraded" with the reason.
And the stream's health, as the pose stage publishes it on ``ovis/<arena>/health``:
"waiting" (no frame yet), "ok" (a frame within the timeout), "stalled", "source lost"
(the capture says its source failed, and why: :class:`SourceWatch`), or the pose
stage's own "degraded"/"failing", so that a consumer can tell "no obstacles" from "no
data" and from "wrong data"."""

from __future__ import annotations

import itertools
import secrets
import time
from collections.abc import Iterable

from ovis.common.messages import SourceState, StreamHealth

__all__ = [
    "DEGRADED_FRACTION",
    "FAILING_FRACTION",
    "HEALTH_WINDOW_S",
    "MIN_INPUTS",
    "SERVICE_STATE",
    "SOURCE_FRESH_S",
    "SOURCE_REPEAT_S",
    "SourceWatch",
    "StreamWatch",
    "Verdict",
    "stage_verdict",
]

#: A stage's verdict is over the inputs of the last this many seconds: a stage that
#: starts failing says so within this window plus one status period.
HEALTH_WINDOW_S = 1.0
#: Fewer inputs than this in the window: too few to judge (the stream's own state rules).
MIN_INPUTS = 3
#: Share of the window's inputs that failed above which the stage is "failing" …
FAILING_FRACTION = 0.5
#: … or "degraded".
DEGRADED_FRACTION = 0.1

Verdict = tuple[str, str]  # (state, reason); ("ok", "") when nothing is wrong


def stage_verdict(
    outcomes: Iterable[tuple[float, bool]], now: float, last_error: str = ""
) -> Verdict:
    """Judge a stage by its recent inputs, ``(monotonic time, produced an output?)``:
    "failing" when none of at least :data:`MIN_INPUTS` gave an output or more than
    :data:`FAILING_FRACTION` failed, "degraded" above :data:`DEGRADED_FRACTION`."""
    recent = [ok for t, ok in outcomes if now - t <= HEALTH_WINDOW_S]
    if len(recent) < MIN_INPUTS:
        return "ok", ""
    failed = recent.count(False)
    share = failed / len(recent)
    why = f" (last error: {last_error})" if last_error else ""
    if failed == len(recent):
        return "failing", f"{len(recent)} inputs in {HEALTH_WINDOW_S:g} s, no output{why}"
    if share > FAILING_FRACTION:
        return "failing", f"{failed} of {len(recent)} inputs failed{why}"
    if share > DEGRADED_FRACTION:
        return "degraded", f"{failed} of {len(recent)} inputs failed{why}"
    return "ok", ""


#: The service's state (in its status) for each stream state.
SERVICE_STATE = {
    "ok": "ok",
    "stalled": "no frames",
    "waiting": "waiting",
    "source lost": "source lost",
}

#: The capture repeats its ``source`` message this often, seconds, while its source is
#: lost (and sends one at once whenever the source fails or delivers again).
SOURCE_REPEAT_S = 0.5
#: A "source lost" heard longer ago than this, seconds, no longer counts: the capture
#: that said it has gone quiet, and the frames' own state rules.
SOURCE_FRESH_S = 4 * SOURCE_REPEAT_S


class SourceWatch:
    """The capture's latest word on its source (its :class:`SourceState` messages), as
    a stage downstream hears it."""

    def __init__(self, fresh_s: float = SOURCE_FRESH_S) -> None:
        self.fresh_s = fresh_s
        self._heard: tuple[SourceState, float] | None = None

    def hear(self, msg: SourceState, now: float) -> bool:
        """Take a message heard at ``now`` (monotonic seconds); True when it changes
        what :meth:`lost` says."""
        before = self.lost(now)
        self._heard = (msg, now)
        return self.lost(now) != before

    def lost(self, now: float) -> str | None:
        """Why the source is lost, or None: not lost, or not said within ``fresh_s``."""
        heard = self._heard
        if heard is None or heard[0].state != "source lost" or now - heard[1] > self.fresh_s:
            return None
        return heard[0].reason or "the capture gave no reason"


class StreamWatch:
    """Follows the time since the last frame and whether the source is lost; says when
    the stream's state changes."""

    def __init__(self, timeout_s: float) -> None:
        self.timeout_s = timeout_s
        self.state = "waiting"
        self.reason = ""  # why the source is lost
        self.stream = secrets.token_hex(8)  # this run's health messages, numbered
        self._numbers = itertools.count()

    def classify(self, seconds_since_frame: float | None) -> str:
        """The stream's state ``seconds_since_frame`` after the last frame (None: none yet)."""
        if seconds_since_frame is None:
            return "waiting"
        return "ok" if seconds_since_frame <= self.timeout_s else "stalled"

    def update(self, seconds_since_frame: float | None, source_lost: str | None = None) -> bool:
        """Take the time since the last frame and why the source is lost (None: it is
        not); True when the state or that reason changed."""
        state = "source lost" if source_lost is not None else self.classify(seconds_since_frame)
        reason = source_lost or ""
        changed = (state, reason) != (self.state, self.reason)
        self.state, self.reason = state, reason
        return changed

    def message(
        self,
        *,
        last_seq: int | None,
        seconds_since_frame: float | None,
        last_frame_age_ms: float | None,
        frames_dropped: int,
        calibration_version: int,
        verdict: Verdict = ("ok", ""),
    ) -> StreamHealth:
        """The health message for the current state; a stage that receives frames but
        is not "ok" itself (``verdict``) says that instead of "ok"."""
        state, reason = self.state, self.reason
        if state == "ok" and verdict[0] in ("degraded", "failing"):
            state, reason = verdict  # a service state ("waiting for input", …) is no verdict
        return StreamHealth(
            state=state,  # type: ignore[arg-type]
            reason=reason,
            published_ns=time.time_ns(),
            last_seq=-1 if last_seq is None else last_seq,
            seconds_since_frame=seconds_since_frame,
            last_frame_age_ms=last_frame_age_ms,
            frames_dropped=frames_dropped,
            calibration_version=calibration_version,
            stream=self.stream,
            seq=next(self._numbers),
        )
