"""The stream's health, as the pose stage publishes it on ``ovis/<arena>/health``:
"waiting" (no frame yet), "ok" (a frame within the timeout) or "stalled", so that a
consumer can tell "no obstacles" from "no data"."""

from __future__ import annotations

import time

from ovis.common.messages import StreamHealth

__all__ = ["SERVICE_STATE", "StreamWatch"]

#: The service's state (in its status) for each stream state.
SERVICE_STATE = {"ok": "ok", "stalled": "no frames", "waiting": "waiting"}


class StreamWatch:
    """Follows the time since the last frame; says when the stream's state changes."""

    def __init__(self, timeout_s: float) -> None:
        self.timeout_s = timeout_s
        self.state = "waiting"

    def classify(self, seconds_since_frame: float | None) -> str:
        """The stream's state ``seconds_since_frame`` after the last frame (None: none yet)."""
        if seconds_since_frame is None:
            return "waiting"
        return "ok" if seconds_since_frame <= self.timeout_s else "stalled"

    def update(self, seconds_since_frame: float | None) -> bool:
        """Take the time since the last frame; True when the state changed."""
        state = self.classify(seconds_since_frame)
        changed, self.state = state != self.state, state
        return changed

    def message(
        self,
        *,
        last_seq: int | None,
        seconds_since_frame: float | None,
        last_frame_age_ms: float | None,
        frames_dropped: int,
        calibration_version: int,
    ) -> StreamHealth:
        """The health message for the current state."""
        return StreamHealth(
            state=self.state,
            published_ns=time.time_ns(),
            last_seq=-1 if last_seq is None else last_seq,
            seconds_since_frame=seconds_since_frame,
            last_frame_age_ms=last_frame_age_ms,
            frames_dropped=frames_dropped,
            calibration_version=calibration_version,
        )
