"""Accuracy of the marked robots against the simulator's ground truth (issue 16).

:func:`evaluate_marked` renders a marked arena (:func:`ovis.common.sim.scenes.marked_scene`),
runs :class:`ovis.common.world.detection.Detector` on every frame (frames
``1 / simulator.fps`` apart) and compares each reported robot with the truth:

* **swaps**: robot-frames whose reported position is nearer another robot's true centre
  than its own (identity swapped);
* **position** (cm) and **heading** (deg, wrapped) errors, mean and max over all
  robot-frames;
* **velocity** error |v̂ − v| (cm/s), mean and max over the frames after ``settle``
  frames of each robot's track;
* **robots as obstacles**: obstacles reported within a robot's radius of a true robot
  centre; **missed**: robot-frames with no report.
"""

from __future__ import annotations

import time

import msgspec
import numpy as np

from ovis.common.config import OvisConfig
from ovis.common.sim.arena import Arena
from ovis.common.sim.scenes import marked_scene
from ovis.common.world.detection import Detector
from ovis.common.world.planner import wrap_deg

__all__ = ["MarkedAccuracy", "evaluate_marked"]

#: Frames of a robot's track before its velocity counts (the filter settles).
SETTLE_FRAMES = 15


class MarkedAccuracy(msgspec.Struct, kw_only=True):
    """The numbers of one simulated run (see the module docstring)."""

    seed: int
    frames: int
    robots: int
    obstacles: int
    swaps: int
    missed: int
    robots_as_obstacles: int
    position_mean_cm: float
    position_max_cm: float
    heading_mean_deg: float
    heading_max_deg: float
    velocity_mean_cm_s: float
    velocity_max_cm_s: float
    ms_per_frame: float


def evaluate_marked(
    config: OvisConfig, *, seed: int, frames: int, robots: int = 4, obstacles: int = 6
) -> MarkedAccuracy:
    """Render ``frames`` frames of a marked arena and measure the detector against truth."""
    cfg = marked_scene(config, robots, obstacles)
    arena = Arena(cfg, seed)
    detector = Detector(cfg.camera, cfg.image, cfg.pose)
    radius = {r.id: r.radius_cm for r in cfg.pose.robots}
    fps = cfg.simulator.fps
    pos: list[float] = []
    head: list[float] = []
    vel: list[float] = []
    swaps = missed = as_obstacles = 0
    seen_frames: dict[int, int] = {}
    spent = 0.0
    for k, (image, truth) in enumerate(arena.frames(frames)):
        t0 = time.perf_counter()
        det = detector.detect(image, stamp_s=k / fps)
        spent += time.perf_counter() - t0
        true = {o.id: o for o in truth.objects if o.kind == "robot"}
        txy = np.array([[o.x_cm, o.y_cm] for o in true.values()])
        tids = np.array(list(true))
        missed += len(true) - len(det.robots)
        for r in det.robots:
            o = true[r.id]
            near = tids[np.hypot(*(txy - [r.x_cm, r.y_cm]).T).argmin()]
            swaps += int(near != r.id)
            pos.append(float(np.hypot(r.x_cm - o.x_cm, r.y_cm - o.y_cm)))
            head.append(float(abs(wrap_deg(r.heading_deg - o.heading_deg))))
            seen_frames[r.id] = seen_frames.get(r.id, 0) + 1
            if seen_frames[r.id] > SETTLE_FRAMES:
                vel.append(float(np.hypot(r.vx_cm_s - o.vx_cm_s, r.vy_cm_s - o.vy_cm_s)))
        for obj in det.objects:
            if obj.kind == "obstacle":
                d = np.hypot(txy[:, 0] - obj.x_cm, txy[:, 1] - obj.y_cm)
                as_obstacles += int((d <= [radius[i] for i in tids]).any())

    def mean_max(v: list[float]) -> tuple[float, float]:
        return (float(np.mean(v)), float(np.max(v))) if v else (float("nan"), float("nan"))

    (pm, px), (hm, hx), (vm, vx) = mean_max(pos), mean_max(head), mean_max(vel)
    return MarkedAccuracy(
        seed=seed,
        frames=frames,
        robots=robots,
        obstacles=obstacles,
        swaps=swaps,
        missed=missed,
        robots_as_obstacles=as_obstacles,
        position_mean_cm=pm,
        position_max_cm=px,
        heading_mean_deg=hm,
        heading_max_deg=hx,
        velocity_mean_cm_s=vm,
        velocity_max_cm_s=vx,
        ms_per_frame=1000.0 * spent / max(frames, 1),
    )
