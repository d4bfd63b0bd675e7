"""Paths of marked robots in the simulated arena: smooth closed curves that cross.

Each marked robot drives round an ellipse, ``p(t) = c + R(α)·(a cos θ, b sin θ)`` with
``θ = φ ± 2π t / T``: every robot has the same period ``T`` (frames), so the whole scene
repeats every ``T`` frames and checking one period proves every frame valid. Heading is
the direction of motion (the tangent), velocity the exact derivative (cm per frame),
and the tightest turn has radius ``b²/a`` ≥ :data:`MIN_TURN_RADIUS_CM`.

The ellipses are drawn at random (one ``numpy`` Generator) and kept only when, in
every frame of the period, each robot's disk of radius ``reach`` (its circumscribed
circle) is inside the arena and keeps the gap to every robot placed before it, both
in the world and as the camera sees it (central projection from the camera centre,
like :class:`ovis.common.sim.arena.Arena`), and its path crosses one placed before.
Obstacles are then set down still, beside a robot's path (clear of every robot in
every frame by the gap plus at most :data:`OBSTACLE_SLACK_CM`), so robots pass near them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["MIN_TURN_RADIUS_CM", "OBSTACLE_SLACK_CM", "EllipsePaths", "plan_paths"]

FloatArray = NDArray[np.float64]

#: Tightest turn of a robot's path (cm).
MIN_TURN_RADIUS_CM = 12.0
#: Obstacles are at most this much (cm) farther from a path than the gap requires.
OBSTACLE_SLACK_CM = 6.0
#: Two paths cross where their sampled points come this close (cm).
_CROSSING_CM = 1.5
_TRIES = 2000
#: Robots (with their gaps) may cover at most this share of the arena.
_MAX_CROWD = 0.3


@dataclass(frozen=True)
class EllipsePaths:
    """The robots' ellipses: (n,) arrays of centre, semi-axes, rotation, phase, sense."""

    cx: FloatArray
    cy: FloatArray
    a: FloatArray
    b: FloatArray
    alpha: FloatArray
    phase: FloatArray
    sense: FloatArray
    period: int

    def _theta(self, t: float | FloatArray) -> FloatArray:
        return (
            self.phase + self.sense * 2.0 * math.pi * np.asarray(t, dtype=np.float64) / self.period
        )

    def position(self, t: float) -> tuple[FloatArray, FloatArray]:
        """Centres (cm) of every robot at frame ``t``."""
        th = self._theta(t)
        u, v = self.a * np.cos(th), self.b * np.sin(th)
        ca, sa = np.cos(self.alpha), np.sin(self.alpha)
        return self.cx + u * ca - v * sa, self.cy + u * sa + v * ca

    def velocity(self, t: float) -> tuple[FloatArray, FloatArray]:
        """Velocities (cm per frame) of every robot at frame ``t``."""
        th = self._theta(t)
        w = self.sense * 2.0 * math.pi / self.period
        du, dv = -self.a * np.sin(th) * w, self.b * np.cos(th) * w
        ca, sa = np.cos(self.alpha), np.sin(self.alpha)
        return du * ca - dv * sa, du * sa + dv * ca


def _ellipse_points(
    cx: float, cy: float, a: float, b: float, alpha: float, theta: FloatArray
) -> tuple[FloatArray, FloatArray]:
    u, v = a * np.cos(theta), b * np.sin(theta)
    ca, sa = math.cos(alpha), math.sin(alpha)
    return cx + u * ca - v * sa, cy + u * sa + v * ca


