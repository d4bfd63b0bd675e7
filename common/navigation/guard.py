"""A last look at a planner's wish before it is driven: the time to contact along it,
against every other body, and an evasive wish (or an emergency stop) when that time is
short.

The fuzzy controller of Pratihar, Deb & Ghosh sees one body, the most critical. The
failures it left (docs/navigation.md, "Why runs failed") are of what that cannot see: a
robot sent by its rules towards the arena's edge runs along it at speed into a body
crossing towards the edge (the rules' turn away is what the edge takes away, their
speed is kept); a robot turning away from one body turns into a second one, or flips
between two on either side; two robots each swerve for the other. The guard checks
the wished velocity (a heading and a speed) against **every** other body: each moves
on at its velocity; the robot moves at the wish after its reaction (:data:`REACTION_S`:
the command's way to the wheels), its turn to the wish's heading (the heading
control's, :func:`turn_time`; a differential drive turns more than 90° on the spot) and
the ramp of its rims to the new velocity (at the acceleration limit; a stop at the
braking limit), so that it starts from where it will really be when it moves at the
wish (:func:`start_shift`). The **time to contact** is when the two disks first come
within :data:`MARGIN_CM` of each other (0: they already are and close in; infinite:
never).

When it is shorter than the controller's ``guard_s``, the robot takes instead, of
headings turned by :data:`TURNS_DEG` from the wish (each kept off the arena's edge as
every heading is, :func:`~.steering.inside`) at the speeds of :data:`SPEEDS` (shares of
the top speed) and at the wished speed, the one whose time to contact is longest (up
to ``guard_s``), and among those as long, the one nearest the goal's direction and the
wished speed (:data:`NEAR_WISH_S`: what a half turn from the goal and the whole top
speed cost, in seconds of time to contact; nearest the goal, not the wish: a wish that
led into danger may be the rules flipping between two bodies). It **keeps to its last
choice**: a candidate also costs :data:`KEEP_S` per half turn from the heading the
robot was steered to the frame before (:class:`~.steering.Turns`), so that the way out
changes only for one clearly better (a pick flipping between far-apart headings from
frame to frame left robots turning back and forth near a body: MuJoCo seeds 317 and
329, docs/navigation.md); but nothing for a candidate clear for the whole guard's time
and between that heading and the goal's direction (:func:`off_last`): the keep holds a
way out against one as marginal, not a detour against a clear way back (it costs more
per half turn than the goal's direction gains, so it held a detour against every way
back as clear as it for as long as the wish stayed in danger: two robots kept off
their goals, docs/navigation.md). When that is a stop, the command says **brake**: the
robot stops at its braking limit (``[navigation] brake_cm_s2``), as it does for the
planner's other stops. Each turn is timed the way round the robot keeps
(:class:`~.steering.Turns`).

**Another robot** shares the avoidance, as in reciprocal velocity obstacles (van den
Berg, Lin & Manocha 2008): a velocity is judged against it as if the robot's own change
of velocity were twice as large (each robot takes half the way out), so that two robots
meeting do not both swerve by the whole way; the candidates are tried in the same
order by both, so that in a meeting face to face both turn the same way round.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ovis.common.navigation.base import DriveLimits
from ovis.common.navigation.observe import Situation
from ovis.common.navigation.steering import (
    HEADING_GAIN,
    Arena,
    goal_direction,
    held,
    inside,
    wrap_rad,
)

__all__ = [
    "KEEP_S",
    "MARGIN_CM",
    "REACTION_S",
    "SETTLED_DEG",
    "SPEEDS",
    "TURNS_DEG",
    "Wish",
    "guard",
    "off_last",
    "start_shift",
    "time_to_contact",
    "turn_time",
]

FloatArray = NDArray[np.float64]

#: How near (cm) two bodies' disks count as a contact for the guard.
MARGIN_CM = 2.0
#: A command's way to the wheels (s): the pipeline's latency and half a control period.
REACTION_S = 0.1
#: A turn is done when its heading error is within this (deg).
SETTLED_DEG = 30.0
#: The evasive headings, turned from the wish (deg).
TURNS_DEG = (0.0, 30.0, -30.0, 60.0, -60.0, 90.0, -90.0, 135.0, -135.0, 180.0)
#: The evasive speeds, as shares of the top speed (the wished speed is tried too).
SPEEDS = (1.0, 0.5, 0.0)
#: The cost (s of time to contact) of a candidate a half turn from the goal's direction
#: and the whole top speed from the wished speed.
NEAR_WISH_S = 0.2
#: The cost (s of time to contact) of a candidate a half turn from the heading the robot
#: was steered to the frame before.
KEEP_S = 0.15


class Wish(NamedTuple):
    """B robots' wished headings (rad) and speeds (cm/s), which the guard changed, and
    which it stops (at the braking limit: module docstring)."""

    heading: FloatArray
    speed: FloatArray
    guarded: NDArray[np.bool_]
    brake: NDArray[np.bool_]


def time_to_contact(
    px: FloatArray, py: FloatArray, wx: FloatArray, wy: FloatArray, reach: FloatArray
) -> FloatArray:
    """First time (s, ≥ 0) at which ``p + w·t`` comes within ``reach`` of the origin:
    0 if it already is and is not moving away, infinite if never (or moving away from
    within: a robot already that near is not held there) (the relative position ``p``,
    cm; the relative velocity ``w``, cm/s; all broadcast)."""
    pw = px * wx + py * wy
    ww = wx * wx + wy * wy
    pp = px * px + py * py - reach * reach
    disc = pw * pw - ww * pp
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (-pw - np.sqrt(np.maximum(disc, 0.0))) / ww
    meets = (disc >= 0.0) & (ww > 0.0) & (pw < 0.0) & np.isfinite(t)
    within = np.where(pw < 0.0, 0.0, np.inf)
    return np.where(pp <= 0.0, within, np.where(meets, np.maximum(t, 0.0), np.inf))


def turn_time(turn: FloatArray, limits: DriveLimits) -> FloatArray:
    """Time (s) the heading control (:func:`~.steering.steer`: ``HEADING_GAIN`` per
    second of error, within the top yaw rate) takes to bring an error of ``turn``
    (rad) within :data:`SETTLED_DEG`."""
    turn = np.abs(np.asarray(turn, float))
    done = np.radians(SETTLED_DEG)
    top = np.radians(limits.max_yaw_rate_deg_s)
    knee = max(top / HEADING_GAIN, done)  # beyond it the turn runs at the top rate
    flat = np.maximum(turn - knee, 0.0) / top
    with np.errstate(divide="ignore"):
        tail = np.log(np.maximum(np.minimum(turn, knee), done) / done) / HEADING_GAIN
    return flat + tail


def start_shift(
    v0x: FloatArray,
    v0y: FloatArray,
    vx: FloatArray,
    vy: FloatArray,
    turn: FloatArray,
    limits: DriveLimits,
) -> tuple[FloatArray, FloatArray]:
    """Where (cm, from its place now) a robot moving at ``v0`` would have to start to
    be, moving at ``v`` all along, where it will really be (module docstring): after
    its reaction (:data:`REACTION_S`), a turn of ``turn`` (rad) within 90° ramps the
    velocity to ``v`` at the acceleration limit, ``(v0 − v)(τ + T/2)``, ``T`` the
    ramp's time, and lags by the turn's time (:func:`turn_time`); a wider one stops
    the robot first (a differential drive turns on the spot), ``v0 (τ + |v0| / 2a) −
    v (τ + max(turn, |v0| / a) + |v| / 2a)``."""
    a = limits.accel_cm_s2
    turning = turn_time(turn, limits)
    dx, dy = v0x - vx, v0y - vy
    lag = REACTION_S + 0.5 * np.hypot(dx, dy) / a
    near_x, near_y = dx * lag - vx * turning, dy * lag - vy * turning
    s0, s1 = np.hypot(v0x, v0y), np.hypot(vx, vy)
    stop = REACTION_S + 0.5 * s0 / a
    go = REACTION_S + np.maximum(turning, s0 / a) + 0.5 * s1 / a
    wide = np.abs(turn) > 0.5 * np.pi
    halt = REACTION_S + 0.5 * s0 / limits.brake_cm_s2  # a stop brakes (module docstring)
    return (
        np.where(s1 == 0.0, v0x * halt, np.where(wide, v0x * stop - vx * go, near_x)),
        np.where(s1 == 0.0, v0y * halt, np.where(wide, v0y * stop - vy * go, near_y)),
    )


def off_last(
    heading: FloatArray, last: FloatArray, to_goal: FloatArray, clear: NDArray[np.bool_]
) -> FloatArray:
    """(B, C) share of a half turn each of C candidate headings (rad) of B robots turns
    away from the heading ``last`` (B,) each was steered to the frame before (NaN: none,
    0); 0 for a candidate ``clear`` (no contact within the guard's time) between that
    heading and the goal's direction ``to_goal`` (B,) (module docstring: the keep holds
    a way out against one as marginal, not a detour against a clear way back)."""
    ahead = wrap_rad(last - to_goal)[:, None]
    off = wrap_rad(heading - to_goal[:, None])
    back = clear & (off * ahead >= 0.0) & (np.abs(off) <= np.abs(ahead))
    turned = np.abs(wrap_rad(heading - last[:, None])) / np.pi
    return np.where(back | ~np.isfinite(turned), 0.0, turned)


def _contact_times(
    s: Situation,
    heading: FloatArray,
    speed: FloatArray,
    limits: DriveLimits,
    way: FloatArray | None = None,
) -> FloatArray:
    """(B, C) time to contact of B robots moving at C velocities each (heading,
    speed: (B, C)) against their other bodies (module docstring), each turning its
    way round ``way`` (B,) (:func:`~.steering.held`; None: the shorter way)."""
    v0x = (s.speed * np.cos(s.heading))[:, None]
    v0y = (s.speed * np.sin(s.heading))[:, None]
    vx, vy = speed * np.cos(heading), speed * np.sin(heading)
    turn = wrap_rad(heading - s.heading[:, None])
    if way is not None:
        turn = held(turn, way[:, None])
    sx, sy = start_shift(v0x, v0y, vx, vy, turn, limits)
    # (B, C, M)
    px = s.ox[:, None, :] - (s.x[:, None] + sx)[:, :, None]
    py = s.oy[:, None, :] - (s.y[:, None] + sy)[:, :, None]
    robot = np.zeros(s.present.shape, bool) if s.robot is None else s.robot
    share = np.where(robot, 2.0, 1.0)[:, None, :]  # reciprocal: twice the own change
    wx = s.ovx[:, None, :] - (v0x[:, :, None] + share * (vx - v0x)[:, :, None])
    wy = s.ovy[:, None, :] - (v0y[:, :, None] + share * (vy - v0y)[:, :, None])
    reach = (s.orad + s.radius[:, None] + MARGIN_CM)[:, None, :]
    t = time_to_contact(px, py, wx, wy, reach)
    t = np.where(s.present[:, None, :], t, np.inf)
    return t.min(axis=2) if t.shape[2] else np.full(t.shape[:2], np.inf)


def guard(
    s: Situation,
    heading: FloatArray,
    speed: FloatArray,
    guard_s: FloatArray,
    limits: DriveLimits,
    arena: Arena | None = None,
    edge_cm: FloatArray | float = 0.0,
    way: FloatArray | None = None,
    last: FloatArray | None = None,
) -> Wish:
    """The wishes of B robots (``heading`` rad, ``speed`` cm/s), each kept or changed
    by its guard of ``guard_s`` (s; 0: off) (module docstring), each robot turning its
    way round ``way`` and steered to ``last`` (rad; NaN: none) the frame before
    (:class:`~.steering.Turns`; None: neither kept)."""
    heading = np.asarray(heading, float)
    speed = np.asarray(speed, float)
    guard_s = np.broadcast_to(np.asarray(guard_s, float), heading.shape)
    wished = heading if arena is None else inside(s, heading, arena, edge_cm)
    now = _contact_times(s, wished[:, None], speed[:, None], limits, way)[:, 0]
    danger = np.flatnonzero(now < guard_s)
    if danger.size == 0:
        none = np.zeros(heading.shape, bool)
        return Wish(heading, speed, none, none)
    d = Situation(*(None if f is None else f[danger] for f in s))
    turns = np.radians(np.array(TURNS_DEG))
    top = limits.max_speed_cm_s
    speeds = np.array(SPEEDS) * top
    # candidates: every turn at every speed, and every turn at the wished speed
    h = wrap_rad(heading[danger, None, None] + turns[None, :, None])
    v = np.concatenate(
        [np.broadcast_to(speeds, (danger.size, speeds.size)), speed[danger, None]], axis=1
    )[:, None, :]
    h, v = np.broadcast_arrays(h, v)
    h = h.reshape(danger.size, -1)
    v = v.reshape(danger.size, -1)
    if arena is not None:
        edge = np.broadcast_to(np.asarray(edge_cm, float), heading.shape)[danger]
        rows = np.repeat(np.arange(danger.size), h.shape[1])
        flat = Situation(*(None if f is None else f[rows] for f in d))
        h = inside(flat, h.reshape(-1), arena, edge[rows]).reshape(h.shape)
    t = _contact_times(d, h, v, limits, None if way is None else way[danger])
    to_goal, _ = goal_direction(d)
    away = np.abs(wrap_rad(h - to_goal[:, None])) / np.pi
    away = away + np.abs(v - speed[danger, None]) / top
    score = np.minimum(t, guard_s[danger, None]) - NEAR_WISH_S * 0.5 * away
    if last is not None:  # keep to the last choice unless another is clearly better
        clear = t >= guard_s[danger, None]
        score = score - KEEP_S * off_last(h, last[danger], to_goal, clear)
    best = np.argmax(score, axis=1)
    rows = np.arange(danger.size)
    heading, speed = heading.copy(), speed.copy()
    heading[danger] = h[rows, best]
    speed[danger] = v[rows, best]
    guarded = np.zeros(heading.shape, bool)
    guarded[danger] = True
    return Wish(heading, speed, guarded, guarded & (speed == 0.0))
