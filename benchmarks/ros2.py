"""The ROS 2 output's extra per-frame cost (issue 30): what turning it on adds to a frame.

On pre-rendered frames of the simulated arena (4 marked robots, 6 obstacles, 640×480,
the default camera), taking turns per frame: a frame's processing, the floor (the whole
in-process frame path of ``ovis up``: grey image, the preprocess, label and pose
stages of :mod:`ovis.common.pipeline.stages`, as the services run them), and the ROS 2
conversion of its result by :class:`~ovis.common.ros2.stream.RosStream`, CDR included.
Each is measured in its steady state, as each runs on a stream (the ROS 2 output is a
process of its own) and as ``benchmarks/pipeline.py`` measures the frame path: in
blocks of :data:`BLOCK` frames after one untimed frame, the frame path's block and
then the conversion of its results.
Every frame gets its PoseArray and one Odometry per robot (what Nav2 consumes); the
MarkerArray (for people watching RViz or Foxglove) and the JPEG image with its
CameraInfo come at their own rates, the ``[ros2]`` defaults ``ovis up --ros2`` ships
(:data:`ROS2`: the stream is the bridge's), for frames stamped :data:`FPS` a second,
so the cost per frame is each kind of frame's median (plain, with markers, with an
image) times its share of the frames. Ratio = the extra cost / the frame
path's median.
"""

from __future__ import annotations

import time

import msgspec

from benchmarks.core import Row, ratio, stats
from benchmarks.stage_work import FramePath
from ovis.common.capture.sources import SimSource
from ovis.common.config import Ros2Config, load_config
from ovis.common.messages import Frame
from ovis.common.ros2.cdr import COMPRESSED_IMAGE, MARKER_ARRAY
from ovis.common.ros2.convert import obstacle_messages
from ovis.common.ros2.stream import RosStream
from ovis.common.sim.scenes import marked_scene

__all__ = ["ros2_rows"]

PREFIX = "ROS 2 output"
ROBOTS, OBSTACLES = 4, 6
PRERENDER = 30
#: the frame rate the shares are taken at (the service's default)
FPS = 30.0
#: the bridge's configuration as shipped (its markers' and image's rates)
ROS2 = Ros2Config()
#: timed frames per block, each block after one untimed frame (see the module docstring)
BLOCK = 10
#: the extra cost allowed, as a share of the frame's processing
TARGET = 0.10


def _stamp(i: int) -> int:
    """The capture stamp of frame ``i`` of a stream at :data:`FPS`."""
    return 1_700_000_000_000_000_000 + round(i * 1e9 / FPS)


def ros2_rows(quick: bool, log=print) -> list[Row]:
    config = marked_scene(load_config(), ROBOTS, OBSTACLES)
    source = SimSource(config, 9200, prerender=PRERENDER)
    images = [source.read()[0] for _ in range(PRERENDER)]
    path = FramePath(config)
    stream = RosStream(ROS2)
    stream.calibration(path.calib, 0)
    frame_ms: list[float] = []
    extra_ms: dict[tuple[bool, bool], list[float]] = {}  # by (markers, image) sent
    sent: dict[str, int] = {}
    frames = [
        Frame.from_image(images[i % PRERENDER], seq=i, stamp_ns=_stamp(i), copy=False)
        for i in range(PRERENDER)
    ]
    reps = 150 if quick else 900
    for first in range(0, reps, BLOCK):
        block = [frames[(first + k) % PRERENDER] for k in range(BLOCK + 1)]
        stamps = [_stamp(first + k) for k in range(BLOCK)]
        # each in its steady state, as on a stream: one untimed frame, then the block
        path(block[0])
        results = []
        for f in block[1:]:
            t0 = time.perf_counter()
            results.append(path(f))
            frame_ms.append((time.perf_counter() - t0) * 1e3)
        obstacle_messages(results[-1], stream.frame_id, stream.floor, markers=False)
        for f, result, stamp in zip(block[1:], results, stamps, strict=True):
            # the frames' stamps go on across blocks, as a stream's do
            result = msgspec.structs.replace(result, stamp_ns=stamp)
            f = msgspec.structs.replace(f, stamp_ns=stamp)
            t0 = time.perf_counter()
            out = stream.obstacles(result) + stream.images_due(f)
            dt = (time.perf_counter() - t0) * 1e3
            kinds = {m.type for m in out}
            extra_ms.setdefault((MARKER_ARRAY in kinds, COMPRESSED_IMAGE in kinds), []).append(dt)
            assert len(result.robots) == ROBOTS, len(result.robots)
            for m in out:
                sent[m.type] = sent.get(m.type, 0) + 1
    n = sum(len(v) for v in extra_ms.values())
    # each kind of frame's median, by its share of the frames: robust to the odd
    # pre-empted frame, and the visual topics count at the rate they go out
    by_kind = {k: (len(v) / n, stats(v).p50) for k, v in extra_ms.items()}
    extra = sum(share * p50 for share, p50 in by_kind.values())
    floor = stats(frame_ms).p50
    names = {(False, False): "plain", (True, False): "+markers", (False, True): "+image"}
    log(
        f"  per frame: frame path p50 {floor:.3f} ms; ROS 2 output {extra:.3f} ms = "
        + " + ".join(
            f"{share:.3f}×{p50:.3f} ({names.get(k, '+both')})"
            for k, (share, p50) in by_kind.items()
        )
        + f"; sent {sent}"
    )
    name = (
        f"{PREFIX} extra per-frame cost, {ROBOTS} robots + {OBSTACLES} obstacles, 640×480 at "
        f"{FPS:g} frames/s (PoseArray + Odometry every frame, MarkerArray at "
        f"{ROS2.markers_rate_hz:g} Hz, JPEG image + CameraInfo at {ROS2.image_rate_hz:g} Hz;"
        " each kind of frame's p50 by its share; floor: the frame path p50, preprocess +"
        " label + pose stages in one process, same frames)"
    )
    met = bool(extra <= TARGET * floor)
    return [Row(name, "ms", extra, floor, ratio(extra, floor), f"ratio ≤ {TARGET:.2f}", met)]
