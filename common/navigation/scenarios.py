"""The paper's two cases as driving scenarios, drawn from a seed (:func:`make_scenario`).

A robot starts at one side of the arena facing its goal at the other (``MARGIN_CM``
from the edges, at random heights); with two robots the second crosses from the bottom
to the top through the middle, so that their straight paths cross. Case 1 has two
moving obstacles, case 2 four (the paper's §5.2 cases). Each obstacle **crosses a
robot's straight path**: it passes a point of that path (a share of the way along it,
the obstacles spread over the way) at about the moment a robot driving straight at top
speed would be there (± ``TIMING_S``), at an angle of 45–135° to it, at up to
``[navigation] obstacle_speed`` × the robot's top speed. So a straight drive often
meets one.

An obstacle's path is a closed ellipse of the physical world
(:class:`~ovis.common.physical.scene.Path`, one lap per :data:`PERIOD_S`): the
crossing point is an end of its minor axis, where it moves along the major axis at its
top speed; the minor axis is a fraction of the major (a thin ellipse: back and forth
across the robot's way). Obstacles are drawn as the physical world draws them
(``[physical]`` shapes, sizes, heights, albedos), and kept in the arena and in every
camera's view, ``[physical] gap_cm`` apart, off the robots' starts for the first
seconds and off their goals, at every instant (their paths repeat: checked over one
period).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.config import CameraModel, OvisConfig
from ovis.common.physical.scene import (
    FloorMark,
    Path,
    Scene,
    Solid,
    ceiling_lamps,
    draw_solid,
    path_fits,
    random_scene,
    spread_marks,
)
from ovis.common.sim.scenes import marked_scene

__all__ = [
    "CASE_OBSTACLES",
    "PERIOD_S",
    "TRAINING_SEED0",
    "RobotTask",
    "Scenario",
    "driving_config",
    "live_drive_config",
    "make_scenario",
    "straight_time_s",
]

#: Obstacles of the paper's cases.
CASE_OBSTACLES = {1: 2, 2: 4}
#: One lap of an obstacle's path (s): longer than any run, so each crosses once or twice.
PERIOD_S = 24.0
#: Distance of starts and goals from the arena's edges (cm).
MARGIN_CM = 15.0
#: A crossing is timed within this of a straight driver's passage (s).
TIMING_S = 0.6
#: Where along a robot's way the crossings are (shares of its length).
CROSSING_SPAN = (0.2, 0.85)
#: Crossing angles to the robot's way (deg, either side).
CROSSING_ANGLE_DEG = (45.0, 135.0)
#: An obstacle's top speed, as a share of ``obstacle_speed`` × the robot's top speed.
SPEED_SHARE = (0.4, 1.0)
#: Minor over major semi-axis of an obstacle's ellipse.
THINNESS = (0.0, 0.4)
#: Clearance (cm) kept between an obstacle and a robot's start (during the first
#: ``START_CLEAR_S``) and goal (all the run), beyond both their radii.
CLEAR_CM = 6.0
START_CLEAR_S = 2.5
#: Time step (s) at which paths are checked.
CHECK_STEP_S = 0.1
TRIES = 200
RESTARTS = 60
#: Seeds from here on are the tuning's: evaluations use seeds below it.
TRAINING_SEED0 = 1_000_000


class RobotTask(msgspec.Struct, frozen=True, kw_only=True):
    """One robot's drive: where it starts (cm, facing ``yaw_deg``) and its goal (cm)."""

    id: int
    start_cm: tuple[float, float]
    yaw_deg: float
    goal_cm: tuple[float, float]
    radius_cm: float

    @property
    def distance_cm(self) -> float:
        return math.hypot(self.goal_cm[0] - self.start_cm[0], self.goal_cm[1] - self.start_cm[1])