def plan_paths(
    rng: np.random.Generator,
    *,
    n: int,
    reach_cm: float,
    speed_cm_per_frame: float,
    arena_x_cm: tuple[float, float],
    arena_y_cm: tuple[float, float],
    gap_cm: float,
    seen: Callable[[FloatArray, FloatArray], tuple[FloatArray, FloatArray, float]],
    fits_image: Callable[[FloatArray, FloatArray], bool],
) -> EllipsePaths:
    """Draw ``n`` crossing ellipses that keep robots of radius ``reach_cm`` apart.

    ``seen(x, y)`` gives where the camera sees robot-top points (on the floor, by central
    projection) and the scale of a length there; ``fits_image(x, y)`` whether disks of
    radius ``reach_cm`` at those centres are inside the image. For each drawn ellipse,
    every start phase (in whole frames) is tried. Raises ValueError if no such paths
    are found.
    """
    (x0, x1), (y0, y1) = arena_x_cm, arena_y_cm
    crowd = n * math.pi * (reach_cm + gap_cm) ** 2 / max((x1 - x0) * (y1 - y0), 1e-9)
    if crowd > _MAX_CROWD:
        raise ValueError(
            f"cannot find crossing paths for {n} robots of radius {reach_cm:.1f} cm: with "
            f"their gaps they would cover {crowd:.0%} of the arena x {arena_x_cm} cm, y "
            f"{arena_y_cm} cm (at most {_MAX_CROWD:.0%}); use fewer or smaller robots"
        )
    span = min(x1 - x0, y1 - y0) / 2.0 - reach_cm
    a_lo, a_hi = MIN_TURN_RADIUS_CM, max(MIN_TURN_RADIUS_CM, 0.8 * span)
    # one period for all: the mean perimeter at the wanted speed
    mean_a = 0.5 * (a_lo + a_hi)
    period = max(8, round(2.0 * math.pi * 0.9 * mean_a / max(speed_cm_per_frame, 1e-6)))
    t = np.arange(period, dtype=np.float64)
    shift = (t[:, None] + t[None, :]).astype(np.int64) % period  # [start, frame]
    names = ("cx", "cy", "a", "b", "alpha", "phase", "sense")
    fields: dict[str, list[float]] = {k: [] for k in names}
    xs: list[FloatArray] = []
    ys: list[FloatArray] = []
    shapes: list[FloatArray] = []
    for i in range(n):
        for _ in range(_TRIES):
            a = rng.uniform(a_lo, a_hi)
            b = rng.uniform(max(math.sqrt(MIN_TURN_RADIUS_CM * a), 0.6 * a), a)
            alpha = rng.uniform(-math.pi, math.pi)
            sense = float(rng.choice([-1.0, 1.0]))
            room_x, room_y = x1 - x0 - 2 * (reach_cm + a), y1 - y0 - 2 * (reach_cm + a)
            if room_x < 0 or room_y < 0:
                continue
            cx = x0 + reach_cm + a + rng.uniform(0.0, room_x)
            cy = y0 + reach_cm + a + rng.uniform(0.0, room_y)
            theta = sense * 2.0 * math.pi * t / period
            x, y = _ellipse_points(cx, cy, a, b, alpha, theta)
            if not fits_image(x, y):
                continue
            outline = np.stack(
                _ellipse_points(cx, cy, a, b, alpha, np.linspace(0, 2 * math.pi, 240))
            )
            if shapes and not any(_crosses(outline, other) for other in shapes):
                continue
            clear = _clear_starts(x[shift], y[shift], reach_cm, xs, ys, gap_cm, seen)
            if not clear.size:
                continue
            start = int(rng.choice(clear))
            values = (cx, cy, a, b, alpha, sense * 2.0 * math.pi * start / period, sense)
            for k, value in zip(names, values, strict=True):
                fields[k].append(float(value))
            xs.append(x[shift[start]])
            ys.append(y[shift[start]])
            shapes.append(outline)
            break
        else:
            raise ValueError(
                f"cannot find crossing paths for {n} robots of radius {reach_cm:.1f} cm inside "
                f"the arena x {arena_x_cm} cm, y {arena_y_cm} cm with gaps of {gap_cm} cm "
                f"(placed {i}); enlarge the arena or use fewer or smaller robots"
            )
    arrays = {k: np.array(v) for k, v in fields.items()}
    return EllipsePaths(period=period, **arrays)  # type: ignore[arg-type]


