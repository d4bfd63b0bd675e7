"""When to write a frame while recording, and when to publish a message while replaying.

``--frames every|none|N/s`` (:class:`FrameGate`), the replay's pace (:class:`Pacer`)
and the stamps of replayed frames (:class:`Restamp`): pure logic, clocks passed in.
"""

from __future__ import annotations

import re
from collections.abc import Callable

import msgspec

from ovis.common.messages import Frame, MessageError, TruthFrame, decode, encode

__all__ = ["FrameGate", "Pacer", "Restamp", "parse_speed"]

_RATE_RE = re.compile(r"^\s*(\d+(?:\.\d*)?|\.\d+)\s*/\s*s\s*$")


class FrameGate:
    """Which frames a recording keeps: ``every``, ``none`` or ``N/s`` (at most N a
    second, evenly: a frame is kept once 1/N s of capture time has passed since the
    last kept one)."""

    def __init__(self, spec: str) -> None:
        text = spec.strip().lower()
        self.spec = text
        self.period_ns: int | None
        if text == "every":
            self.period_ns = 0
        elif text == "none":
            self.period_ns = None
        else:
            m = _RATE_RE.match(text)
            rate = float(m.group(1)) if m else 0.0
            if not m or not 0 < rate <= 10000:
                raise ValueError(
                    f"--frames {spec!r}: expected 'every', 'none' or a rate such as '5/s' "
                    "(0 < N ≤ 10000)"
                )
            self.period_ns = round(1e9 / rate)
        self._last_ns: int | None = None

    def keep(self, stamp_ns: int) -> bool:
        """Whether to record the frame captured at ``stamp_ns``."""
        if self.period_ns is None:
            return False
        if self._last_ns is not None and 0 <= stamp_ns - self._last_ns < self.period_ns:
            return False
        self._last_ns = stamp_ns
        return True


def parse_speed(text: str) -> float | None:
    """``--speed``: a factor of the recorded pace (``1``, ``0.5``, ``4``) or ``max``
    (None: no waiting)."""
    if text.strip().lower() == "max":
        return None
    try:
        speed = float(text)
    except ValueError:
        speed = float("nan")
    if not 0.01 <= speed <= 1000:  # also refuses NaN
        raise ValueError(f"--speed {text!r}: expected 'max' or a factor from 0.01 to 1000")
    return speed


class Pacer:
    """Publishes at the recorded pace: message ``k`` goes out ``(t_k − t_0) / speed``
    after the first (its log time, as recorded), on ``clock`` (monotonic seconds),
    waiting with ``wait(seconds)`` (which returns True to stop early)."""

    def __init__(
        self,
        speed: float | None,
        clock: Callable[[], float],
        wait: Callable[[float], bool],
    ) -> None:
        self.speed = speed
        self.clock = clock
        self.wait = wait
        self._origin: tuple[float, int] | None = None

    def restart(self) -> None:
        """Start over (a new pass of ``--loop``): the next message goes out at once."""
        self._origin = None

    def until(self, log_ns: int) -> bool:
        """Wait until the message logged at ``log_ns`` is due; False if told to stop."""
        if self.speed is None:
            return True
        if self._origin is None:
            self._origin = (self.clock(), log_ns)
            return True
        t0, log0 = self._origin
        delay = t0 + (log_ns - log0) / 1e9 / self.speed - self.clock()
        return delay <= 0 or not self.wait(delay)


class Restamp:
    """Stamps and sequence numbers of replayed frames and ground truth.

    The first pass sends them as recorded (bit-exact payloads) unless ``shift_ns`` moves
    every stamp (a recording older than the services accept). Each later pass of
    ``--loop`` comes after the previous one (its length plus one frame period) with
    sequence numbers after its last, so both keep growing for the services downstream.
    ``last`` is the (seq, stamp_ns) of the last frame as sent, ``stream`` its capture
    stream identity.
    """

    def __init__(self, shift_ns: int = 0) -> None:
        self.shift_ns = int(shift_ns)
        self.seq_offset = 0
        self.last: tuple[int, int] | None = None
        self.stream = ""
        self._stamps: list[int] = []  # first and last recorded stamp of this pass
        self._frames = 0
        self._max_seq = -1

    def next_pass(self) -> None:
        """Move on to the next pass of a loop."""
        if self._frames:
            first, last = self._stamps
            period = (last - first) // (self._frames - 1) if self._frames > 1 else 10**9
            self.shift_ns += last - first + max(period, 1)
        self.seq_offset += self._max_seq + 1
        self._stamps, self._frames, self._max_seq = [], 0, -1

    def frame(self, payload: bytes) -> bytes:
        """A frame payload as it goes out (unchanged when nothing moves)."""
        try:
            frame = decode(payload, Frame)
        except MessageError:
            return payload  # sent as recorded: the services refuse it as they would
        self._stamps = [self._stamps[0] if self._stamps else frame.stamp_ns, frame.stamp_ns]
        self._frames += 1
        self._max_seq = max(self._max_seq, frame.seq)
        self.last = (frame.seq + self.seq_offset, frame.stamp_ns + self.shift_ns)
        self.stream = frame.stream
        if not self.shift_ns and not self.seq_offset:
            return payload
        return encode(msgspec.structs.replace(frame, seq=self.last[0], stamp_ns=self.last[1]))

    def truth(self, payload: bytes) -> bytes:
        """A ground-truth payload as it goes out (its sequence number follows the frames)."""
        if not self.seq_offset:
            return payload
        try:
            truth = decode(payload, TruthFrame)
        except MessageError:
            return payload
        return encode(msgspec.structs.replace(truth, seq=truth.seq + self.seq_offset))
