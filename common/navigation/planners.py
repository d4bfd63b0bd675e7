"""The planners behind one interface: an :class:`Observation` in, a :class:`Command` out.

* ``fuzzy``: the genetic-fuzzy planner (:mod:`.fuzzy` on the inputs of :mod:`.critical`):
  the robot heads for the goal direction turned by the controller's deviation, at its
  speed (the side it passes on chosen by the arena's room if the controller says so,
  :mod:`.sides`), checked against every body by its guard if it has one (:mod:`.guard`);
* ``dwa``: the dynamic window baseline (:mod:`.dwa`);
* ``straight``: straight to the goal at top speed, blind to everything.

Every planner keeps, per robot, the other bodies' velocities smoothed over the frames
(an exponential mean with weight ``VELOCITY_WEIGHT`` for the newest measurement:
a velocity from two frames' positions carries their noise twice); the fuzzy and
straight planners keep each robot's way round a half turn (:class:`~.steering.Turns`).
The batched cores (:func:`fuzzy_batch`, :func:`straight_batch`) are what the tuning's
fast simulation runs for a whole population at once.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ovis.common.config import OvisConfig
from ovis.common.navigation.base import DriveLimits
from ovis.common.navigation.critical import Critical, critical_obstacle
from ovis.common.navigation.dwa import dwa
from ovis.common.navigation.fuzzy import FuzzyArrays, FuzzyParams, infer_arrays
from ovis.common.navigation.guard import guard
from ovis.common.navigation.observe import Body, Observation, Situation, situation
from ovis.common.navigation.sides import Sides, roomier_right
from ovis.common.navigation.steering import Arena, Steer, Turns, goal_direction, steer, wrap_rad

__all__ = [
    "BRAKE",
    "PLANNERS",
    "VELOCITY_WEIGHT",
    "Command",
    "Planner",
    "arena_of",
    "fuzzy_batch",
    "make_planner",
    "straight_batch",
]

PLANNERS = ("fuzzy", "dwa", "straight")
#: Why a command says stop when its guard brakes (the robot's reason while it does).
BRAKE = "emergency brake: contact ahead"
#: Weight of the newest velocity measurement in a body's smoothed velocity.
VELOCITY_WEIGHT = 0.5
#: A body unseen this long (s) starts its smoothing afresh.
FORGET_S = 1.0


class Command(NamedTuple):
    """One robot's command and why: v (cm/s), ω (deg/s), whether it is at its goal,
    the critical body (id, distance cm, angle deg; None: none) and the deviation (deg)
    of the fuzzy planner; whether it says brake (its guard's emergency stop: the robot
    stops at its braking limit, :data:`BRAKE` its reason)."""

    v_cm_s: float
    omega_deg_s: float
    arrived: bool
    critical_id: int | None = None
    distance_cm: float | None = None
    angle_deg: float | None = None
    deviation_deg: float | None = None
    brake: bool = False


def fuzzy_batch(
    s: Situation,
    f: FuzzyArrays,
    limits: DriveLimits,
    tolerance_cm: float,
    arena: Arena | None = None,
    sides: Sides | None = None,
    keys: np.ndarray | None = None,
    turns: Turns | None = None,
) -> tuple[Steer, Critical, np.ndarray]:
    """The fuzzy planner for B robots (with B controllers): their commands, critical
    bodies and deviations (deg). ``sides`` keeps each robot's chosen side between
    calls (:mod:`.sides`; None: chosen afresh each time), for the critical body's key
    in ``keys`` (B, M) (default its index); ``turns`` each robot's way round
    (:class:`~.steering.Turns`; None: the shorter way each time)."""
    crit = critical_obstacle(s, f.lookahead, f.closest_approach)
    none = crit.index < 0
    angle = crit.angle_deg
    mirror = np.zeros(s.x.size, dtype=bool)
    if arena is not None and np.any(f.side_by_room):
        k = np.maximum(crit.index, 0)
        known = keys is not None and np.shape(keys)[1] > 0
        key = np.asarray(keys)[np.arange(k.size), k] if known else crit.index
        key = np.where(none, -1, key)
        roomier = roomier_right(s, arena)
        mirror = f.side_by_room & (roomier if sides is None else sides.choose(key, roomier))
        angle = np.where(mirror, -angle, angle)
    deviation, speed = infer_arrays(f, crit.distance_cm, angle, limits.max_speed_cm_s)
    deviation = np.where(none, 0.0, np.where(mirror, -deviation, deviation))
    speed = np.where(none, limits.max_speed_cm_s, speed)
    to_goal, _ = goal_direction(s)
    heading = to_goal + np.radians(deviation)
    brake = None
    if np.any(f.guard > 0.0):
        way, last = (None, None) if turns is None else turns.current(s.x.size)
        wish = guard(s, heading, speed, f.guard, limits, arena, f.edge_cm, way, last)
        heading, speed, brake = wish.heading, wish.speed, wish.brake
        deviation = np.degrees(wrap_rad(heading - to_goal))
    out = steer(s, heading, speed, limits, tolerance_cm, arena, f.edge_cm, f.edge_slow, turns)
    if brake is not None:
        out = out._replace(brake=brake & ~out.arrived)
    return out, crit, deviation


def straight_batch(
    s: Situation, limits: DriveLimits, tolerance_cm: float, turns: Turns | None = None
) -> Steer:
    """Straight to the goal at top speed (blind: it leaves the arena if its goal does),
    each robot turning its way round kept in ``turns`` (None: the shorter way)."""
    to_goal, _ = goal_direction(s)
    top = np.full(s.x.size, limits.max_speed_cm_s)
    return steer(s, to_goal, top, limits, tolerance_cm, turns=turns)


class Planner:
    """One robot's planner (module docstring)."""

    def __init__(
        self,
        name: str,
        limits: DriveLimits,
        tolerance_cm: float,
        period_s: float,
        fuzzy: FuzzyParams | None = None,
        arena: Arena | None = None,
    ) -> None:
        if name not in PLANNERS:
            raise ValueError(f"unknown planner {name!r}; choose one of {', '.join(PLANNERS)}")
        if name == "fuzzy" and fuzzy is None:
            raise ValueError("the fuzzy planner needs its controller")
        self.name = name
        self.limits = limits
        self.tolerance_cm = tolerance_cm
        self.period_s = period_s
        self.arena = arena
        self.fuzzy = FuzzyArrays.of(fuzzy) if fuzzy is not None else None
        self._sides = Sides()
        self._turns = Turns()
        self._velocity: dict[tuple[str, int], tuple[float, float, float]] = {}

    def _smoothed(self, obs: Observation) -> Observation:
        """``obs`` with the others' velocities smoothed (module docstring)."""
        kept: dict[tuple[str, int], tuple[float, float, float]] = {}
        others = []
        a = VELOCITY_WEIGHT
        for body in obs.others:
            key = (body.kind, body.id)
            old = self._velocity.get(key)
            vx, vy = body.vx_cm_s, body.vy_cm_s
            if old is not None and obs.t_s - old[2] <= FORGET_S:
                vx, vy = old[0] + a * (vx - old[0]), old[1] + a * (vy - old[1])
            kept[key] = (vx, vy, obs.t_s)
            others.append(body._replace(vx_cm_s=vx, vy_cm_s=vy))
        self._velocity = {k: v for k, v in self._velocity.items() if obs.t_s - v[2] <= FORGET_S}
        self._velocity |= kept
        return obs._replace(others=others)

    def plan(self, obs: Observation) -> Command:
        """The command for this robot's view of one frame."""
        obs = self._smoothed(obs)
        s = situation([obs])
        if self.name == "fuzzy":
            assert self.fuzzy is not None
            keys = np.array([[_key(b) for b in obs.others]], dtype=np.int64).reshape(1, -1)
            out, crit, deviation = fuzzy_batch(
                s,
                self.fuzzy,
                self.limits,
                self.tolerance_cm,
                self.arena,
                self._sides,
                keys,
                self._turns,
            )
            return _command(out, obs.others, crit, float(deviation[0]))
        if self.name == "dwa":
            out = dwa(s, self.limits, self.tolerance_cm, self.period_s, self.arena)
        else:
            out = straight_batch(s, self.limits, self.tolerance_cm, self._turns)
        return _command(out, obs.others)


