"""The capture's record of its source's losses: each time the source stops delivering
(unplugged, network lost, ended), from its last frame (or from the first failure, when
it never delivered) to its next frame, and why; what the capture's status and its
``source`` messages say about it."""

from __future__ import annotations

import collections
import threading

import msgspec

from ovis.common.messages import ServiceStatus, SourceGap, SourceState

__all__ = ["KEEP", "SourceGaps"]

#: Losses listed in the status, the latest ones (the count and total cover them all).
KEEP = 50


class SourceGaps:
    """The losses of one source; safe to use from the capture's loop and Zenoh's threads.

    A loss is found at a failure (:meth:`lose`) and ends at the next frame
    (:meth:`delivered`); it counts from the last frame before it. Failures in between
    (attempts to reopen) only update the reason the source is lost now. A source that
    ``ended`` is lost for good."""

    def __init__(self, keep: int = KEEP) -> None:
        self._closed: collections.deque[SourceGap] = collections.deque(maxlen=keep)
        self._closed_s = 0.0
        self.count = 0
        self._open: SourceGap | None = None  # the ongoing loss (seconds filled on demand)
        self.reason = ""  # the latest error while lost
        self.ended = False
        self._last_frame_ns: int | None = None
        self._lock = threading.RLock()

    @property
    def lost(self) -> bool:
        return self._open is not None

    def lose(self, reason: str, now_ns: int, *, ended: bool = False) -> bool:
        """The source failed with ``reason`` (``ended``: for good); True when this
        starts a loss, False when it was lost already."""
        with self._lock:
            self.reason, self.ended = reason, ended
            if self._open is not None:
                return False
            start = now_ns if self._last_frame_ns is None else self._last_frame_ns
            self._open = SourceGap(start_ns=start, seconds=0.0, reason=reason, ongoing=True)
            self.count += 1
            return True

    def delivered(self, now_ns: int) -> SourceGap | None:
        """The source delivered a frame at ``now_ns``: the loss that ends here, or None."""
        with self._lock:
            self._last_frame_ns = now_ns
            if self._open is None:
                return None
            gap = self._ongoing(now_ns)
            gap.ongoing = False
            self._closed.append(gap)
            self._closed_s += gap.seconds
            self._open, self.reason, self.ended = None, "", False
            return gap

    def _ongoing(self, now_ns: int) -> SourceGap:
        assert self._open is not None
        seconds = max(0.0, (now_ns - self._open.start_ns) / 1e9)
        return msgspec.structs.replace(self._open, seconds=round(seconds, 3))

    def gaps(self, now_ns: int) -> list[SourceGap]:
        """The latest losses, oldest first, the ongoing one last (seconds so far)."""
        with self._lock:
            ongoing = [self._ongoing(now_ns)] if self._open is not None else []
            return [*self._closed, *ongoing]

    def total_s(self, now_ns: int) -> float:
        """Seconds without the source, every loss (the ongoing one so far)."""
        with self._lock:
            ongoing = self._ongoing(now_ns).seconds if self._open is not None else 0.0
            return round(self._closed_s + ongoing, 3)

    def message(self, now_ns: int) -> SourceState:
        """What the capture publishes on its ``source`` topic now."""
        with self._lock:
            if self._open is None:
                return SourceState(state="ok", published_ns=now_ns, gaps=self.count)
            return SourceState(
                state="source lost",
                published_ns=now_ns,
                reason=self.reason,
                lost_ns=self._open.start_ns,
                ended=self.ended,
                gaps=self.count,
            )

    def amend(self, status: ServiceStatus, now_ns: int) -> ServiceStatus:
        """The capture's status with its losses: state "source lost" and the reason
        while lost, the count, the total seconds and the latest losses always."""
        with self._lock:
            lost = self.lost
            return msgspec.structs.replace(
                status,
                state="source lost" if lost else status.state,
                reason=self.reason if lost else status.reason,
                source_gaps=self.count,
                source_gap_s=self.total_s(now_ns),
                gaps=self.gaps(now_ns),
            )
