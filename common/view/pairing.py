"""Which kept camera frame the view draws: the newest whose detections have arrived, so
that the picture shows what was found on that very frame. A frame whose detections are
still on their way is not drawn without them (the page would show a robot as not found);
it is drawn without them only once waiting no longer helps, and the picture says so."""

from __future__ import annotations

from collections.abc import Container, Sequence

__all__ = ["DETECTIONS_WAIT_S", "frame_to_draw"]

#: Seconds the oldest kept frame may wait for its detections before the newest frame is
#: drawn without any (the frame path is down, or behind by more than this).
DETECTIONS_WAIT_S = 1.0


def frame_to_draw(
    kept: Sequence[tuple[int, float]], detected: Container[int], now_s: float, *, full: bool
) -> tuple[int, bool] | None:
    """The frame to draw of ``kept`` (sequence number and monotonic arrival, oldest
    first) and whether its detections are drawn: the newest one in ``detected``; with
    none, None (wait for them) while the oldest has waited less than
    :data:`DETECTIONS_WAIT_S` and the store is not ``full`` (detections further behind
    than it keeps frames would never pair), else the newest without detections."""
    if not kept:
        return None
    paired = next((seq for seq, _ in reversed(kept) if seq in detected), None)
    if paired is not None:
        return paired, True
    if not full and now_s - kept[0][1] < DETECTIONS_WAIT_S:
        return None
    return kept[-1][0], False