def _key(body: Body) -> int:
    """A body's key for the side memory: its id, robots apart from obstacles."""
    return 2 * body.id + (body.kind == "robot")


def _command(
    out: Steer,
    others: list[Body],
    crit: Critical | None = None,
    deviation: float | None = None,
) -> Command:
    v, w, arrived = float(out.v_cm_s[0]), float(out.omega_deg_s[0]), bool(out.arrived[0])
    brake = out.brake is not None and bool(out.brake[0])
    if crit is None or crit.index[0] < 0:
        return Command(v, w, arrived, deviation_deg=deviation, brake=brake)
    k = int(crit.index[0])
    distance, angle = float(crit.distance_cm[0]), float(crit.angle_deg[0])
    if not (math.isfinite(distance) and math.isfinite(angle)):
        return Command(v, w, arrived, deviation_deg=deviation, brake=brake)
    return Command(v, w, arrived, others[k].id, distance, angle, deviation, brake)


def arena_of(config: OvisConfig) -> Arena:
    """The configured arena (``[simulator] arena_x_cm``, ``arena_y_cm``)."""
    (x0, x1), (y0, y1) = config.simulator.arena_x_cm, config.simulator.arena_y_cm
    return Arena(x0, x1, y0, y1)


def make_planner(name: str, config: OvisConfig, fuzzy: FuzzyParams | None = None) -> Planner:
    """A planner of ``[navigation]``'s limits, tolerance and rate on the configured arena."""
    nav = config.navigation
    return Planner(
        name, DriveLimits.of(nav), nav.goal_tolerance_cm, 1.0 / nav.rate_hz, fuzzy, arena_of(config)
    )
