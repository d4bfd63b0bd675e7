"""The dynamic window approach (Fox, Burgard & Thrun 1997), for moving obstacles: the
baseline the fuzzy planner is compared with.

Each control period the robot tries the velocities (v, ω) it can reach in one period
(speeds within ``accel × period`` of its current one, all turn rates up to the top
one: a differential drive changes its turn rate far faster than its speed), follows
each on its arc for ``HORIZON_S`` while every other body moves on at its measured
velocity, and scores the arc:

* **heading**: how well the arc's end faces the goal (1 − |angle| / 180°),
* **clearance**: the least gap to any body along it (capped at ``CLEAR_CAP_CM``),
* **velocity**: v over the top speed,
* **progress**: the distance to the goal it gains, over what top speed would gain,

as ``Σ weight × term``. An arc is admissible only if its clearance stays above
``MARGIN_CM`` and the robot could still brake to a stop before that gap closes
(``v ≤ √(2·brake·gap)``). With no admissible arc the robot stops and turns in place.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ovis.common.navigation.base import DriveLimits
from ovis.common.navigation.observe import Situation
from ovis.common.navigation.steering import Arena, Steer, goal_direction, steer, wrap_rad

__all__ = ["DwaWeights", "dwa"]

HORIZON_S = 1.6
STEP_S = 0.1
SPEEDS = 7
TURNS = 17
MARGIN_CM = 1.5
CLEAR_CAP_CM = 25.0


class DwaWeights(NamedTuple):
    heading: float = 0.8
    clearance: float = 1.0
    velocity: float = 0.4
    progress: float = 1.0


def dwa(
    s: Situation,
    limits: DriveLimits,
    tolerance_cm: float,
    period_s: float,
    arena: Arena | None = None,
    weights: DwaWeights = DwaWeights(),  # noqa: B008  (an immutable NamedTuple)
) -> Steer:
    """The commands of B robots by the dynamic window approach (module docstring)."""
    b = s.x.size
    reach = limits.accel_cm_s2 * period_s
    lo = np.maximum(s.speed - reach, 0.0)
    hi = np.minimum(np.maximum(s.speed, 0.0) + reach, limits.max_speed_cm_s)
    frac = np.linspace(0.0, 1.0, SPEEDS)
    v = lo[:, None, None] + (hi - lo)[:, None, None] * frac[None, :, None]  # (B, V, 1)
    w = np.radians(np.linspace(-limits.max_yaw_rate_deg_s, limits.max_yaw_rate_deg_s, TURNS))
    v, w = np.broadcast_arrays(v, w[None, None, :])  # (B, V, W)
    times = np.arange(1, round(HORIZON_S / STEP_S) + 1) * STEP_S  # (T,)
    th0 = s.heading[:, None, None, None]
    t = times[None, None, None, :]
    ww = w[..., None]
    vv = v[..., None]
    turning = np.abs(ww) > 1e-9
    safe_w = np.where(turning, ww, 1.0)
    th = th0 + ww * t
    px = s.x[:, None, None, None] + np.where(
        turning, vv / safe_w * (np.sin(th) - np.sin(th0)), vv * t * np.cos(th0)
    )
    py = s.y[:, None, None, None] + np.where(
        turning, -vv / safe_w * (np.cos(th) - np.cos(th0)), vv * t * np.sin(th0)
    )  # (B, V, W, T)
    gap = np.full(px.shape, np.inf)
    for j in range(s.ox.shape[1]):
        ox = (s.ox[:, j, None] + s.ovx[:, j, None] * times[None, :])[:, None, None, :]
        oy = (s.oy[:, j, None] + s.ovy[:, j, None] * times[None, :])[:, None, None, :]
        d = (
            np.hypot(px - ox, py - oy)
            - s.orad[:, j, None, None, None]
            - s.radius[:, None, None, None]
        )
        gap = np.minimum(gap, np.where(s.present[:, j, None, None, None], d, np.inf))
    if arena is not None:  # the arena's edges are walls: an arc beyond them is not taken
        r = s.radius[:, None, None, None]
        wall = np.minimum.reduce(
            [px - r - arena.x0, arena.x1 - px - r, py - r - arena.y0, arena.y1 - py - r]
        )
        gap = np.minimum(gap, wall)
    clearance = gap.min(axis=3)
    # the gap now, too: an arc that starts inside the margin is not admissible
    admissible = (clearance > MARGIN_CM) & (
        v <= np.sqrt(2.0 * limits.brake_cm_s2 * np.maximum(clearance - MARGIN_CM, 0.0))
    )
    to_goal, dist0 = goal_direction(s)
    end_x, end_y, end_th = px[..., -1], py[..., -1], th[..., -1]
    gx, gy = s.goal_x[:, None, None], s.goal_y[:, None, None]
    facing = np.abs(wrap_rad(np.arctan2(gy - end_y, gx - end_x) - end_th)) / np.pi
    gained = (dist0[:, None, None] - np.hypot(gx - end_x, gy - end_y)) / (
        limits.max_speed_cm_s * HORIZON_S
    )
    score = (
        weights.heading * (1.0 - facing)
        + weights.clearance * np.minimum(clearance, CLEAR_CAP_CM) / CLEAR_CAP_CM
        + weights.velocity * v / limits.max_speed_cm_s
        + weights.progress * gained
    )
    score = np.where(admissible, score, -np.inf).reshape(b, -1)
    best = np.argmax(score, axis=1)
    rows = np.arange(b)
    ok = np.isfinite(score[rows, best])
    v_best = np.where(ok, v.reshape(b, -1)[rows, best], 0.0)
    w_best = np.where(ok, w.reshape(b, -1)[rows, best], 0.0)
    # no admissible arc: stop, and turn towards the goal in place (steer's turn)
    turn = steer(s, to_goal, np.zeros(b), limits, tolerance_cm)
    omega = np.where(ok, np.degrees(w_best), turn.omega_deg_s)
    # and never past the goal
    near = steer(s, s.heading, v_best, limits, tolerance_cm)
    return Steer(np.minimum(v_best, near.v_cm_s), np.where(near.arrived, 0.0, omega), near.arrived)
