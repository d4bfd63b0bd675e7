"""The stages' own work on one frame, in one process: the floor the services' per-frame
CPU is compared with.

:class:`FramePath` runs a frame through the preprocess, label and pose stages of
:mod:`ovis.common.pipeline.stages` as the services run them (grey image, median step
and binarisation; labeling, size filter, perimeter and marker search with the plane
tables; robots, obstacles and the planner's inputs), keeping what each service keeps
between frames, and times each stage.

:func:`stage_work_ms` measures it on camera ``cam00`` of the ``ovis up --cameras 2x2``
world (its configuration and frames, :class:`~ovis.common.sim.gridview.GridCamera`),
warm, and with ``evict_mb`` of other memory written between the stages: what running
beside a dozen other processes on the same core does to the caches a stage finds.
"""

from __future__ import annotations

import time

import msgspec
import numpy as np

from ovis.common.calibration.file import Calibration, calibration_from_config
from ovis.common.camera.plane_table import PlaneTables
from ovis.common.config import OvisConfig, PinholeParams
from ovis.common.messages import Frame, ObstacleFrame
from ovis.common.pipeline.stages import SizeFilter, binary_frame, blob_list, obstacle_frame
from ovis.common.vision.contrast import ObjectWindow
from ovis.common.vision.frames import as_gray
from ovis.common.world.detection import Detector
from ovis.common.world.marker_search import BlobMarkers

__all__ = ["STAGES", "FramePath", "grid_camera_frames", "stage_work_ms"]

STAGES = ("preprocess", "label", "pose")


class FramePath:
    """The three stages of one frame, in one process, with what each service keeps
    between frames; :attr:`last_ms` holds each stage's time of the last frame."""

    def __init__(self, config: OvisConfig) -> None:
        self.calib: Calibration = msgspec.structs.replace(
            calibration_from_config(config), version=1
        )
        calib = self.calib
        self.detector = Detector(calib.camera, calib.image, calib.pose)
        self.detector.robots.prepare(calib.camera)
        self.markers, self.window = BlobMarkers(), ObjectWindow()
        self.find_markers, self.size_filter = BlobMarkers(), SizeFilter()
        self.tables = PlaneTables()
        if calib.pose.robots:
            self.find_markers.sizes(calib.version, calib.camera, calib.pose)
        if isinstance(calib.camera, PinholeParams):
            heights = (calib.pose.obstacle_height_cm, calib.pose.robot_height_cm)
            self.tables.prepare(calib.camera, heights, wait=True)
        self.last_ms = dict.fromkeys(STAGES, 0.0)
        self.between: np.ndarray | None = None  # memory written between the stages

    def _evict(self) -> None:
        if self.between is not None:
            self.between += 1

    def __call__(self, frame: Frame) -> ObstacleFrame:
        calib = self.calib
        self._evict()
        t0 = time.perf_counter()
        binary = binary_frame(frame, as_gray(frame.image()), calib, self.markers, self.window)
        t1 = time.perf_counter()
        self._evict()
        t2 = time.perf_counter()
        area = self.size_filter.min_area_px(calib)
        blobs = blob_list(binary, calib, area, self.find_markers, self.tables)
        t3 = time.perf_counter()
        self._evict()
        t4 = time.perf_counter()
        out = obstacle_frame(blobs, self.detector, calib.version, "default", frame.stamp_ns)
        t5 = time.perf_counter()
        self.last_ms = {"preprocess": (t1 - t0) * 1e3, "label": (t3 - t2) * 1e3,
                        "pose": (t5 - t4) * 1e3}  # fmt: skip
        return out


def grid_camera_frames(seed: int, n: int, camera: int = 0) -> tuple[OvisConfig, list[Frame]]:
    """Camera ``camera``'s (0: ``cam00``) chain configuration of ``ovis up --cameras 2x2
    --seed seed`` and its first ``n`` frames, stamped at 30 frames/s."""
    from ovis.common.config import with_options
    from ovis.common.sim.gridview import GridCamera, grid_specs
    from ovis.common.sim.scenes import marked_scene
    from ovis.services.cli.multicam_up import OBSTACLES, ROBOTS

    base = marked_scene(with_options(None, seed=seed), ROBOTS, OBSTACLES)
    spec = grid_specs(2, 2, base, base.service.seed)[camera]
    config = msgspec.structs.replace(base, camera=spec.camera)
    camera = GridCamera(config, 2, 2, spec.name, base.service.seed)
    frames = [
        Frame.from_image(camera.render(i)[0], seq=i, stamp_ns=round(i * 1e9 / 30), copy=False)
        for i in range(n)
    ]
    return config, frames


def stage_work_ms(seed: int, reps: int, evict_mb: float = 0.0, camera: int = 0) -> dict[str, float]:
    """Each stage's median ms per frame on camera ``camera``'s frames (0: ``cam00``;
    :func:`grid_camera_frames`), after a warm-up, with ``evict_mb`` MB written between
    the stages (0: warm caches)."""
    config, frames = grid_camera_frames(seed, 60, camera)
    path = FramePath(config)
    for frame in frames:  # the warm-up: the trackers and tables in their steady state
        path(frame)
    if evict_mb:
        path.between = np.zeros(int(evict_mb * 2**20) // 8)
    times: dict[str, list[float]] = {stage: [] for stage in STAGES}
    for i in range(reps):
        path(msgspec.structs.replace(frames[i % len(frames)], stamp_ns=round((60 + i) * 1e9 / 30)))
        for stage in STAGES:
            times[stage].append(path.last_ms[stage])
    return {stage: float(np.median(v)) for stage, v in times.items()}
