"""Frames from different cameras matched by capture time.

Each camera's detections carry the capture stamp of their frame. Frames whose stamps
lie within a window of the first one form one *world frame*; it leaves when every live
camera has given its frame, or when it has waited ``wait_ns`` (by the receiver's clock)
for a late one. A frame that arrives after its world frame left is *late*: counted per
camera and not fused (the world already moved on). A camera silent for ``stale_ns`` is
not waited for any more (its area is uncovered, the rest keeps flowing) until it speaks
again.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Generic, TypeVar

__all__ = ["FrameMatcher", "MatchedFrame"]

T = TypeVar("T")


@dataclass
class MatchedFrame(Generic[T]):
    """One world frame: the stamp of its first camera frame and each camera's item."""

    stamp_ns: int
    opened_ns: int
    items: dict[str, T] = field(default_factory=dict)


class FrameMatcher(Generic[T]):
    """Groups per-camera items by capture stamp (see the module docstring)."""

    def __init__(self, cameras: list[str], *, window_ns: int, wait_ns: int, stale_ns: int) -> None:
        if not cameras:
            raise ValueError("a frame matcher needs at least one camera")
        if window_ns <= 0 or wait_ns < 0 or stale_ns <= 0:
            raise ValueError("window_ns and stale_ns must be > 0 and wait_ns >= 0")
        self.cameras = list(cameras)
        self.window_ns, self.wait_ns, self.stale_ns = int(window_ns), int(wait_ns), int(stale_ns)
        self.late = dict.fromkeys(self.cameras, 0)
        self.unknown = 0
        self.last_heard_ns: dict[str, int | None] = dict.fromkeys(self.cameras, None)
        self._started_ns: int | None = None  # first item: never-heard cameras count as
        # live for ``stale_ns`` after it, so the first world frames wait for them
        self._open: list[MatchedFrame[T]] = []
        self._left_until_ns: int | None = None  # stamp of the newest world frame that left

    def live(self, now_ns: int) -> list[str]:
        """The cameras heard within ``stale_ns`` (those a world frame waits for)."""
        start = now_ns if self._started_ns is None else self._started_ns
        return [
            c
            for c, t in self.last_heard_ns.items()
            if now_ns - (start if t is None else t) <= self.stale_ns
        ]

    def add(self, camera: str, stamp_ns: int, item: T, now_ns: int) -> list[MatchedFrame[T]]:
        """Take one camera's item; returns the world frames now complete or overdue,
        oldest first."""
        if camera not in self.late:
            self.unknown += 1
            return self.due(now_ns)
        if self._started_ns is None:
            self._started_ns = now_ns
        self.last_heard_ns[camera] = now_ns
        left = self._left_until_ns
        if left is not None and stamp_ns <= left + self.window_ns and not self._fits_open(stamp_ns):
            self.late[camera] += 1
            return self.due(now_ns)
        group = self._group_for(camera, stamp_ns, now_ns)
        if camera in group.items:  # a second frame of one camera in a window: late-ish
            self.late[camera] += 1
        else:
            group.items[camera] = item
        return self.due(now_ns)

    def due(self, now_ns: int) -> list[MatchedFrame[T]]:
        """The world frames that may leave now: complete, overdue, or older than one that
        may leave (frames leave in stamp order)."""
        live = set(self.live(now_ns))
        ready = -1
        for k, g in enumerate(self._open):
            if live <= g.items.keys() or now_ns - g.opened_ns >= self.wait_ns:
                ready = k
        if ready < 0:
            return []
        out, self._open = self._open[: ready + 1], self._open[ready + 1 :]
        newest = out[-1].stamp_ns
        self._left_until_ns = (
            newest if self._left_until_ns is None else max(self._left_until_ns, newest)
        )
        return out

    def next_due_ns(self) -> int | None:
        """When the oldest open world frame's wait for a late camera runs out (None when
        none is open): until then, only a camera's frame can let one leave."""
        if not self._open:
            return None
        return min(g.opened_ns for g in self._open) + self.wait_ns

    def _fits_open(self, stamp_ns: int) -> bool:
        return any(abs(stamp_ns - g.stamp_ns) <= self.window_ns for g in self._open)

    def _group_for(self, camera: str, stamp_ns: int, now_ns: int) -> MatchedFrame[T]:
        near = [g for g in self._open if abs(stamp_ns - g.stamp_ns) <= self.window_ns]
        if near:
            return min(near, key=lambda g: abs(stamp_ns - g.stamp_ns))
        group: MatchedFrame[T] = MatchedFrame(stamp_ns=stamp_ns, opened_ns=now_ns)
        self._open.append(group)
        self._open.sort(key=lambda g: g.stamp_ns)
        return group
