"""One camera of the simulated camera grid (``grid:2x2:cam01``) over the physical world:
the grid's cameras (:func:`ovis.common.sim.gridview.grid_specs`, their poses and lenses
from the seed) looking at one physical world on the grid's whole floor.

Every camera's process builds the same world from the seed (:func:`grid_world`: the
configuration's ``[physical]`` scene on the grid's arena, placed without regard to any
one view, so that it does not depend on which camera builds it), and renders one period
of it, frame ``f`` showing ``t = f · period_s / N`` (N frames a period at the capture's
``[service] fps``), each from the physics state at that instant: a prerendered period
loops without a jump, and the grid's shared trigger
(:class:`~ovis.common.capture.sources.GridSource`) plays it on every camera at once.
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.calibration.file import Calibration
from ovis.common.config import OvisConfig, PinholeParams
from ovis.common.physical import camera, model, scene, world
from ovis.common.physical.marks import calibrate_on_marks, measure_marks
from ovis.common.physical.scene import Scene, random_scene
from ovis.common.physical.world import PhysicalWorld
from ovis.common.sim.arena import FrameTruth
from ovis.common.sim.gridview import CELL_CM, PeriodCamera, grid_specs
from ovis.common.sim.multiview import grid_arena

__all__ = [
    "MARKS_PER_CAMERA",
    "PhysicalGridCamera",
    "calibrate_grid_camera",
    "grid_config",
    "grid_world",
    "period_frames",
]

#: Floor marks laid per camera of a grid (spread over the whole floor): enough for each
#: camera to see the four a pose needs, and more, in its cell.
MARKS_PER_CAMERA = 8


def grid_config(config: OvisConfig, nx: int, ny: int) -> OvisConfig:
    """``config`` on the floor of an ``nx × ny`` grid (its ``[simulator]`` arena), with
    :data:`MARKS_PER_CAMERA` floor marks per camera unless it lays more."""
    x, y = grid_arena(nx, ny, CELL_CM)
    sim = msgspec.structs.replace(config.simulator, arena_x_cm=x, arena_y_cm=y)
    marks = min(64, max(config.physical.floor_marks, MARKS_PER_CAMERA * nx * ny))
    phys = msgspec.structs.replace(config.physical, floor_marks=marks)
    return msgspec.structs.replace(config, simulator=sim, physical=phys)


def grid_world(config: OvisConfig, nx: int, ny: int, seed: int) -> Scene:
    """The physical world every camera of the grid sees (the module docstring)."""
    return random_scene(grid_config(config, nx, ny), seed, [])


def period_frames(config: OvisConfig, period_s: float) -> int:
    """Frames in one period at the capture's rate (at least one)."""
    fps = config.service.fps if config.service.fps > 0 else config.simulator.fps
    return max(1, round(period_s * fps))


class PhysicalGridCamera(PeriodCamera):
    """Camera ``name`` of an ``nx × ny`` grid over the physical world of ``seed``."""

    def __init__(self, config: OvisConfig, nx: int, ny: int, name: str, seed: int) -> None:
        specs = grid_specs(nx, ny, config, seed)
        names = [s.name for s in specs]
        if name not in names:
            raise ValueError(f"no camera {name!r} in a {nx}x{ny} grid ({', '.join(names)})")
        cam = specs[names.index(name)].camera
        assert isinstance(cam, PinholeParams)
        self.name, self.seed, self.cam = name, int(seed), cam
        self.config = grid_config(config, nx, ny)
        self.scene = grid_world(config, nx, ny, seed)
        self.period = period_frames(config, self.scene.period_s)
        self._world: PhysicalWorld | None = None

    @property
    def world(self) -> PhysicalWorld:
        """This camera's MuJoCo world (built on first use)."""
        if self._world is None:
            self._world = PhysicalWorld(self.scene, self.config, [self.cam])
        return self._world

    def time_of(self, frame: int) -> float:
        """The instant (s) frame ``frame`` of the period shows."""
        return (frame % self.period) * self.scene.period_s / self.period

    def floor(self) -> NDArray[np.uint8]:
        """This camera's picture of the empty floor with its marks (no sensor noise)."""
        return self.world.clean(solids=False)

    def render(self, frame: int) -> tuple[NDArray[np.uint8], FrameTruth]:
        """Frame ``frame`` (modulo the period) and the truth of the whole floor then."""
        frame %= self.period
        self.world.set_time(self.time_of(frame))
        return self.world.render(frame), self.world.truth(frame)

    def _truth(self, frame: int) -> FrameTruth:
        """Frame ``frame``'s truth, read from the physics state at its instant."""
        self.world.set_time(self.time_of(frame))
        return self.world.truth(frame)

    def close(self) -> None:
        if self._world is not None:
            self._world.close()

    def _cache_key(self) -> str:
        h = hashlib.sha256()
        key = [self.config.simulator, self.config.physical, self.config.pose, self.cam]
        h.update(msgspec.json.encode([key, self.name, self.seed, self.period]))
        for module in (camera, model, scene, world, sys.modules[__name__]):
            h.update(Path(module.__file__ or "").read_bytes())
        h.update(f"mujoco {_mujoco_version()}".encode())
        return f"physical-{self.name}-{h.hexdigest()[:20]}"


def calibrate_grid_camera(camera: PhysicalGridCamera) -> tuple[Calibration, NDArray[np.uint8]]:
    """The grid camera calibrated as one camera is (:mod:`ovis.common.physical.marks`):
    its pose solved on the floor marks it sees in its picture of the empty floor, its
    lens fixed at its own; and that picture (for ``[image] background``)."""
    floor = camera.floor()
    points = measure_marks(floor, camera.scene.marks, camera.cam)
    source = (
        f"{len(points)} floor marks of the empty floor seen by {camera.name} (physical "
        f"world, seed {camera.seed}), its own lens"
    )
    calib = calibrate_on_marks(points, camera.cam, camera.config, source=source)
    return msgspec.structs.replace(calib, simulated=True), floor


def _mujoco_version() -> str:
    import mujoco

    return str(mujoco.__version__)
