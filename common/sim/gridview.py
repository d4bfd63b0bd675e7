"""What one camera of the simulated camera grid sees: real frames of the shared
:class:`~ovis.common.sim.multiview.GridScene` rendered through that camera's own model
(pose and lens, :func:`~ovis.common.sim.multiview.camera_grid`), with the one-camera
arena's painting (:mod:`ovis.common.sim.painting`): anti-aliased top faces, the robots'
markers, lighting, blur, sensor and pepper noise (no clutter specks).

Source spec ``grid:<nx>x<ny>:<camera>`` (e.g. ``grid:2x2:cam01``, see
:func:`parse_grid_source`); every camera of one grid is built from the same seed
(``service.seed``), so the chains of separate processes see one scene. The scene is
periodic (:data:`PERIOD_FRAMES`), so one period rendered once loops seamlessly.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import math
import re
import sys
from collections.abc import Callable
from pathlib import Path

import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.atomic import write_atomic
from ovis.common.camera.projection import camera_centre_cm
from ovis.common.config import OvisConfig, PinholeParams
from ovis.common.sim import arena, multiview, painting
from ovis.common.sim.arena import FrameTruth, SimObject, lighting_field
from ovis.common.sim.multiview import GridScene, camera_grid, grid_arena
from ovis.common.sim.painting import (
    PlaneSamples,
    finish_frame,
    marker_hand,
    paint_marker,
    paint_top_face,
)
from ovis.common.vision.markers import marker_cells

__all__ = [
    "CELL_CM",
    "PERIOD_FRAMES",
    "GridCamera",
    "PeriodCamera",
    "cached_period",
    "grid_scene",
    "grid_specs",
    "parse_grid_source",
]

#: floor cell of each camera of the grid (cm)
CELL_CM = (100.0, 75.0)
#: the grid scene repeats every this many frames (10 s at 30 frames/s)
PERIOD_FRAMES = 300

_GRID_RE = re.compile(r"grid:([1-8])x([1-8]):(cam[0-7][0-7])")


def parse_grid_source(spec: str) -> tuple[int, int, str]:
    """``"grid:2x2:cam01"`` → (2, 2, "cam01"); ValueError naming the form otherwise."""
    m = _GRID_RE.fullmatch(spec.strip())
    if m is None:
        raise ValueError(
            f"source {spec!r}: a camera of the simulated grid is grid:<columns>x<rows>:cam<i><j>,"
            " e.g. grid:2x2:cam01 (1 to 8 each way)"
        )
    nx, ny, name = int(m.group(1)), int(m.group(2)), m.group(3)
    i, j = int(name[3]), int(name[4])
    if i >= nx or j >= ny:
        raise ValueError(
            f"source {spec!r}: a {nx}x{ny} grid has cameras cam00 to cam{nx - 1}{ny - 1}"
        )
    return nx, ny, name


def grid_specs(nx: int, ny: int, config: OvisConfig, seed: int):
    """The grid's cameras for ``config``'s frame size (``config.camera``'s)."""
    return camera_grid(
        nx,
        ny,
        cell_cm=CELL_CM,
        rows=int(config.camera.rows),
        cols=int(config.camera.cols),
        seed=seed,
    )


def grid_scene(nx: int, ny: int, config: OvisConfig, seed: int) -> GridScene:
    """The shared scene: one marked robot per ``pose.robots`` entry (ids 1…N, markers
    0…N−1) and ``simulator.n_obstacles`` still obstacles, periodic."""
    pose = config.pose
    return GridScene(
        *grid_arena(nx, ny, CELL_CM),
        robots=len(pose.robots),
        obstacles=config.simulator.n_obstacles,
        seed=seed,
        fps=config.simulator.fps,
        robot_height_cm=pose.robot_height_cm,
        obstacle_height_cm=pose.obstacle_height_cm,
        obstacle_radius_cm=config.simulator.obstacle_radius_cm,
        period_frames=PERIOD_FRAMES,
    )


def cached_period(
    render: Callable[[int], NDArray[np.uint8]],
    shape: tuple[int, int, int],
    cached: Path | None,
    progress: Callable[[int, int], None] | None = None,
) -> NDArray[np.uint8]:
    """The ``shape[0]`` frames of a period, read-only: read back (memory-mapped) from
    ``cached`` when it holds them, else rendered (``render(f)``; ``progress(done,
    total)`` after each) and kept there (a cache that cannot be written: none)."""
    if cached is not None and cached.is_file():
        try:
            frames = np.load(cached, mmap_mode="r")
            if frames.shape == shape:
                if progress is not None:
                    progress(shape[0], shape[0])
                return frames
        except (OSError, ValueError):
            pass  # unreadable: render again and replace it
    images = np.empty(shape, np.uint8)
    for f in range(shape[0]):
        images[f] = render(f)
        if progress is not None:
            progress(f + 1, shape[0])
    images.setflags(write=False)
    if cached is not None:
        with contextlib.suppress(OSError):
            cached.parent.mkdir(parents=True, exist_ok=True)
            buf = io.BytesIO()
            np.save(buf, images)
            write_atomic(cached, buf.getbuffer())
    return images


class PeriodCamera:
    """A camera of the grid that renders one period of its scene once (:meth:`render`,
    ``period`` frames of ``cam``'s size) and keeps it in a cache named by
    :meth:`_cache_key`; :meth:`_truth` gives each frame's truth."""

    period: int
    cam: PinholeParams

    def render(self, frame: int) -> tuple[NDArray[np.uint8], FrameTruth]:
        raise NotImplementedError

    def _truth(self, frame: int) -> FrameTruth:
        raise NotImplementedError

    def _cache_key(self) -> str:
        raise NotImplementedError

    def render_period(
        self,
        progress: Callable[[int, int], None] | None = None,
        cache_dir: Path | None = None,
    ) -> list[tuple[NDArray[np.uint8], FrameTruth]]:
        """Every frame of one period, read-only; ``progress(done, total)`` after each.

        With ``cache_dir``, the frames are kept there (one ``.npy`` per camera, named by
        a hash of everything they depend on: the configuration, seed, camera and the
        scene and rendering code) and read back, memory-mapped, by the next run."""
        cached = None if cache_dir is None else cache_dir / f"{self._cache_key()}.npy"
        shape = (self.period, int(self.cam.rows), int(self.cam.cols))
        images = cached_period(lambda f: self.render(f)[0], shape, cached, progress)
        return [(images[f], self._truth(f)) for f in range(self.period)]


class GridCamera(PeriodCamera):
    """Camera ``name`` of an ``nx × ny`` grid rendering the shared scene (the module
    docstring). ``config.pose.robots`` must list robots ids 1…N with markers 0…N−1
    (as :func:`ovis.common.sim.scenes.marked_scene` makes them)."""

    def __init__(self, config: OvisConfig, nx: int, ny: int, name: str, seed: int) -> None:
        specs = grid_specs(nx, ny, config, seed)
        names = [s.name for s in specs]
        if name not in names:
            raise ValueError(f"no camera {name!r} in a {nx}x{ny} grid ({', '.join(names)})")
        self.name, self.seed, self.index = name, int(seed), names.index(name)
        cam = specs[self.index].camera
        assert isinstance(cam, PinholeParams)
        self.cam = cam
        self.scene = grid_scene(nx, ny, config, seed)
        self.period = PERIOD_FRAMES
        self._sim = config.simulator
        self._config_key = [config.simulator, config.pose, cam]
        by_marker = {r.marker_id: r for r in config.pose.robots}
        robots = [o for o in self.scene.objects(0) if o.kind == "robot"]
        missing = [o.marker_id for o in robots if o.marker_id not in by_marker]
        if missing:
            raise ValueError(
                f"the grid's robots carry markers 0-{len(robots) - 1}; pose.robots lacks "
                f"marker(s) {missing}"
            )
        self._markers = {
            o.marker_id: (
                marker_cells(config.pose.marker_dictionary, o.marker_id),
                by_marker[o.marker_id].marker_side_cm,
            )
            for o in robots
        }
        foot_x, foot_y, _ = camera_centre_cm(cam)
        self._hand = marker_hand(cam, foot_x, foot_y, self.scene.robot_z)
        light_rng = np.random.default_rng([self.seed, 19, self.index])
        self._light = lighting_field(
            cam,
            gradient=self._sim.lighting_gradient,
            vignetting=self._sim.vignetting,
            direction_rad=float(light_rng.uniform(0.0, 2.0 * math.pi)),
        )
        # the floor and the still obstacles, painted once; the robots' plane, sampled once
        self._background = np.full(self._light.shape, self._sim.floor_level, np.float32)
        for o in self.scene.objects(0):
            if o.kind == "obstacle":
                self._paint(self._background, o)
        self._robot_plane: PlaneSamples | None = None  # sampled at the first render

    def _paint(
        self, level: NDArray[np.float32], o: SimObject, samples: PlaneSamples | None = None
    ) -> None:
        heading = math.radians(o.heading_deg)
        paint_top_face(
            level, self.cam, self._sim, x=o.x_cm, y=o.y_cm, z=o.z_cm, heading=heading,
            half_len=o.length_cm / 2, half_wid=o.width_cm / 2, is_rect=o.shape == "rect",
            samples=samples,
        )  # fmt: skip
        if o.marker_id is not None:
            cells, side = self._markers[o.marker_id]
            paint_marker(
                level, self.cam, self._sim, cells=cells, side_cm=side, hand=self._hand,
                x=o.x_cm, y=o.y_cm, z=o.z_cm, heading=heading, samples=samples,
            )  # fmt: skip

    def render(self, frame: int) -> tuple[NDArray[np.uint8], FrameTruth]:
        """Frame ``frame`` (taken modulo the period) as this camera sees it, and the
        truth of the whole floor then (every object, seen by this camera or not)."""
        frame %= self.period
        if self._robot_plane is None:
            self._robot_plane = PlaneSamples(self.cam, self.scene.robot_z, self._sim.supersample)
        level = self._background.copy()
        for o in self.scene.objects(frame):
            if o.kind == "robot":
                self._paint(level, o, self._robot_plane)
        rng = np.random.default_rng([self.seed, 19, self.index, frame])
        return finish_frame(level, self._light, self._sim, rng), self._truth(frame)

    def _truth(self, frame: int) -> FrameTruth:
        return FrameTruth(index=frame, objects=self.scene.objects(frame))

    def _cache_key(self) -> str:
        h = hashlib.sha256()
        h.update(msgspec.json.encode([self._config_key, self.name, self.seed, self.period]))
        for module in (painting, multiview, arena, sys.modules[__name__]):
            h.update(Path(module.__file__ or "").read_bytes())
        return f"grid-{self.name}-{h.hexdigest()[:20]}"
