"""Ready-made simulated scenes: ``N`` marked robots and ``M`` obstacles (``ovis simulate
--robots N --obstacles M``, the accuracy study and benchmarks)."""

from __future__ import annotations

import msgspec
import numpy as np

from ovis.common.camera.projection import back_project
from ovis.common.config import OvisConfig, RobotSpec

__all__ = ["MARKED_ROBOT", "marked_scene"]

#: The simulated marked robot: top 14 × 10 cm carrying a 7 cm marker (a white margin
#: of at least one marker cell all round), radius 9 cm, at 30 cm/s at 30 frames/s.
MARKED_ROBOT = {"size_cm": (14.0, 10.0), "marker_side_cm": 7.0, "radius_cm": 9.0, "speed": 1.0}


def marked_scene(config: OvisConfig, robots: int, obstacles: int | None = None) -> OvisConfig:
    """``config`` with ``robots`` marked robots (ids 1…N, markers 0…N−1 of the configured
    dictionary, unless ``pose.robots`` already lists them) and ``obstacles`` obstacles,
    on the whole floor the camera sees."""
    if robots < 1:
        raise ValueError(f"a marked scene needs at least one robot, got {robots}")
    pose, sim = config.pose, config.simulator
    listed = list(pose.robots)
    if len(listed) != robots:
        listed = [
            RobotSpec(
                id=i + 1,
                name=f"robot{i + 1}",
                marker_id=i,
                marker_side_cm=MARKED_ROBOT["marker_side_cm"],
                marker_height_cm=pose.robot_height_cm,
                radius_cm=MARKED_ROBOT["radius_cm"],
            )
            for i in range(robots)
        ]
    cam = config.camera
    rows, cols = cam.rows - 1.0, cam.cols - 1.0
    corners = back_project(np.array([0.0, 0.0, rows, rows]), np.array([0.0, cols, 0.0, cols]), cam)
    x, y = np.asarray(corners.x_cm)[corners.valid], np.asarray(corners.y_cm)[corners.valid]
    arena = {}
    if x.size == 4:  # the floor the image sees (the image rule keeps objects inside it)
        arena = {
            "arena_x_cm": (float(x.min()), float(x.max())),
            "arena_y_cm": (float(y.min()), float(y.max())),
        }
    sim = msgspec.structs.replace(
        sim,
        n_obstacles=sim.n_obstacles if obstacles is None else obstacles,
        robot_size_cm=MARKED_ROBOT["size_cm"],
        speed_cm_per_frame=MARKED_ROBOT["speed"],
        **arena,
    )
    pose = msgspec.structs.replace(pose, robots=listed)
    return msgspec.structs.replace(config, pose=pose, simulator=sim)
