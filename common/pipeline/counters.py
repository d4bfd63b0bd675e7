"""A stage's counters: frames in and out, frames lost upstream (plausible gaps in
sequence numbers, confirmed one frame at a time by the sequence going on after the gap;
a jump beyond :data:`MAX_PLAUSIBLE_GAP`, a gap the old sequence resumes from, or a new
capture stream is counted as such, not as lost frames: no message moves a counter by
more than one), the recent input rate, the recent inputs' outcomes
(the stage's health verdict) and errors by kind; and the process's memory. They make the
:class:`~ovis.common.messages.ServiceStatus` a stage answers with."""

from __future__ import annotations

import collections
import os
import resource
import socket
import threading
import time

from ovis.common.messages import ServiceStatus
from ovis.common.pipeline.health import Verdict, stage_verdict

__all__ = ["MAX_PLAUSIBLE_GAP", "RATE_WINDOW_S", "StageCounters", "rss_mb", "worth_logging"]

#: The input rate is over the frames of the last this many seconds.
RATE_WINDOW_S = 5.0
#: A gap in sequence numbers larger than this (forward or back) is not frames lost: a
#: forged number, or a capture that restarted. It is counted as a jump and the count
#: goes on from the new number.
MAX_PLAUSIBLE_GAP = 1000


def rss_mb() -> float:
    """Current resident set size (VmRSS), MB; the peak if /proc is unavailable."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def worth_logging(n: int) -> bool:
    """Log the ``n``-th error of a kind? The first 5, then every 100th (a flood of bad
    input must not flood the log)."""
    return n <= 5 or n % 100 == 0


class StageCounters:
    """What one stage counts; safe to update from Zenoh's threads and the loop."""

    def __init__(self) -> None:
        self.frames_in = 0
        self.frames_out = 0
        self.errors: collections.Counter[str] = collections.Counter()
        self.last_error = ""
        self.last_frame_ns: int | None = None  # the last frame's capture stamp
        self.last_receipt_ns: int | None = None  # our clock, when the last frame came in
        self.last_seq: int | None = None
        self.stream: str = ""  # the capture's stream identity of the last frame
        self.seq_gaps = 0
        self._pending = 0  # frames missing in the gaps, not yet confirmed as dropped
        self._before_gap = -1  # the last sequence number before the first of those gaps
        self.seq_jumps = 0
        self.stream_restarts = 0
        self._arrivals: collections.deque[float] = collections.deque(maxlen=64)
        self._outcomes: collections.deque[tuple[float, bool]] = collections.deque(maxlen=256)
        self._lock = threading.Lock()

    def saw_frame(self, seq: int, stamp_ns: int, stream: str = "") -> None:
        """Count an input frame. A plausible gap in sequence numbers is dropped upstream,
        counted one frame at a time as the sequence goes on after it: each later frame
        confirms one, and a gap that follows adds its frames to those still to confirm
        (under overload none is forgotten; a forged frame far ahead, even a pair, moves
        the count by at most one). A frame of the sequence before the gaps (it goes on:
        they were forged or stray numbers) counts them as one jump instead. A new
        ``stream`` (the capture restarted) or a jump beyond :data:`MAX_PLAUSIBLE_GAP` is
        counted as such, and the count restarts there; any other late, older frame
        neither counts nor moves the last one back."""
        with self._lock:
            self.frames_in += 1
            if stream and self.stream and stream != self.stream:
                self.stream_restarts += 1
                self._restart_sequence()
            self.stream = stream or self.stream
            if self.last_seq is not None and abs(seq - self.last_seq) > MAX_PLAUSIBLE_GAP:
                self.seq_jumps += 1
                self._restart_sequence()
            self._follow(seq)
            self.last_frame_ns = stamp_ns
            self.last_receipt_ns = time.time_ns()
            self._arrivals.append(time.monotonic())

    def _restart_sequence(self) -> None:
        self.last_seq, self._pending, self._before_gap = None, 0, -1

    def _follow(self, seq: int) -> None:
        """Move the followed sequence to ``seq`` (see :meth:`saw_frame`); under the lock."""
        last = self.last_seq
        if last is None:
            self.last_seq = seq
        elif seq > last:
            if self._pending:  # the sequence goes on after the gaps: one more frame lost
                self._pending -= 1
                self.seq_gaps += 1
            else:
                self._before_gap = last
            self._pending += seq - last - 1  # a new gap adds to the earlier ones' frames
            self.last_seq = seq
        elif self._pending and seq == self._before_gap + 1:  # the old sequence goes on
            self.seq_jumps += 1
            self._pending, self._before_gap, self.last_seq = 0, -1, seq
        elif self._pending and self._before_gap < seq:
            self._pending -= 1  # a frame of the gap, late: not lost

    def sent(self) -> None:
        with self._lock:
            self.frames_out += 1

    def outcome(self, produced: bool) -> None:
        """One input handled: it produced an output, or not (refused, or it failed)."""
        with self._lock:
            self._outcomes.append((time.monotonic(), produced))

    def verdict(self) -> Verdict:
        """The stage's health from its recent inputs (:func:`stage_verdict`)."""
        with self._lock:
            outcomes, last_error = list(self._outcomes), self.last_error
        return stage_verdict(outcomes, time.monotonic(), last_error)

    def error(self, kind: str, message: str) -> int:
        """Count an error of ``kind`` (``message`` becomes the last error); its count."""
        with self._lock:
            self.errors[kind] += 1
            self.last_error = message
            return self.errors[kind]

    def fps(self) -> float:
        """Input frames per second over the last :data:`RATE_WINDOW_S`."""
        now = time.monotonic()
        with self._lock:
            recent = [t for t in self._arrivals if now - t <= RATE_WINDOW_S]
        return (len(recent) - 1) / (recent[-1] - recent[0]) if len(recent) > 1 else 0.0

    def seconds_since_frame(self) -> float | None:
        """Seconds since the last input frame came in (None: none yet)."""
        if self.last_receipt_ns is None:
            return None
        return (time.time_ns() - self.last_receipt_ns) / 1e9

    def status(
        self,
        service: str,
        *,
        started_ns: int,
        state: str,
        dropped_here: int,
        calibration_version: int,
        calibration_epoch: str = "",
        problem: str | None = None,
    ) -> ServiceStatus:
        """The status message: these counts, plus what only the service knows (its name,
        state, the frames its inboxes dropped, its calibration, and a ``problem`` that
        makes it "degraded" whatever its inputs say)."""
        fps = self.fps()
        verdict = self.verdict()
        if verdict[0] == "ok" and problem:
            verdict = ("degraded", problem)
        if verdict[0] != "ok":
            state = verdict[0]
        with self._lock:
            age = None
            if self.last_frame_ns is not None:
                age = (time.time_ns() - self.last_frame_ns) / 1e9
            return ServiceStatus(
                service=service,
                pid=os.getpid(),
                host=socket.gethostname(),
                started_ns=started_ns,
                state=state,
                frames_in=self.frames_in,
                frames_out=self.frames_out,
                fps=round(fps, 2),
                dropped=self.seq_gaps + dropped_here,
                errors=dict(self.errors),
                last_error=self.last_error,
                calibration_version=calibration_version,
                last_frame_age_s=age,
                rss_mb=rss_mb(),
                restarts=int(os.environ.get("OVIS_RESTARTS", "0") or 0),
                reason=verdict[1],
                calibration_epoch=calibration_epoch,
                seq_jumps=self.seq_jumps,
                stream_restarts=self.stream_restarts,
                stream=self.stream,
            )
