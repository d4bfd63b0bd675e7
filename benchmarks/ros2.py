"""The ROS 2 output's extra per-frame cost (issue 30): what turning it on adds to a frame.

On pre-rendered frames of the simulated arena (4 marked robots, 6 obstacles, 640×480,
the default camera), taking turns per frame: ``Detector.detect`` (a frame's processing,
the floor) and the ROS 2 conversion of its result, ``obstacle_messages`` (PoseArray,
MarkerArray, one Odometry per robot, CDR included) plus ``image_message`` (JPEG) for
one frame in :data:`IMAGE_EVERY` (its share at the image rate). Ratio = the extra cost /
the frame's processing.
"""

from __future__ import annotations

import time

import msgspec

from benchmarks.core import Row, ratio, stats
from ovis.common.calibration.file import calibration_from_config
from ovis.common.capture.sources import SimSource
from ovis.common.config import load_config
from ovis.common.messages import Frame, ObstacleFrame
from ovis.common.ros2.convert import image_message, obstacle_messages
from ovis.common.ros2.floor import ros_floor
from ovis.common.sim.scenes import marked_scene
from ovis.common.world.detection import Detector

__all__ = ["ros2_rows"]

PREFIX = "ROS 2 output"
ROBOTS, OBSTACLES = 4, 6
PRERENDER = 30
#: one compressed image per this many frames (e.g. 5 images a second at 30 frames/s)
IMAGE_EVERY = 6
#: the extra cost allowed, as a share of the frame's processing
TARGET = 0.10


def ros2_rows(quick: bool, log=print) -> list[Row]:
    config = marked_scene(load_config(), ROBOTS, OBSTACLES)
    source = SimSource(config, 9200, prerender=PRERENDER)
    images = [source.read()[0] for _ in range(PRERENDER)]
    detector = Detector(config.camera, config.image, config.pose)
    floor = ros_floor(msgspec.structs.replace(calibration_from_config(config), version=1))
    detect_ms: list[float] = []
    convert_ms: list[float] = []
    image_ms: list[float] = []
    reps = 60 if quick else 300
    for i in range(reps + 5):
        image, stamp_ns = images[i % PRERENDER], 1_700_000_000_000_000_000 + i * 33_333_333
        t0 = time.perf_counter()
        det = detector.detect(image, stamp_s=stamp_ns / 1e9)
        t1 = time.perf_counter()
        frame = ObstacleFrame(
            seq=i, stamp_ns=stamp_ns, published_ns=stamp_ns, frame_age_ms=0.0,
            calibration_version=1, robot=None,
            obstacles=[o for o in det.objects if o.kind == "obstacle"], planner=det.planner,
            robots=det.robots,
        )  # fmt: skip
        t2 = time.perf_counter()
        obstacle_messages(frame, "ovis_floor", floor)
        t3 = time.perf_counter()
        image_message(Frame.from_image(image, seq=i, stamp_ns=stamp_ns, copy=False))
        t4 = time.perf_counter()
        if i >= 5:
            detect_ms.append((t1 - t0) * 1e3)
            convert_ms.append((t3 - t2) * 1e3)
            image_ms.append((t4 - t3) * 1e3)
    frame_ms, convert, jpeg = stats(detect_ms).p50, stats(convert_ms).p50, stats(image_ms).p50
    extra = convert + jpeg / IMAGE_EVERY
    log(
        f"  per frame: detect {frame_ms:.2f} ms; obstacle_messages {convert:.3f} ms, "
        f"image_message {jpeg:.2f} ms (1 in {IMAGE_EVERY}): extra {extra:.3f} ms"
    )
    name = (
        f"{PREFIX} extra per-frame cost, {ROBOTS} robots + {OBSTACLES} obstacles, 640×480 "
        f"(obstacle_messages p50 + image_message p50 / {IMAGE_EVERY}; floor: Detector.detect "
        "p50 of the same frames)"
    )
    met = bool(extra <= TARGET * frame_ms)
    return [Row(name, "ms", extra, frame_ms, ratio(extra, frame_ms), f"ratio ≤ {TARGET:.2f}", met)]
