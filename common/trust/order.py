"""Replays of genuine messages: a proof of origin (:mod:`.proof`) says who published a
message, not that it is new, so a recorded obstacle message sent again later verifies.
A consumer therefore also checks, per key expression, that a proven message comes after
the last one it took.

What orders a message is what it says of itself, read by field name as any reader
would: its run, ``stream`` (random, new at each start: the capture's for obstacles, the
pose stage's for the health, fusion's for the world), its ``seq`` within it, and its
stamp (``stamp_ns``, else ``published_ns``). A message is taken when

1. it is the first on its key, or
2. it continues the stream last taken with a higher ``seq`` (a clock that steps back
   inside a stream changes nothing), or
3. its stream was never taken (a new one: a restart; or it names none, an older
   sender) and it is stamped after the last message taken, or within
   :data:`FRESH_S` of the receiver's clock (a capture restarted after its clock
   stepped back is not refused until the clock catches up).

So a replay is refused whether it repeats the current stream, brings back a stream
that was replaced (never taken again), or comes from an older run (older than the last
message taken, and not fresh). A message with neither stamp is not ordered (a
calibration: its store's identity and version order it,
:mod:`ovis.common.pipeline.following`).
"""

from __future__ import annotations

import collections
import threading

import msgspec

__all__ = ["FRESH_S", "MessageOrder", "ReplayGuard"]

#: How close to the receiver's clock a new stream's first message must be stamped when
#: it is not after the last message taken (the clocks of two hosts differ by less).
FRESH_S = 5.0

#: Streams remembered per key expression (a stream once replaced never comes back).
STREAMS_KEPT = 64


class MessageOrder(msgspec.Struct, kw_only=True, forbid_unknown_fields=False):
    """What orders a message, read by field name from its MessagePack map."""

    stream: str = ""
    seq: int = -1
    stamp_ns: int = 0
    published_ns: int = 0

    @property
    def stamp(self) -> int:
        return self.stamp_ns or self.published_ns


_decoder = msgspec.msgpack.Decoder(MessageOrder)


class _Last(msgspec.Struct):
    """The last message taken on a key, and the streams taken there."""

    stream: str
    seq: int
    stamp: int
    streams: collections.deque[str]


class ReplayGuard:
    """The order check of every key expression one consumer reads (thread-safe: Zenoh
    delivers from several threads)."""

    def __init__(self) -> None:
        self._last: dict[str, _Last] = {}
        self._lock = threading.Lock()

    def problem(self, key_expr: str, payload: bytes, now_ns: int) -> str | None:
        """Why a proven message on ``key_expr`` is not taken (a replay, or out of
        order), or None: it is taken and becomes the last on its key."""
        try:
            order = _decoder.decode(payload)
        except (msgspec.DecodeError, msgspec.ValidationError):
            return None  # nothing to order by: the message's own decoding says why
        if not order.stamp:
            return None
        with self._lock:
            last = self._last.get(key_expr)
            if last is not None and (why := _refused(last, order, now_ns)):
                return why
            self._take(key_expr, last, order)
        return None

    def _take(self, key_expr: str, last: _Last | None, order: MessageOrder) -> None:
        if last is None:
            streams = collections.deque([order.stream], maxlen=STREAMS_KEPT)
            self._last[key_expr] = _Last(order.stream, order.seq, order.stamp, streams)
            return
        if order.stream not in last.streams:
            last.streams.append(order.stream)
        last.stream, last.seq, last.stamp = order.stream, order.seq, order.stamp


def _refused(last: _Last, order: MessageOrder, now_ns: int) -> str | None:
    """Why ``order`` may not follow ``last`` (rules 2 and 3 of the module), or None."""
    ago = (last.stamp - order.stamp) / 1e9
    if order.stream and order.stream == last.stream:
        if order.seq > last.seq:
            return None
        return (
            f"replayed or out of order: seq {order.seq} of stream {order.stream} after "
            f"seq {last.seq} (stamped {ago:.3f} s before it)"
        )
    if order.stream and order.stream in last.streams:
        return (
            f"replayed: stream {order.stream} (seq {order.seq}) was replaced by "
            f"{last.stream or '-'} and does not come back"
        )
    if order.stamp > last.stamp or abs(now_ns - order.stamp) <= FRESH_S * 1e9:
        return None
    return f"replayed: stamped {ago:.3f} s before the last message taken, and not now"