class Scenario(msgspec.Struct, frozen=True, kw_only=True):
    """A drawn scenario: the physical scene (obstacles on their paths, robots standing at
    their starts), the robots' tasks, the run's timeout (s)."""

    seed: int
    case: int
    scene: Scene
    tasks: list[RobotTask]
    timeout_s: float

    @property
    def obstacles(self) -> list[Solid]:
        return [s for s in self.scene.solids if s.kind == "obstacle"]


def driving_config(config: OvisConfig, robots: int | None = None) -> OvisConfig:
    """``config`` with the marked robots a drive needs: ``[[pose.robots]]`` as listed,
    else ``robots`` (default ``[navigation] robots``) of the simulator's marked kind
    (:func:`~ovis.common.sim.scenes.marked_scene`; ids 1…N, markers 0…N−1), the arena
    kept. A planner needs a robot's heading, which its marker gives."""
    robots = config.navigation.robots if robots is None else int(robots)
    if len(config.pose.robots) >= robots:
        return config
    sim = config.simulator
    marked = marked_scene(config, robots)
    arena = {"arena_x_cm": sim.arena_x_cm, "arena_y_cm": sim.arena_y_cm}
    return msgspec.structs.replace(
        marked, simulator=msgspec.structs.replace(marked.simulator, **arena)
    )


def straight_time_s(distance_cm: float, speed_cm_s: float, accel_cm_s2: float) -> float:
    """Time a robot driving straight from rest takes to cover ``distance_cm`` at most
    ``speed_cm_s``, accelerating at ``accel_cm_s2``."""
    ramp = speed_cm_s * speed_cm_s / (2.0 * accel_cm_s2)
    if distance_cm <= ramp:
        return math.sqrt(2.0 * distance_cm / accel_cm_s2)
    return (distance_cm - ramp) / speed_cm_s + speed_cm_s / accel_cm_s2


def _tasks(rng: np.random.Generator, config: OvisConfig, robots: int) -> list[RobotTask]:
    """The robots' starts and goals (module docstring)."""
    (x0, x1), (y0, y1) = config.simulator.arena_x_cm, config.simulator.arena_y_cm
    m = MARGIN_CM
    specs = list(config.pose.robots)[:robots]
    ids = [s.id for s in specs] or list(range(robots))
    radii = [s.radius_cm for s in specs] or [
        math.hypot(*config.simulator.robot_size_cm) / 2.0
    ] * robots
    ya, yb = rng.uniform(y0 + m, y1 - m, size=2)
    start, goal = (x0 + m, float(ya)), (x1 - m, float(yb))
    if rng.random() < 0.5:
        start, goal = goal, start
    ends = [(start, goal)]
    if robots > 1:
        xa, xb = rng.uniform(x0 + 0.35 * (x1 - x0), x0 + 0.65 * (x1 - x0), size=2)
        start, goal = (float(xa), y0 + m), (float(xb), y1 - m)
        if rng.random() < 0.5:
            start, goal = goal, start
        ends.append((start, goal))
    tasks = []
    for ident, radius, (s, g) in zip(ids, radii, ends, strict=True):
        yaw = math.degrees(math.atan2(g[1] - s[1], g[0] - s[0]))
        tasks.append(
            RobotTask(id=ident, start_cm=s, yaw_deg=yaw, goal_cm=g, radius_cm=float(radius))
        )
    return tasks


