"""What stands in the physical world: solid prisms on the floor, their paths, floor marks
and ceiling lamps, drawn from a seed (:func:`random_scene`).

Every solid is an upright prism standing on the floor (Z = 0): a cylinder, a box or a
regular prism with 3, 5 or 6 sides, ``height_cm`` tall, its footprint as large as a disk
of radius ``radius_cm`` (``equal-area radius``, the radius ovis reports). Each moves on a
closed ellipse (:class:`Path`) traversed once per :attr:`Scene.period_s`, so the world
repeats with that period; a robot's heading follows its path, an obstacle keeps its
yaw. The generator keeps every footprint inside the arena and, top included, inside the
image of each camera it must be seen by, and ``gap_cm`` between any two footprints at
every instant (checked on their circumscribed disks at :data:`PATH_SAMPLES` instants of
the period).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.camera.projection import project
from ovis.common.config import CameraModel, OvisConfig

__all__ = [
    "PATH_SAMPLES",
    "FloorMark",
    "Lamp",
    "Path",
    "Scene",
    "Solid",
    "ceiling_lamps",
    "draw_solid",
    "footprint",
    "path_fits",
    "random_scene",
    "spread_marks",
]

#: Instants of the period at which paths are checked for gaps and visibility.
PATH_SAMPLES = 96
#: Seconds the world takes to repeat (each path is one lap of it).
PERIOD_S = 20.0
#: Margin (px) between a solid's outline and the image border, at every instant.
IMAGE_MARGIN_PX = 4.0
#: Random placements tried per solid before the scene is drawn again.
TRIES = 300
RESTARTS = 40
#: Sides of the prisms drawn for "prism".
PRISM_SIDES = (3, 5, 6)
#: Box length over width, drawn in this range.
BOX_ASPECT = (1.0, 2.2)
#: Points on a cylinder's outline when checking it against the image.
RING = 24

FloatArray = NDArray[np.float64]


class Path(msgspec.Struct, frozen=True, kw_only=True):
    """A closed ellipse, one lap per period: centre (cm), semi-axes ``a ≥ b`` (cm, 0:
    standing still), the major axis at ``alpha_deg`` from +X, the phase at t = 0 (deg)
    and the sense (+1 counter-clockwise)."""

    cx_cm: float
    cy_cm: float
    a_cm: float = 0.0
    b_cm: float = 0.0
    alpha_deg: float = 0.0
    phase_deg: float = 0.0
    sense: float = 1.0

    def at(self, t_s: FloatArray | float, period_s: float) -> tuple[FloatArray, FloatArray]:
        """Position (cm) at times ``t_s``."""
        th = math.radians(self.phase_deg) + self.sense * 2.0 * math.pi * np.asarray(t_s) / period_s
        ca, sa = math.cos(math.radians(self.alpha_deg)), math.sin(math.radians(self.alpha_deg))
        u, v = self.a_cm * np.cos(th), self.b_cm * np.sin(th)
        return self.cx_cm + u * ca - v * sa, self.cy_cm + u * sa + v * ca

    def velocity(self, t_s: FloatArray | float, period_s: float) -> tuple[FloatArray, FloatArray]:
        """Velocity (cm/s) at times ``t_s``."""
        w = self.sense * 2.0 * math.pi / period_s
        th = math.radians(self.phase_deg) + w * np.asarray(t_s)
        ca, sa = math.cos(math.radians(self.alpha_deg)), math.sin(math.radians(self.alpha_deg))
        du, dv = -self.a_cm * w * np.sin(th), self.b_cm * w * np.cos(th)
        return du * ca - dv * sa, du * sa + dv * ca

    @property
    def moving(self) -> bool:
        return self.a_cm > 0.0


class Solid(msgspec.Struct, frozen=True, kw_only=True):
    """One upright prism: obstacle or robot, its shape and size, grey albedo, path; a
    marked robot's marker (``marker_id``, ``marker_side_cm``, printed on its top).
    ``yaw_deg`` is an obstacle's fixed yaw (a robot's follows its path)."""

    id: int
    kind: Literal["robot", "obstacle"]
    shape: Literal["cylinder", "box", "prism"]
    height_cm: float
    radius_cm: float  # equal-area radius of the footprint
    length_cm: float = 0.0  # box
    width_cm: float = 0.0  # box
    sides: int = 0  # prism
    yaw_deg: float = 0.0
    albedo: float = 0.8
    path: Path
    marker_id: int | None = None
    marker_side_cm: float = 0.0

    @property
    def bound_cm(self) -> float:
        """Radius of the circumscribed disk of the footprint."""
        if self.shape == "box":
            return math.hypot(self.length_cm, self.width_cm) / 2.0
        if self.shape == "prism":
            return circumradius(self.radius_cm, self.sides)
        return self.radius_cm


class FloorMark(msgspec.Struct, frozen=True, kw_only=True):
    """A flat white disc on the floor at a known place (calibration points)."""

    name: str
    x_cm: float
    y_cm: float
    radius_cm: float


class Lamp(msgspec.Struct, frozen=True, kw_only=True):
    """A ceiling lamp (a spot light pointing down), world cm."""

    x_cm: float
    y_cm: float
    z_cm: float


class Scene(msgspec.Struct, frozen=True, kw_only=True):
    """Everything in one physical world (see the module's docstring)."""

    seed: int
    period_s: float
    arena_x_cm: tuple[float, float]
    arena_y_cm: tuple[float, float]
    solids: list[Solid]
    marks: list[FloorMark]
    lamps: list[Lamp]
    floor_albedo: float
    ambient: float
    shadows: bool


def circumradius(radius_cm: float, sides: int) -> float:
    """Circumradius of the regular ``sides``-gon whose area is π·radius²."""
    return radius_cm * math.sqrt(2.0 * math.pi / (sides * math.sin(2.0 * math.pi / sides)))


def footprint(solid: Solid, x: float, y: float, yaw_rad: float, ring: int = RING) -> FloatArray:
    """(k, 2) corners of the solid's footprint (cm) at (x, y) turned by ``yaw_rad``: a
    cylinder as a circumscribed ``ring``-gon."""
    if solid.shape == "box":
        hl, hw = solid.length_cm / 2.0, solid.width_cm / 2.0
        local = np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])
    elif solid.shape == "prism":
        a = 2.0 * math.pi * np.arange(solid.sides) / solid.sides
        local = circumradius(solid.radius_cm, solid.sides) * np.stack([np.cos(a), np.sin(a)], 1)
    else:
        a = 2.0 * math.pi * np.arange(ring) / ring
        r = solid.radius_cm / math.cos(math.pi / ring)
        local = r * np.stack([np.cos(a), np.sin(a)], 1)
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return local @ np.array([[c, s], [-s, c]]) + np.array([x, y])


