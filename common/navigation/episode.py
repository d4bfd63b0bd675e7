"""One scenario driven in the physical world, in lock-step simulated time.

Every control period (``1 / [navigation] rate_hz``) at ``t_k``:

1. each robot's planner is given the world at ``t_k`` — from **ovis** (the camera's
   frame rendered by MuJoCo, through ovis's own detection:
   :class:`~ovis.common.world.detection.Detector` with the camera's calibration and its
   empty floor) or from the **oracle** (the physics truth at ``t_k``);
2. its command, stamped with ``t_k`` (the frame it was made from), reaches the robot
   ``L_k`` later: the pipeline's latency, drawn per frame from a log-normal of the
   measured median and 99th percentile (``[navigation] latency_ms``), from the seed;
3. the physics runs to ``t_{k+1}`` (:class:`~ovis.common.navigation.driving.Driving`:
   each robot's firmware setting its wheels from the commands it has received by then,
   under its safety rules; contacts, clearance and arrival counted as it goes).

A robot is done at its goal (the truth within ``goal_tolerance_cm``), or at its first
contact (it is then stopped); the run ends when every robot is done, or at the
scenario's timeout. A planner that does not see its robot in a frame (its marker
unseen) sends nothing: the robot's watchdog stops it. Everything depends only on the
scenario, the planner and the seed: the same inputs, the same run.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path
from typing import Literal

import cv2
import msgspec
import numpy as np

from ovis.common.atomic import write_atomic
from ovis.common.config import OvisConfig
from ovis.common.navigation.base import DriveCommand
from ovis.common.navigation.driving import Driving
from ovis.common.navigation.observe import Observation, observe_detection, observe_truth
from ovis.common.navigation.planners import BRAKE, Planner
from ovis.common.navigation.scenarios import Scenario
from ovis.common.physical.world import PhysicalWorld

__all__ = ["EpisodeResult", "RobotRun", "latencies_s", "run_episode"]
#: z of the 99th percentile of a standard normal.
_Z99 = 2.3263478740408408

Feed = Literal["ovis", "oracle"]


class RobotRun(msgspec.Struct, kw_only=True):
    """How one robot's drive went: at its goal or not, when (s; the run's end if not),
    its contacts (each new touch of another solid), its closest approach to any other
    solid (cm, MuJoCo's geometry; ≤ 0 touching), the straight-line time at top speed
    (s), the frames its planner did not see it in, and its path (t s, x cm, y cm)."""

    id: int
    goal_reached: bool
    time_s: float
    collisions: int
    min_clearance_cm: float
    straight_s: float
    unseen_frames: int
    path: list[tuple[float, float, float]]

    @property
    def time_ratio(self) -> float:
        return self.time_s / self.straight_s


class EpisodeResult(msgspec.Struct, kw_only=True):
    """One scenario's run: its seed, case, planner, feed, robots, frames processed and
    the latencies applied (ms)."""

    seed: int
    case: int
    planner: str
    feed: str
    robots: list[RobotRun]
    frames: int
    latency_ms: list[float]
    obstacle_paths: dict[int, list[tuple[float, float]]] = {}

    @property
    def success(self) -> bool:
        return all(r.goal_reached and r.collisions == 0 for r in self.robots)

    @property
    def collided(self) -> bool:
        return any(r.collisions for r in self.robots)

    @property
    def timed_out(self) -> bool:
        return not self.collided and not all(r.goal_reached for r in self.robots)


def latencies_s(config: OvisConfig, seed: int, n: int) -> np.ndarray:
    """``n`` latencies (s) drawn for run ``seed`` (module docstring, step 2)."""
    median, p99 = config.navigation.latency_ms
    rng = np.random.default_rng([int(seed), 38])
    if median <= 0.0:
        return np.zeros(n)
    sigma = math.log(max(p99, median) / median) / _Z99
    return median / 1000.0 * np.exp(sigma * rng.standard_normal(n))


class _Seen:
    """How each robot's planner sees frame ``k``: rendered and detected, or the truth."""

    def __init__(self, feed: Feed, world: PhysicalWorld, config: OvisConfig) -> None:
        self.feed = feed
        self.world = world
        self.radii = {r.id: r.radius_cm for r in config.pose.robots}
        self.predict_s = config.navigation.predict_s
        self.detector = None
        if feed == "ovis":
            from ovis.common.world.detection import Detector

            self.detector = Detector(config.camera, config.image, config.pose)
        self.detection = None
        self.truth = None

    def look(self, k: int, t_s: float) -> None:
        if self.detector is not None:
            self.detection = self.detector.detect(self.world.render(k), stamp_s=t_s)
        else:
            self.truth = self.world.truth(k)

    def of(self, robot_id: int, goal: tuple[float, float], radius: float, t_s: float):
        if self.detection is not None:
            d = self.detection
            predict = self.predict_s
            return observe_detection(d.robots, d.objects, robot_id, goal, t_s, predict)
        assert self.truth is not None
        return observe_truth(self.truth, robot_id, goal, radius, self.radii, t_s)


def run_episode(
    scenario: Scenario,
    config: OvisConfig,
    planners: dict[int, Planner],
    feed: Feed,
    *,
    background: Path | None = None,
    world: PhysicalWorld | None = None,
) -> EpisodeResult:
    """Drive ``scenario`` (module docstring) with one planner per robot id. ``config``:
    its camera renders the frames (``feed`` "ovis"; ``background``: the empty floor
    the detection segments against, rendered into a temporary folder if not given)."""
    if world is None:
        world = PhysicalWorld(scenario.scene, config, [config.camera], driven=True)
    try:
        with tempfile.TemporaryDirectory(prefix="ovis-navigate-") as tmp:
            if feed == "ovis":
                floor = background or Path(tmp) / "background.png"
                config = _with_background(config, world, floor)
            return _drive(scenario, config, planners, feed, world)
    finally:
        world.close()


def _with_background(config: OvisConfig, world: PhysicalWorld, path: Path) -> OvisConfig:
    """``config`` segmenting against the empty floor at ``path`` (rendered there if no
    file is)."""
    if not path.is_file():
        ok, png = cv2.imencode(".png", world.clean(0, solids=False))
        if not ok:
            raise ValueError("could not encode the empty floor as PNG")
        write_atomic(path, png.tobytes())
    image = msgspec.structs.replace(config.image, background=str(path))
    return msgspec.structs.replace(config, image=image)


def _drive(
    scenario: Scenario,
    config: OvisConfig,
    planners: dict[int, Planner],
    feed: Feed,
    world: PhysicalWorld,
) -> EpisodeResult:
    nav = config.navigation
    period = 1.0 / nav.rate_hz
    frames = math.ceil(scenario.timeout_s / period) + 1
    delays = latencies_s(config, scenario.seed, frames)
    world.set_time(0.0)
    drive = Driving(world, scenario.tasks, nav)
    seen = _Seen(feed, world, config)
    done: dict[int, float] = {}
    unseen = dict.fromkeys(drive.tasks, 0)
    paths: dict[int, list[tuple[float, float, float]]] = {i: [] for i in drive.tasks}
    obstacles: dict[int, list[tuple[float, float]]] = {o.id: [] for o in scenario.obstacles}
    applied: list[float] = []
    k = 0
    while k < frames and len(done) < len(drive.tasks):
        t = k * period
        for o in world.truth(k).objects:
            if o.id in paths:
                paths[o.id].append((round(t, 3), round(o.x_cm, 2), round(o.y_cm, 2)))
            elif o.id in obstacles:
                obstacles[o.id].append((round(o.x_cm, 2), round(o.y_cm, 2)))
        seen.look(k, t)
        for ident, task in drive.tasks.items():
            if ident in done:  # at its goal, or after a contact: it stays where it is
                drive.receive(ident, DriveCommand(0.0, 0.0, t, t, "done"))
                continue
            obs: Observation | None = seen.of(ident, task.goal_cm, task.radius_cm, t)
            if obs is None:
                unseen[ident] += 1
                continue
            cmd = planners[ident].plan(obs)
            late = float(delays[k])
            applied.append(late * 1000.0)
            stop = BRAKE if cmd.brake else ""
            drive.receive(ident, DriveCommand(cmd.v_cm_s, cmd.omega_deg_s, t, t + late, stop))
        drive.advance_to((k + 1) * period)
        for ident in drive.tasks:
            if ident not in done and (drive.contacts[ident] or drive.reached_s[ident] is not None):
                done[ident] = drive.world.t_s if drive.contacts[ident] else drive.reached_s[ident]
        k += 1
    end = min(k * period, scenario.timeout_s)
    robots = [
        RobotRun(
            id=i,
            goal_reached=drive.reached_s[i] is not None and not drive.contacts[i],
            time_s=round(done.get(i, end), 3),
            collisions=drive.contacts[i],
            min_clearance_cm=round(drive.clearance[i], 3),
            straight_s=task.distance_cm / nav.max_speed_cm_s,
            unseen_frames=unseen[i],
            path=paths[i],
        )
        for i, task in drive.tasks.items()
    ]
    return EpisodeResult(
        seed=scenario.seed,
        case=scenario.case,
        planner=next(iter(planners.values())).name,
        feed=feed,
        robots=robots,
        frames=k,
        latency_ms=applied,
        obstacle_paths=obstacles,
    )