def _crossing_path(
    rng: np.random.Generator, task: RobotTask, share: float, config: OvisConfig
) -> Path:
    """An ellipse crossing ``task``'s straight way ``share`` of the way along it, at
    about the time a straight driver passes there (module docstring)."""
    nav = config.navigation
    sx, sy = task.start_cm
    gx, gy = task.goal_cm
    px, py = sx + share * (gx - sx), sy + share * (gy - sy)
    when = straight_time_s(share * task.distance_cm, nav.max_speed_cm_s, nav.max_accel_cm_s2)
    when += float(rng.uniform(-TIMING_S, TIMING_S))
    way = math.atan2(gy - sy, gx - sx)
    turn = math.radians(float(rng.uniform(*CROSSING_ANGLE_DEG)))
    motion = way + (turn if rng.random() < 0.5 else -turn)  # the obstacle's direction there
    speed = float(rng.uniform(*SPEED_SHARE)) * nav.obstacle_speed * nav.max_speed_cm_s
    omega = 2.0 * math.pi / PERIOD_S
    a = speed / omega
    b = float(rng.uniform(*THINNESS)) * a
    sense = float(rng.choice([-1.0, 1.0]))
    # At the parameter θ = π/2 a Path is at centre + b·(−sin α, cos α), moving along
    # −sense·(cos α, sin α) at a·ω: pick α so that this is the obstacle's direction.
    alpha = motion + math.pi if sense > 0 else motion
    cx, cy = px + b * math.sin(alpha), py - b * math.cos(alpha)
    phase = math.pi / 2.0 - sense * omega * when
    return Path(
        cx_cm=cx,
        cy_cm=cy,
        a_cm=a,
        b_cm=b,
        alpha_deg=math.degrees(alpha),
        phase_deg=math.degrees(phase),
        sense=sense,
    )


def _clear(
    xy: tuple[NDArray[np.float64], NDArray[np.float64]],
    bound: float,
    placed: list[tuple[NDArray[np.float64], NDArray[np.float64], float]],
    tasks: list[RobotTask],
    times: NDArray[np.float64],
    gap: float,
) -> bool:
    """Whether an obstacle at ``xy`` (over ``times``) keeps its gap to those placed,
    and its clearance to the robots' starts (early on) and goals."""
    x, y = xy
    for ox, oy, ob in placed:
        if np.min(np.hypot(x - ox, y - oy)) < bound + ob + gap:
            return False
    early = times <= START_CLEAR_S
    for task in tasks:
        need = bound + task.radius_cm + CLEAR_CM
        if np.min(np.hypot(x[early] - task.start_cm[0], y[early] - task.start_cm[1])) < need:
            return False
        if np.min(np.hypot(x - task.goal_cm[0], y - task.goal_cm[1])) < need:
            return False
    return True


def _robot_solid(
    rng: np.random.Generator, config: OvisConfig, task: RobotTask, marker: int | None
) -> Solid:
    """A robot standing at its start, facing its goal."""
    solid = draw_solid(rng, config, task.id, "robot", marker)
    path = Path(cx_cm=task.start_cm[0], cy_cm=task.start_cm[1])
    return msgspec.structs.replace(solid, path=path, yaw_deg=task.yaw_deg)


def _marks(
    rng: np.random.Generator, config: OvisConfig, seed: int, cameras: Sequence[CameraModel]
) -> list[FloorMark]:
    """The floor marks: live (``[navigation] drive``) those of the physical world's
    scene of ``seed`` (what the live calibration and the empty floor are made from),
    else drawn here."""
    if config.navigation.drive:
        return random_scene(config, seed, cameras).marks
    return spread_marks(rng, config, cameras)


