"""A fast simulation of many drives at once, for tuning a planner on training scenarios.

The physical world (MuJoCo, :mod:`.episode`) is what the planners are judged in; a GA
needs thousands of drives per generation, so it runs this instead, for a whole
population over all training scenarios in one batch of arrays: each robot a
differential drive whose rims follow the commands within the same speed and
acceleration limits (:mod:`.base`), integrated every ``STEP_S``; commands made every
control period from what the robot sees then and applied ``latency`` later (the
pipeline's median); the obstacles on their paths (:class:`~ovis.common.physical.scene.
Path`, evaluated once per scenario); each body a disk (an obstacle's circumscribed
one: a box's corners count), a contact when disks come closer than
``CONTACT_MARGIN_CM`` (a planner tuned to graze would touch on what ovis sees: its
positions are off by up to a few centimetres for obstacles far from the height it
assumes). What the planner sees is
disturbed as ovis's measurements are (``POSITION_SIGMA_CM``, ``VELOCITY_SIGMA_CM_S`` on
the others; drawn from a fixed seed, so that a string's fitness is the same each time
the GA asks).

A drive ends at the goal (within its tolerance), at a contact, or at the scenario's
timeout. Its **cost** (lower is better): at the goal, the time over the straight-line
time at top speed (≥ 1); after a contact, ``CONTACT_COST`` plus the share of the way
still to go; at the timeout, ``TIMEOUT_COST`` plus that share. A contact costs far more
than any detour saves (the planner's target is to arrive without contact; its time
counts only against the oracle's), a timeout less than a contact (a robot that waits
too long is not a danger).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ovis.common.config import NavigationConfig
from ovis.common.navigation.base import DriveLimits, body_velocity, ramp, wheel_targets
from ovis.common.navigation.observe import Situation
from ovis.common.navigation.scenarios import Scenario
from ovis.common.navigation.steering import Steer

__all__ = [
    "CONTACT_COST",
    "CONTACT_MARGIN_CM",
    "TIMEOUT_COST",
    "Drives",
    "TrainingSet",
    "costs",
    "simulate",
    "training_set",
]

STEP_S = 0.025
CONTACT_MARGIN_CM = 1.5
POSITION_SIGMA_CM = 0.3
VELOCITY_SIGMA_CM_S = 1.5
CONTACT_COST = 20.0
TIMEOUT_COST = 10.0
NOISE_SEED = 37

FloatArray = NDArray[np.float64]
#: A batched planner: a Situation and, per row, which copy (controller) it is.
Policy = Callable[[Situation, NDArray[np.int64]], Steer]


class TrainingSet(NamedTuple):
    """S scenarios of R robots and M obstacles as arrays, the obstacles' paths sampled
    at ``STEP_S``: positions and velocities (S, M, T), circumscribed radius (contacts)
    and equal-area radius (what ovis reports: what the planner sees) (S, M)."""

    start_x: FloatArray
    start_y: FloatArray
    yaw: FloatArray
    goal_x: FloatArray
    goal_y: FloatArray
    radius: FloatArray
    ox: FloatArray
    oy: FloatArray
    ovx: FloatArray
    ovy: FloatArray
    bound: FloatArray
    seen_radius: FloatArray
    timeout_s: FloatArray


def training_set(scenarios: Sequence[Scenario]) -> TrainingSet:
    """The scenarios (all of one case and number of robots) as arrays."""
    if len({(len(s.tasks), len(s.obstacles)) for s in scenarios}) != 1:
        raise ValueError("training scenarios must all have the same robots and obstacles")
    longest = max(s.timeout_s for s in scenarios)
    times = np.arange(0.0, longest + 2 * STEP_S, STEP_S)
    tasks = np.array(
        [[(*t.start_cm, np.radians(t.yaw_deg), *t.goal_cm, t.radius_cm) for t in s.tasks]
         for s in scenarios]
    )  # fmt: skip
    paths = []
    for s in scenarios:
        per = []
        for o in s.obstacles:
            x, y = o.path.at(times, s.scene.period_s)
            vx, vy = o.path.velocity(times, s.scene.period_s)
            per.append(np.stack([x, y, vx, vy]))
        paths.append(per)
    track = np.array(paths)  # (S, M, 4, T)
    sizes = np.array([[(o.bound_cm, o.radius_cm) for o in s.obstacles] for s in scenarios])
    return TrainingSet(
        *(tasks[..., k] for k in range(6)),
        *(track[:, :, k, :] for k in range(4)),
        sizes[..., 0],
        sizes[..., 1],
        np.array([s.timeout_s for s in scenarios]),
    )


class Drives(NamedTuple):
    """How each drive ended, (C, S, R): at the goal, with a contact, its time (s), the
    share of the way left, and the straight-line time at top speed (s)."""

    reached: NDArray[np.bool_]
    contact: NDArray[np.bool_]
    time_s: FloatArray
    left: FloatArray
    straight_s: FloatArray


def simulate(
    policy: Policy,
    data: TrainingSet,
    copies: int,
    nav: NavigationConfig,
    margin_cm: float = CONTACT_MARGIN_CM,
) -> Drives:
    """Drive every robot of every scenario with each of ``copies`` controllers (module
    docstring; ``margin_cm``: how close is a contact, 0: touching)."""
    limits = DriveLimits.of(nav)
    S, R = data.start_x.shape
    M = data.ox.shape[1]
    shape = (copies, S, R)
    B = copies * S * R

    def flat(a: FloatArray) -> FloatArray:  # (S, R) → (B,)
        return np.broadcast_to(a, shape).reshape(B).astype(float)

    rows = np.broadcast_to(np.arange(copies)[:, None, None], shape).reshape(B)
    scen = np.broadcast_to(np.arange(S)[None, :, None], shape).reshape(B)
    me = np.broadcast_to(np.arange(R)[None, None, :], shape).reshape(B)
    x, y, th = flat(data.start_x), flat(data.start_y), flat(data.yaw)
    gx, gy, rad = flat(data.goal_x), flat(data.goal_y), flat(data.radius)
    distance = np.hypot(gx - x, gy - y)
    timeout = data.timeout_s[scen]
    rims = np.zeros((B, 2))
    command = np.zeros((B, 2))
    pending = np.zeros((B, 2))
    braking = pending_brake = np.zeros(B, dtype=bool)
    period = max(1, round(1.0 / (nav.rate_hz * STEP_S)))
    delay = round(nav.latency_ms[0] / 1000.0 / STEP_S)
    due = -1
    done = np.zeros(B, dtype=bool)
    reached = np.zeros(B, dtype=bool)
    contact = np.zeros(B, dtype=bool)
    when = np.zeros(B)
    rng = np.random.default_rng(NOISE_SEED)
    # the other robots of each robot's scenario: (B, R-1) indices into the batch
    base = np.arange(B) - me
    mates = np.stack([base + j for j in range(R)], axis=1)
    mates = np.array([row[row != i] for i, row in enumerate(mates)]).reshape(B, R - 1)
    steps = int(np.ceil(timeout.max() / STEP_S))
    for k in range(steps + 1):
        t = k * STEP_S
        ox, oy = data.ox[scen, :, k], data.oy[scen, :, k]
        v, w = body_velocity(rims[:, 0], rims[:, 1], limits)
        if k % period == 0:
            noise = rng.standard_normal((4, B, M))
            others_x = np.concatenate([ox + POSITION_SIGMA_CM * noise[0], x[mates]], axis=1)
            others_y = np.concatenate([oy + POSITION_SIGMA_CM * noise[1], y[mates]], axis=1)
            ovx = data.ovx[scen, :, k] + VELOCITY_SIGMA_CM_S * noise[2]
            ovy = data.ovy[scen, :, k] + VELOCITY_SIGMA_CM_S * noise[3]
            s = Situation(
                x, y, th, v, rad, gx, gy,
                others_x,
                others_y,
                np.concatenate([ovx, (v * np.cos(th))[mates]], axis=1),
                np.concatenate([ovy, (v * np.sin(th))[mates]], axis=1),
                np.concatenate([data.seen_radius[scen], rad[mates]], axis=1),
                np.ones((B, M + R - 1), dtype=bool),
                np.arange(M + R - 1)[None, :].repeat(B, axis=0) >= M,
            )  # fmt: skip
            out = policy(s, rows)
            pending = np.stack([out.v_cm_s, out.omega_deg_s], axis=1)
            pending_brake = np.zeros(B, bool) if out.brake is None else out.brake
            due = k + delay
        if k == due:
            command, braking = pending, pending_brake
        # contacts and arrivals at this instant
        gap = np.hypot(ox - x[:, None], oy - y[:, None]) - data.bound[scen] - rad[:, None]
        if R > 1:
            mate_gap = np.hypot(x[mates] - x[:, None], y[mates] - y[:, None])
            gap = np.concatenate([gap, mate_gap - rad[mates] - rad[:, None]], axis=1)
        hit = ~done & (gap.min(axis=1) < margin_cm)
        home = ~done & (np.hypot(gx - x, gy - y) <= nav.goal_tolerance_cm)
        late = ~done & (t >= timeout)
        contact |= hit
        reached |= home & ~hit
        when = np.where(hit | home | late, t, when)
        done |= hit | home | late
        if done.all():
            break
        left, right = wheel_targets(command[:, 0], command[:, 1], limits)
        stop = done | braking
        target = np.where(stop[:, None], 0.0, np.stack([left, right], axis=1))
        rate = np.where(braking, limits.brake_cm_s2, limits.accel_cm_s2)[:, None]
        rims = ramp(rims, target, rate * STEP_S)
        v, w = body_velocity(rims[:, 0], rims[:, 1], limits)
        mid = th + 0.5 * w * STEP_S
        x = x + v * np.cos(mid) * STEP_S
        y = y + v * np.sin(mid) * STEP_S
        th = th + w * STEP_S
    remaining = np.hypot(gx - x, gy - y) / np.maximum(distance, 1e-9)
    return Drives(
        reached.reshape(shape),
        contact.reshape(shape),
        when.reshape(shape),
        np.clip(remaining, 0.0, 1.0).reshape(shape),
        (distance / limits.max_speed_cm_s).reshape(shape),
    )


def costs(d: Drives) -> FloatArray:
    """Each copy's mean cost over its drives (module docstring), (C,)."""
    each = np.where(
        d.reached,
        d.time_s / d.straight_s,
        np.where(d.contact, CONTACT_COST + d.left, TIMEOUT_COST + d.left),
    )
    return each.reshape(each.shape[0], -1).mean(axis=1)
