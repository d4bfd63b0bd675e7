"""How current what the page shows is: the age of the newest frame (or binarised frame,
or obstacle message) by the wall clock, whether the stream has stalled, and whether it
is a replay of a recording rather than a live camera.

A frame is *stale* when the view has received nothing newer for :data:`STALL_S`
("stalled"), or when it arrived already older than that ("late": replayed by a tool
that does not say so, or the capture's clock is off). A replay says so itself: every
message ``ovis replay`` publishes carries a :class:`~ovis.common.messages.ReplayMark`
attachment with the recording's name and the message's own time in it; a replay is
shown with that time, never with an age or a latency.
"""

from __future__ import annotations

from typing import Any, Literal

import msgspec

from ovis.common.messages import ReplayMark

__all__ = ["STALL_S", "Freshness", "Seen", "freshness", "read_replay_mark", "replay_of_result"]

#: Seconds without a newer item after which a stream is "stalled" (the pose stage's
#: default ``frame_timeout_s``); also the age beyond which an arriving frame is "late".
STALL_S = 2.0

State = Literal["waiting", "live", "late", "replay", "stalled"]

_marks = msgspec.msgpack.Decoder(ReplayMark)


class _Keys(msgspec.Struct, forbid_unknown_fields=False):
    """Whether an attachment map holds a replay mark (a live message's attachment holds
    only the stage's proof of origin)."""

    recording: Any = None


_keys = msgspec.msgpack.Decoder(_Keys)


def read_replay_mark(attachment: bytes | None) -> ReplayMark | None:
    """The replay mark of a message's attachment: None when there is none; ValueError
    saying why when there is one but it is not a valid mark."""
    if not attachment:
        return None
    try:
        if _keys.decode(attachment).recording is None:
            return None  # no mark in it: a live message's proof of origin
        return _marks.decode(attachment)
    except (msgspec.DecodeError, msgspec.ValidationError) as exc:
        raise ValueError(f"not a replay mark: {exc}") from None


class Seen(msgspec.Struct, frozen=True, kw_only=True):
    """The newest item of one kind the view received: its frame, capture stamp (the
    sender's wall clock), when it arrived (the view's wall and monotonic clocks) and its
    replay mark, if any."""

    seq: int
    stamp_ns: int
    received_ns: int
    received_s: float
    replay: ReplayMark | None = None


class Freshness(msgspec.Struct, kw_only=True):
    """What the page says about one stream: ``state``; the newest item's ``seq``; its
    ``age_s`` (now − capture stamp, None for a replay, whose stamps are not now's);
    ``since_s``, seconds since it arrived (or, while waiting, since the view started
    looking); and for a replay the ``recording``, the item's own time in it
    (``recorded_ns``) and how far into it that is (``into_s``)."""

    state: State
    seq: int | None = None
    age_s: float | None = None
    since_s: float | None = None
    recording: str = ""
    recorded_ns: int | None = None
    into_s: float | None = None

    @property
    def stale(self) -> bool:
        """Whether a picture of it must be marked as not current."""
        return self.state in ("stalled", "late")


def freshness(
    seen: Seen | None,
    now_ns: int,
    now_s: float,
    *,
    looking_since_s: float | None = None,
    stall_s: float = STALL_S,
) -> Freshness:
    """The freshness of the newest item ``seen`` at wall time ``now_ns`` and monotonic
    time ``now_s`` (None: nothing yet, "waiting" since ``looking_since_s``)."""
    if seen is None:
        since = None if looking_since_s is None else max(0.0, now_s - looking_since_s)
        return Freshness(state="waiting", since_s=since)
    since = max(0.0, now_s - seen.received_s)
    mark = seen.replay
    if mark is not None:
        return Freshness(
            state="stalled" if since > stall_s else "replay",
            seq=seen.seq,
            since_s=since,
            recording=mark.recording,
            recorded_ns=mark.recorded_ns,
            into_s=max(0, mark.recorded_ns - mark.start_ns) / 1e9,
        )
    age = (now_ns - seen.stamp_ns) / 1e9
    late = (seen.received_ns - seen.stamp_ns) / 1e9 > stall_s
    state: State = "stalled" if since > stall_s else "late" if late else "live"
    return Freshness(state=state, seq=seen.seq, age_s=age, since_s=since)


def replay_of_result(
    frame: Seen | None, newest: Seen | None, stamp_ns: int, now_s: float, stall_s: float = STALL_S
) -> ReplayMark | None:
    """The replay mark of a result the pipeline made from a frame (the stages do not pass
    marks on): that of ``frame``, the kept frame with the result's sequence number, if its
    stamp is the result's; else that of the ``newest`` frame while it is current (a replay
    flowing)."""
    if frame is not None and frame.stamp_ns == stamp_ns:
        return frame.replay
    if newest is not None and now_s - newest.received_s <= stall_s:
        return newest.replay
    return None