def make_scenario(
    config: OvisConfig,
    seed: int,
    cameras: Sequence[CameraModel],
    *,
    case: int | None = None,
    robots: int | None = None,
) -> Scenario:
    """The scenario of ``seed`` (the same seed, the same scenario) for ``case`` and
    ``robots`` (default ``[navigation]``'s), seen whole by every camera of ``cameras``.
    Marked robots are ``config.pose.robots``' first ones (their ids and markers).

    Raises ValueError when the obstacles find no room (say what to change).
    """
    nav = config.navigation
    case = nav.case if case is None else int(case)
    robots = nav.robots if robots is None else int(robots)
    if case not in CASE_OBSTACLES:
        raise ValueError(f"case must be 1 (two obstacles) or 2 (four), got {case}")
    if int(seed) < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed}")
    rng = np.random.default_rng([int(seed), 37, case, robots])
    markers = [r.marker_id for r in config.pose.robots][:robots]
    markers += [None] * (robots - len(markers))
    n = CASE_OBSTACLES[case]
    for _attempt in range(RESTARTS):
        tasks = _tasks(rng, config, robots)
        longest = max(t.distance_cm for t in tasks)
        timeout = nav.timeout_factor * longest / nav.max_speed_cm_s
        # paths repeat every period: checked over one (or the run, if longer), what
        # holds then holds for ever (a live world runs on past the timeout)
        times = np.arange(0.0, max(timeout, PERIOD_S), CHECK_STEP_S)
        first = max(t.id for t in tasks) + 1
        lo, hi = CROSSING_SPAN
        shares = lo + (hi - lo) * (np.arange(n) + rng.uniform(0.15, 0.85, size=n)) / n
        rng.shuffle(shares)
        placed: list[tuple[NDArray[np.float64], NDArray[np.float64], float]] = []
        obstacles: list[Solid] = []
        for k in range(n):
            shape = draw_solid(rng, config, first + k, "obstacle", None)
            task = tasks[k % robots]
            for _ in range(TRIES):
                path = _crossing_path(rng, task, float(shares[k]), config)
                xy = path_fits(shape, path, config, cameras, times, PERIOD_S)
                if xy is None or not _clear(
                    xy, shape.bound_cm, placed, tasks, times, config.physical.gap_cm
                ):
                    continue
                placed.append((*xy, shape.bound_cm))
                obstacles.append(msgspec.structs.replace(shape, path=path))
                break
            else:
                break  # no room for this one: draw the scenario again
        else:
            robots_solids = [
                _robot_solid(rng, config, t, m) for t, m in zip(tasks, markers, strict=True)
            ]
            phys = config.physical
            scene = Scene(
                seed=int(seed),
                period_s=PERIOD_S,
                arena_x_cm=config.simulator.arena_x_cm,
                arena_y_cm=config.simulator.arena_y_cm,
                solids=[*robots_solids, *obstacles],
                marks=_marks(rng, config, seed, cameras),
                lamps=ceiling_lamps(config),
                floor_albedo=phys.floor_albedo,
                ambient=phys.ambient,
                shadows=phys.shadows,
            )
            return Scenario(seed=int(seed), case=case, scene=scene, tasks=tasks, timeout_s=timeout)
    raise ValueError(
        f"cannot place the {n} crossing obstacles of case {case} in the arena x "
        f"{config.simulator.arena_x_cm} cm, y {config.simulator.arena_y_cm} cm and every "
        "camera's view; use smaller obstacles ([physical] radius_cm), a slower "
        "[navigation] obstacle_speed or a larger arena"
    )


def live_drive_config(config: OvisConfig) -> OvisConfig:
    """``config`` for ``ovis up --drive``: the marked robots a drive needs, each with
    its goal of the scenario of ``[service] seed`` (the one the physical world's
    capture draws from the same configuration), ``[navigation] drive`` on, and frames
    at the planner's rate (``[navigation] rate_hz``: a command per frame must come
    within the robots' ``command_timeout_s``), rendered without shadows (a frame then
    costs several times less; ovis segments against the empty floor either way)."""
    nav = msgspec.structs.replace(config.navigation, drive=True)
    service = msgspec.structs.replace(config.service, fps=nav.rate_hz)
    physical = msgspec.structs.replace(config.physical, shadows=False)
    cfg = msgspec.structs.replace(config, navigation=nav, service=service, physical=physical)
    cfg = driving_config(cfg)
    scenario = make_scenario(cfg, cfg.service.seed, [cfg.camera])
    goals = {t.id: t.goal_cm for t in scenario.tasks}
    robots = [
        msgspec.structs.replace(r, goal_cm=goals[r.id]) if r.id in goals else r
        for r in cfg.pose.robots
    ]
    return msgspec.structs.replace(cfg, pose=msgspec.structs.replace(cfg.pose, robots=robots))