def _in_images(
    cameras: Sequence[CameraModel], x: FloatArray, y: FloatArray, z: float, margin: float
) -> bool:
    """Whether every point (cm, at height z) lies inside every camera's image margin."""
    for cam in cameras:
        p = project(x, y, np.full_like(x, z), cam)
        inside = (
            p.valid
            & (p.row >= margin)
            & (p.row <= cam.rows - 1 - margin)
            & (p.col >= margin)
            & (p.col <= cam.cols - 1 - margin)
        )
        if not inside.all():
            return False
    return True


def draw_solid(
    rng: np.random.Generator, config: OvisConfig, ident: int, kind: str, marker: int | None
) -> Solid:
    """Shape, size, height and albedo of one solid (its path comes later)."""
    phys = config.physical
    albedo = float(rng.uniform(*phys.object_albedo))
    if kind == "robot":
        length, width = config.simulator.robot_size_cm
        side = 0.0
        if marker is not None:
            spec = next(r for r in config.pose.robots if r.marker_id == marker)
            side = spec.marker_side_cm
        return Solid(
            id=ident,
            kind="robot",
            shape="box",
            height_cm=float(config.pose.robot_height_cm),
            radius_cm=math.sqrt(length * width / math.pi),
            length_cm=float(length),
            width_cm=float(width),
            albedo=albedo,
            path=Path(cx_cm=0.0, cy_cm=0.0),
            marker_id=marker,
            marker_side_cm=side,
        )
    shape = str(rng.choice(phys.shapes))
    radius = float(rng.uniform(*phys.radius_cm))
    height = float(rng.uniform(*phys.height_cm))
    yaw = float(rng.uniform(-180.0, 180.0))
    extra: dict[str, float | int] = {}
    if shape == "box":
        q = float(rng.uniform(*BOX_ASPECT))
        width = math.sqrt(math.pi * radius * radius / q)
        extra = {"length_cm": q * width, "width_cm": width}
    elif shape == "prism":
        extra = {"sides": int(rng.choice(PRISM_SIDES))}
    else:
        yaw = 0.0
    return Solid(
        id=ident,
        kind="obstacle",
        shape=shape,  # type: ignore[arg-type]
        height_cm=height,
        radius_cm=radius,
        yaw_deg=yaw,
        albedo=albedo,
        path=Path(cx_cm=0.0, cy_cm=0.0),
        **extra,  # type: ignore[arg-type]
    )