def _clear_starts(
    x: FloatArray,
    y: FloatArray,
    radius: float,
    xs: list[FloatArray],
    ys: list[FloatArray],
    gap_cm: float,
    seen: Callable[[FloatArray, FloatArray], tuple[FloatArray, FloatArray, float]],
) -> NDArray[np.int64]:
    """Starts (rows of ``x, y``: (starts, frames)) at which a disk keeps ``gap_cm`` from
    equal disks moving along each of ``xs, ys`` in every frame, in the world and as seen."""
    if not xs:
        return np.arange(x.shape[0])
    ox, oy = np.stack(xs)[:, None, :], np.stack(ys)[:, None, :]  # (others, 1, frames)
    world = np.hypot(ox - x, oy - y) - 2.0 * radius
    sx, sy, s = seen(x, y)
    osx, osy, _ = seen(ox, oy)
    view = np.hypot(osx - sx, osy - sy) - 2.0 * s * radius
    ok = (np.minimum(world, view) >= gap_cm).all(axis=(0, 2))
    return np.flatnonzero(ok)


def _crosses(p: FloatArray, q: FloatArray) -> bool:
    d = np.hypot(p[0][:, None] - q[0][None, :], p[1][:, None] - q[1][None, :])
    return bool(d.min() <= _CROSSING_CM)


def place_still_obstacles(
    rng: np.random.Generator,
    paths: EllipsePaths,
    radii: FloatArray,
    *,
    reach_cm: float,
    arena_x_cm: tuple[float, float],
    arena_y_cm: tuple[float, float],
    gap_cm: float,
    seen_robot: Callable[[FloatArray, FloatArray], tuple[FloatArray, FloatArray, float]],
    seen_obstacle: Callable[[FloatArray, FloatArray], tuple[FloatArray, FloatArray, float]],
    fits_image: Callable[[float, float, float], bool],
) -> tuple[FloatArray, FloatArray]:
    """Still obstacles of the given radii, each beside a robot's path: clear of every
    robot in every frame by ``gap_cm`` to ``gap_cm + OBSTACLE_SLACK_CM`` (world and as
    seen), clear of each other, inside the arena and the image."""
    (x0, x1), (y0, y1) = arena_x_cm, arena_y_cm
    t = np.arange(paths.period, dtype=np.float64)
    rx, ry = (np.stack(v, axis=1) for v in zip(*(paths.position(k) for k in t), strict=True))
    srx, sry, s_r = seen_robot(rx, ry)
    ox: list[float] = []
    oy: list[float] = []
    for k, r in enumerate(radii):
        for _ in range(_TRIES):
            i = int(rng.integers(len(paths.cx)))
            f = int(rng.integers(paths.period))
            vx, vy = paths.velocity(f)
            norm = math.hypot(vx[i], vy[i]) or 1.0
            side = rng.choice([-1.0, 1.0])
            off = reach_cm + r + gap_cm + rng.uniform(0.5, OBSTACLE_SLACK_CM)
            x = rx[i, f] - side * vy[i] / norm * off
            y = ry[i, f] + side * vx[i] / norm * off
            if not (x0 + r <= x <= x1 - r and y0 + r <= y <= y1 - r):
                continue
            if not fits_image(float(x), float(y), float(r)):
                continue
            world = np.hypot(rx - x, ry - y) - reach_cm - r
            sx, sy, s_o = seen_obstacle(np.array([x]), np.array([y]))
            view = np.hypot(srx - sx[0], sry - sy[0]) - s_r * reach_cm - s_o * r
            if min(world.min(), view.min()) < gap_cm:
                continue
            others = [
                math.hypot(x - px, y - py) - r - radii[j]
                for j, (px, py) in enumerate(zip(ox, oy, strict=True))
            ]
            if others and min(others) < gap_cm * 2.0:
                continue
            ox.append(float(x))
            oy.append(float(y))
            break
        else:
            raise ValueError(
                f"cannot place obstacle {k + 1} of {len(radii)} beside the robots' paths; "
                "enlarge the arena or use fewer obstacles"
            )
    return np.array(ox), np.array(oy)
