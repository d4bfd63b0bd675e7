"""The ROS 2 stream's rates (:class:`ovis.common.ros2.stream.Rate`): the topics people
watch (markers, the image) at their own rate, by the frames' capture stamps."""

from __future__ import annotations

import itertools

import pytest

from ovis.common.ros2.stream import Rate

S = 1_000_000_000


def stamps(fps: float, seconds: float, start: int = 10 * S) -> list[int]:
    return [start + round(i * S / fps) for i in range(round(fps * seconds))]


@pytest.mark.parametrize("fps", [30.0, 29.97, 7.0])
def test_a_rate_lets_its_messages_a_second_through_at_any_frame_rate(fps: float) -> None:
    rate = Rate(2.0)
    frames = stamps(fps, 10.0)
    due = [s for s in frames if rate.due(s)]
    assert due[0] == frames[0]  # the first one at once
    assert 19 <= len(due) <= 21  # 2 a second over 10 s, whatever the frame period
    gaps = [(b - a) / S for a, b in itertools.pairwise(due)]
    assert min(gaps) >= 0.5 - 1.0 / fps and max(gaps) <= 0.5 + 1.0 / fps


def test_none_lets_every_frame_through_zero_none_and_a_new_stream_starts_afresh() -> None:
    frames = stamps(30.0, 1.0)
    assert all(Rate(None).due(s) for s in frames)
    assert not any(Rate(0.0).due(s) for s in frames)
    rate = Rate(1.0)
    assert [rate.due(s) for s in frames].count(True) == 1
    assert rate.due(frames[0] - 60 * S)  # stamps went back: a new stream, due at once
    with pytest.raises(ValueError, match="give 0 or more"):
        Rate(-1.0)