class _Placed:
    """Solids placed so far, sampled over the period (for the gap rule)."""

    def __init__(self, times: FloatArray) -> None:
        self.times = times
        self.x: list[FloatArray] = []
        self.y: list[FloatArray] = []
        self.bound: list[float] = []

    def clear_of(self, x: FloatArray, y: FloatArray, bound: float, gap: float) -> bool:
        for ox, oy, ob in zip(self.x, self.y, self.bound, strict=True):
            if np.min(np.hypot(x - ox, y - oy)) < bound + ob + gap:
                return False
        return True

    def add(self, x: FloatArray, y: FloatArray, bound: float) -> None:
        self.x.append(x)
        self.y.append(y)
        self.bound.append(bound)


def path_fits(
    solid: Solid,
    path: Path,
    config: OvisConfig,
    cameras: Sequence[CameraModel],
    times: FloatArray,
    period: float,
) -> tuple[FloatArray, FloatArray] | None:
    """The path's samples at ``times`` if the solid stays in the arena and, top
    included, in every camera's view at each of them; else None."""
    (x0, x1), (y0, y1) = config.simulator.arena_x_cm, config.simulator.arena_y_cm
    x, y = path.at(times, period)
    b = solid.bound_cm
    if x.min() - b < x0 or x.max() + b > x1 or y.min() - b < y0 or y.max() + b > y1:
        return None
    step = max(1, len(times) // 12)  # the image test on fewer instants: paths are smooth
    ring = 2.0 * math.pi * np.arange(RING) / RING
    px = (x[::step, None] + b * np.cos(ring)).ravel()
    py = (y[::step, None] + b * np.sin(ring)).ravel()
    for z in (0.0, solid.height_cm):
        if not _in_images(cameras, px, py, z, IMAGE_MARGIN_PX):
            return None
    return x, y


def _draw_path(rng: np.random.Generator, solid: Solid, config: OvisConfig, period: float) -> Path:
    """A random path for a solid: robots lap a wide ellipse, obstacles a small one
    (or stand still when ``speed_cm_s`` is 0)."""
    (x0, x1), (y0, y1) = config.simulator.arena_x_cm, config.simulator.arena_y_cm
    phys = config.physical
    span = min(x1 - x0, y1 - y0)
    if solid.kind == "robot":
        moving = phys.robots_move
        a_hi = 0.35 * span
        speed = max(phys.speed_cm_s, 1e-9) * 2.0
    else:
        moving = phys.speed_cm_s > 0.0
        a_hi = 0.12 * span
        speed = phys.speed_cm_s
    a = b = 0.0
    if moving:
        # one lap of the ellipse per period at no more than the speed
        a = float(rng.uniform(0.3, 1.0)) * min(a_hi, speed * period / (2.0 * math.pi))
        b = float(rng.uniform(0.5, 1.0)) * a
    cx = float(rng.uniform(x0 + a, x1 - a)) if x1 - x0 > 2 * a else (x0 + x1) / 2
    cy = float(rng.uniform(y0 + a, y1 - a)) if y1 - y0 > 2 * a else (y0 + y1) / 2
    return Path(
        cx_cm=cx,
        cy_cm=cy,
        a_cm=a,
        b_cm=b,
        alpha_deg=float(rng.uniform(-180.0, 180.0)),
        phase_deg=float(rng.uniform(0.0, 360.0)),
        sense=float(rng.choice([-1.0, 1.0])),
    )


def ceiling_lamps(config: OvisConfig) -> list[Lamp]:
    """The ceiling lamps over the arena: a row or a grid round its centre."""
    (x0, x1), (y0, y1) = config.simulator.arena_x_cm, config.simulator.arena_y_cm
    n = config.physical.lights
    cols = math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    z = config.physical.light_height_cm
    out: list[Lamp] = []
    for k in range(n):
        i, j = k % cols, k // cols
        x = x0 + (x1 - x0) * (i + 0.5) / cols
        y = y0 + (y1 - y0) * (j + 0.5) / rows
        out.append(Lamp(x_cm=x, y_cm=y, z_cm=z))
    return out


def spread_marks(
    rng: np.random.Generator, config: OvisConfig, cameras: Sequence[CameraModel]
) -> list[FloorMark]:
    """Floor marks spread over the arena (a jittered grid), inside every camera's view."""
    n = config.physical.floor_marks
    if n == 0:
        return []
    (x0, x1), (y0, y1) = config.simulator.arena_x_cm, config.simulator.arena_y_cm
    r = config.physical.mark_radius_cm
    cols = math.ceil(math.sqrt(n * (x1 - x0) / max(y1 - y0, 1e-9)))
    rows = math.ceil(n / cols)
    ring = 2.0 * math.pi * np.arange(RING) / RING
    out: list[FloorMark] = []
    for k in range(rows * cols):
        if len(out) == n:
            break
        i, j = k % cols, k // cols
        for _ in range(50):
            x = x0 + (x1 - x0) * (i + rng.uniform(0.2, 0.8)) / cols
            y = y0 + (y1 - y0) * (j + rng.uniform(0.2, 0.8)) / rows
            if _in_images(cameras, x + 2 * r * np.cos(ring), y + 2 * r * np.sin(ring), 0.0, 8.0):
                out.append(FloorMark(name=f"M{len(out) + 1}", x_cm=x, y_cm=y, radius_cm=r))
                break
    return out


def random_scene(
    config: OvisConfig, seed: int, cameras: Sequence[CameraModel], *, robots: int = 1
) -> Scene:
    """A scene drawn from ``seed`` (the same seed, the same scene): ``robots`` robots
    (marked ones per ``config.pose.robots``, which then sets their number; else one
    unmarked robot, or none with ``robots=0``) and ``[physical] n_obstacles``
    obstacles, each seen whole by every camera of ``cameras`` at every instant.

    Raises ValueError when the solids find no room (say what to change).
    """
    if int(seed) < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed}")
    phys = config.physical
    rng = np.random.default_rng([int(seed), 36])
    period = PERIOD_S
    times = np.linspace(0.0, period, PATH_SAMPLES, endpoint=False)
    marked = [r.marker_id for r in config.pose.robots]
    markers: list[int | None] = list(marked) if marked else [None] * int(robots)
    ids = [r.id for r in config.pose.robots] if marked else list(range(len(markers)))
    first_obstacle = max(ids, default=-1) + 1
    for _attempt in range(RESTARTS):
        placed = _Placed(times)
        solids: list[Solid] = []
        kinds = [("robot", ident, m) for ident, m in zip(ids, markers, strict=True)]
        kinds += [("obstacle", first_obstacle + k, None) for k in range(phys.n_obstacles)]
        for kind, ident, marker in kinds:
            shape = draw_solid(rng, config, ident, kind, marker)
            for _ in range(TRIES):
                path = _draw_path(rng, shape, config, period)
                samples = path_fits(shape, path, config, cameras, times, period)
                if samples is None or not placed.clear_of(*samples, shape.bound_cm, phys.gap_cm):
                    continue
                placed.add(*samples, shape.bound_cm)
                solids.append(msgspec.structs.replace(shape, path=path))
                break
            else:
                break  # no room for this one: draw the scene again
        else:
            return Scene(
                seed=int(seed),
                period_s=period,
                arena_x_cm=config.simulator.arena_x_cm,
                arena_y_cm=config.simulator.arena_y_cm,
                solids=solids,
                marks=spread_marks(rng, config, cameras),
                lamps=ceiling_lamps(config),
                floor_albedo=phys.floor_albedo,
                ambient=phys.ambient,
                shadows=phys.shadows,
            )
    raise ValueError(
        f"cannot place {len(markers)} robot(s) and {phys.n_obstacles} obstacles of radius "
        f"{phys.radius_cm} cm with gaps of {phys.gap_cm} cm inside the arena x "
        f"{config.simulator.arena_x_cm} cm, y {config.simulator.arena_y_cm} cm and every "
        "camera's view; use fewer or smaller obstacles ([physical]) or a larger arena"
    )
