"""The ROS 2 stream (:mod:`ovis.common.ros2.stream`) and its rates (:class:`Rate`): the
topics people watch (markers, the image) at their own rate, by the frames' capture
stamps, the rest with every frame; the ``[ros2]`` topics chosen; a record unpaced."""

from __future__ import annotations

import itertools
from collections import Counter

import cv2
import msgspec
import pytest
from real_photos import photo_paths

from ovis.common.calibration.file import Calibration, calibration_from_config
from ovis.common.config import ROS2_TOPICS, Ros2Config, load_config
from ovis.common.messages import Frame, ObstacleFrame
from ovis.common.ros2.stream import Rate, RosStream
from ovis.common.sim.arena import Arena
from ovis.common.sim.scenes import marked_scene
from ovis.common.world.detection import Detector

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


def _arena_frame() -> tuple[Calibration, ObstacleFrame]:
    """A calibration and one obstacle frame of a simulated arena (2 marked robots, 4
    obstacles) as ovis's detector finds them."""
    config = marked_scene(load_config(), 2, 4)
    (image, _), *_ = Arena(config, seed=5).frames(1)
    det = Detector(config.camera, config.image, config.pose).detect(image, stamp_s=10.0)
    frame = ObstacleFrame(
        seq=0, stamp_ns=10 * S, published_ns=10 * S, frame_age_ms=0.0, calibration_version=1,
        robot=None, obstacles=[o for o in det.objects if o.kind == "obstacle"],
        planner=det.planner, robots=det.robots,
    )  # fmt: skip
    calib = msgspec.structs.replace(calibration_from_config(config), version=1)
    return calib, frame


def _run(stream: RosStream, frame: ObstacleFrame, photo: Frame, fps: float) -> Counter[str]:
    """Every frame of 10 s at ``fps`` through ``stream``: how many of each topic."""
    sent: Counter[str] = Counter()
    for i, stamp in enumerate(stamps(fps, 10.0)):
        replace = msgspec.structs.replace
        out = stream.obstacles(replace(frame, seq=i, stamp_ns=stamp))
        out += stream.images_due(replace(photo, seq=i, stamp_ns=stamp))
        sent.update(m.topic for m in out)
        assert all(m.stamp_ns == stamp for m in out)  # each stamped with its frame
    return sent


def test_the_bridges_stream_paces_what_people_watch_and_a_record_has_every_message() -> None:
    calib, frame = _arena_frame()
    assert frame.robots and frame.obstacles
    photo = Frame.from_image(cv2.imread(str(photo_paths()[0]), cv2.IMREAD_GRAYSCALE), seq=0,
                             stamp_ns=0)  # fmt: skip
    no_tf = [t for t in ROS2_TOPICS if t != "tf_static"]
    cfg = Ros2Config(markers_rate_hz=3.0, image_rate_hz=1.0, topics=no_tf)
    live, record = RosStream(cfg), RosStream(cfg, paced=False)
    assert live.obstacles(frame) == [] and live.waiting == 1  # no calibration yet
    for stream in (live, record):
        first = stream.calibration(calib, 5 * S)
        assert [m.topic for m in first] == ["camera/camera_info"]  # /tf_static not chosen
    odoms = [f"robots/robot_{r.id}/odom" for r in frame.robots]
    paced = _run(live, frame, photo, 30.0)
    assert all(paced[t] == 300 for t in ["obstacles", *odoms])  # with every frame
    assert 29 <= paced["markers"] <= 31  # 3 a second over 10 s
    assert 9 <= paced["camera/image/compressed"] == paced["camera/camera_info"] <= 11
    assert "/tf_static" not in paced
    every = _run(record, frame, photo, 30.0)
    assert set(every.values()) == {300} and set(every) == set(paced)
    shipped = RosStream()  # the [ros2] defaults: what benchmarks/ros2.py measures
    assert (shipped.markers.hz, shipped.images.hz) == (2.0, 1.0)
    assert RosStream(Ros2Config(topics=["obstacles"])).images.hz == 0.0  # frames unread
