"""The CPU time processes use, read from ``/proc`` (Linux): what ``ovis up``'s summary
says its processes cost per frame, and what the benchmarks read.

A process's CPU time (user + system, every thread: Python's and Zenoh's) is read from
``/proc/<pid>/stat``. :class:`CpuWindow` follows a run's processes through a window,
read now and then: a process restarted meanwhile counts what its earlier pid used up to
its last reading (what it used after is lost), and its new pid from its start."""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping
from pathlib import Path

from ovis.common.analysis.live import CpuUse

__all__ = ["READ_EVERY_S", "CpuWindow", "process_cpu_s", "tree_cpu"]


def _stat_fields(pid: int) -> list[str] | None:
    """The fields of ``/proc/<pid>/stat`` after the command name (None: no such process)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None


def process_cpu_s(pid: int) -> float | None:
    """CPU seconds (user + system, every thread) process ``pid`` has used (None: gone)."""
    fields = _stat_fields(pid)
    if fields is None:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def tree_cpu(root: int) -> dict[int, float]:
    """pid → CPU seconds used so far, of ``root`` and every running process under it."""
    tick = os.sysconf("SC_CLK_TCK")
    parent, used = {}, {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        fields = _stat_fields(int(entry))
        if fields is None:
            continue  # ended meanwhile
        parent[int(entry)] = int(fields[1])
        used[int(entry)] = (int(fields[11]) + int(fields[12])) / tick

    def under(pid: int) -> bool:
        while pid > 1:
            if pid == root:
                return True
            pid = parent.get(pid, 0)
        return False

    return {pid: t for pid, t in used.items() if under(pid)}


#: Seconds between two readings (a process that dies loses at most this much of its
#: CPU time from the count).
READ_EVERY_S = 0.5


class CpuWindow:
    """The CPU time of a run's processes (``pids()``: name → pid, read at each call)
    between :meth:`open` and the last :meth:`read`, and the frames delivered meanwhile;
    this process itself counts apart (:data:`OWN`)."""

    #: this process's name in :meth:`summary` (the measuring one, not the system run)
    OWN = "ovis up"

    def __init__(self, pids: Callable[[], Mapping[str, int]]) -> None:
        self._pids = pids
        self._first: dict[int, float] = {}  # pid → CPU s at the window's opening
        self._last: dict[int, float] = {}  # pid → CPU s at its last reading
        self._names: dict[int, str] = {}
        self._frames = (0, 0)  # frames delivered so far, at the opening and the last read
        self.opened: float | None = None  # monotonic s
        self.closed: float | None = None
        self._first_frame_at: float | None = None  # monotonic s (:meth:`tick`)

    def open(self, frames: int) -> None:
        """Start the window (``frames`` delivered so far): the CPU time used so far does
        not count."""
        self.opened = time.monotonic()
        self.read(frames)
        self._first = dict(self._last)
        self._frames = (frames, frames)

    def read(self, frames: int, *, every_s: float = 0.0) -> None:
        """Read every process now (``frames`` delivered so far), unless the last reading
        is less than ``every_s`` old; a pid first seen after the opening counts from its
        start. Nothing before :meth:`open`."""
        if self.opened is None:
            return
        if self.closed is not None and time.monotonic() - self.closed < every_s:
            return
        for name, pid in {**self._pids(), self.OWN: os.getpid()}.items():
            used = process_cpu_s(pid)
            if used is not None:
                self._last[pid] = used
                self._names[pid] = name
        self._frames = (self._frames[0], frames)
        self.closed = time.monotonic()

    def tick(self, frames: int, *, after_s: float, every_s: float = READ_EVERY_S) -> None:
        """Called now and then with the frames delivered so far: opens the window
        ``after_s`` after the first frame, then reads at most every ``every_s``."""
        now = time.monotonic()
        if self.opened is None:
            if frames and self._first_frame_at is None:
                self._first_frame_at = now
            if self._first_frame_at is None or now - self._first_frame_at < after_s:
                return
            self.open(frames)
        self.read(frames, every_s=every_s)

    def summary(self) -> CpuUse:
        """The window: its length, the frames delivered in it, and the CPU ms per frame
        of the run's processes together, of each, and of this process (apart)."""
        frames = self._frames[1] - self._frames[0]
        by_name: dict[str, float] = {}
        for pid, last in self._last.items():
            name = self._names[pid]
            by_name[name] = by_name.get(name, 0.0) + last - self._first.get(pid, 0.0)

        def per_frame(seconds: float) -> float | None:
            return round(seconds * 1e3 / frames, 3) if frames > 0 else None

        own = by_name.pop(self.OWN, 0.0)
        seconds = 0.0 if self.opened is None or self.closed is None else self.closed - self.opened
        return CpuUse(
            window_s=round(seconds, 2),
            frames=frames,
            ms_per_frame=per_frame(sum(by_name.values())),
            by_process_ms={name: per_frame(v) for name, v in sorted(by_name.items())},
            own_ms_per_frame=per_frame(own),
        )
