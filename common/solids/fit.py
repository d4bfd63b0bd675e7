"""The solids a blob's outline shows: shape, footprint and height, by least squares.

The outline's sub-pixel edge points, back-projected onto the floor, lie on the union of
the blob's solids' silhouettes (:mod:`ovis.common.solids.silhouette`). Each point's
residual is its signed distance to that union, in pixels (the floor distance times the
pixels per cm across the outline there), under a soft-L1 loss (a few wrong points — a
marker's cell, a corner rounded by the blur — weigh little). The fit is a
Levenberg–Marquardt run on many parameter vectors at once (:func:`levenberg_marquardt`:
numeric Jacobians, one batched evaluation per step).

A blob of one solid (:func:`fit_piece`): each shape is fitted from a start worked out of
the outline — its height from the radial sides of the silhouette (the prism's vertical
edges: along them the far end over the near end's distance from the camera's foot is
``S``), its footprint from the near side and the far side shrunk by ``S``, a polygon's
yaw from the footprint's n-fold symmetry —, the shape of least cost (plus a small
price per parameter) is kept and started again from several heights. A blob of several
(:func:`fit_union`) is cut where its outline turns inward, each piece fitted alone,
then all together against the whole outline, and a solid dropped where the others, fitted
again without it, explain the outline as well (:func:`_without_redundant`); one whose
single solid does not explain its outline is also cut across the line of sight (two
solids in line with the camera, the near one hiding the far one's foot:
:func:`_split_along_sight`).

Each solid's covariance comes from the Jacobian and the residuals (scaled for the
correlation of neighbouring edge points, which share pixels), plus what a bias common
to all its edges would do (:data:`EDGE_BIAS_PX`) and what the edges on walls too thin to
be told from the top's edge would, found at the top face's rim (:data:`THIN_WALL_PX`:
a low solid's sides seen nearly edge-on). Points of a union's outline near two
silhouettes (:func:`_junctions`) count for the fit but not for the covariance: a solid
whose walls' foot is hidden behind another is then, rightly, not measurable. Where such
a solid stands is bounded by the others (:func:`bound_behind`): it is placed halfway
along the stretch of its line of sight they leave it, its covariance spread over that.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.solids.shapes import (
    SHAPES,
    equal_area_radius,
    footprint_polygon,
    parameter_count,
    shape_sides,
    yaw_index,
)
from ovis.common.solids.silhouette import (
    MAX_HEIGHT_SHARE,
    Viewpoint,
    signed_distance,
    signed_distance_few,
    signed_distance_jacobian,
    top_distance,
    top_scale,
)
from ovis.common.vision.outline import PROFILE_REACH_PX

__all__ = [
    "FloorOutline",
    "RoughFootprint",
    "Solid",
    "along_sight",
    "bound_behind",
    "feet_hidden",
    "fit_blob",
    "fit_piece",
    "fit_union",
    "follow_union",
    "height_spread",
    "held_covariance",
    "held_height",
    "levenberg_marquardt",
    "radial_height",
    "refit",
    "refit_with_tops",
    "robot_misfit",
    "rough_footprint",
    "solve_small",
    "union_offsets",
    "unplaced_covariance",
]

FloatArray = NDArray[np.float64]
Residuals = Callable[[FloatArray], FloatArray]

#: Soft-L1 loss scale (px): residuals beyond it weigh less and less.
LOSS_PX = 0.3
#: Iterations of a fit, and of the final refinement on every point.
ITERATIONS = 30
#: Edge points used to choose the shape (every k-th of the outline).
SEARCH_POINTS = 120
#: Iterations every shape gets before the shapes are ranked, and how many of the best
#: ranked then get the rest of :data:`ITERATIONS` (the choice is seldom close after a
#: few steps, and a shape's fit costs alike whether it is kept or not).
SELECT_ITERATIONS = 10
SELECT_KEEP = 2
#: Extra cost per parameter when choosing the shape (px² of residual).
PARAMETER_PRICE = 5.0
#: Heights a shape is started from again (cm), beside the one the radial sides give.
HEIGHT_STARTS = (2.0, 8.0, 16.0, 24.0)
#: Neighbouring edge points share pixels: the covariance is scaled by this.
CORRELATION = 3.0
#: Least residual spread assumed for the covariance (px).
MIN_SPREAD_PX = 0.1
#: How far the walls' feet (the outline's side facing the camera's foot) may all be
#: off, one way (px): a bias the residuals cannot show (a thin dark wall blurred into the
#: floor), counted in the covariance.
EDGE_BIAS_PX = 0.25
#: A wall narrower than this in the frame (px) is not told from the top's edge: the edge
#: found there may be the top face's rim, as far inside as the wall is wide (a bias the
#: residuals cannot show either, counted in the covariance).
THIN_WALL_PX = 1.0
#: Smallest size of a footprint's side or radius (cm).
MIN_SIZE_CM = 0.3
#: Lowest height tried (cm).
MIN_HEIGHT_CM = 0.05
#: A height not measurable is held at the configured one where that is within this
#: many of its σ of the fitted one (two-sided 95 %).
HELD_SIGMAS = 1.96
#: Edge points a piece of a cut outline needs to be fitted as a solid of its own.
MIN_PIECE_POINTS = 10
#: An edge point this far (px) from the fitted silhouettes is one the fit does not explain.
OFF_PX = 1.0
#: A fit leaving more than this share of its edge points unexplained (:data:`OFF_PX`)
#: did not find what the outline is (a wrong shape, two solids taken for one): a few
#: points far off (a floor mark, a marker's cell) are a small share, a wrong shape's
#: sides a large one. The root-mean-square residual is no such test: those few points
#: alone can lift it as high as a wrong shape does.
MAX_OFF_SHARE = 0.1
#: Where a blob's one solid does not explain its outline and the outline does not turn
#: inward, it is cut across the line of sight at these shares of its extent along it,
#: in this order (the first cut whose two solids explain it is kept); the points this
#: near a cut (px) are left out of both pieces' own fits.
SIGHT_CUTS = (0.5, 0.3, 0.7)
SIGHT_GAP_PX = 2.0
#: An outline's point this near (px) two solids' silhouettes may be either's edge: the
#: edge profile reaches this far (:data:`~ovis.common.vision.outline.PROFILE_REACH_PX`).
JUNCTION_PX = PROFILE_REACH_PX
#: A solid's walls' foot is hidden when this share of it lies inside others' silhouettes.
FOOT_HIDDEN_SHARE = 0.5
#: Added to the normal matrix's diagonal where no point counts along some direction of
#: the parameters: that direction's variance is then without bound (not measurable).
UNPINNED = 1e-9
#: Where a solid whose foot is hidden can stand (:func:`bound_behind`): heights tried
#: this far apart (cm), each bound then worked out to within :data:`BOUND_TOL_CM`.
BOUND_STEP_CM = 0.5
BOUND_TOL_CM = 0.01
#: A footprint's edge faces the camera's foot when its outward normal points at it
#: within this cosine: its foot would be seen unless something hides it.
FACING_COS = 0.3


class FloorOutline(NamedTuple):
    """Edge points of an outline on the floor (N, 2) cm, their outward normals on the
    floor (N, 2) and pixels per cm across the outline at each (N,)."""

    points: FloatArray
    normals: FloatArray
    px_per_cm: FloatArray

    def take(self, which: NDArray[np.int64] | NDArray[np.bool_] | slice) -> FloorOutline:
        return FloorOutline(self.points[which], self.normals[which], self.px_per_cm[which])


class Solid(NamedTuple):
    """One fitted solid: its shape, parameter vector (:mod:`~ovis.common.solids.shapes`),
    covariance (noise and edge bias), the root-mean-square residual (px), edge points of
    its fit, how far the parameters would move were every edge :data:`EDGE_BIAS_PX`
    further out (the part of the covariance no averaging over fits removes), and the
    share of its edge points more than :data:`OFF_PX` from the silhouettes fitted."""

    shape: str
    theta: FloatArray
    covariance: FloatArray
    rms_px: float
    points: int
    edge_shift: FloatArray
    off_share: float = 0.0

    @property
    def explains(self) -> bool:
        """Whether the fit explains its outline (:data:`MAX_OFF_SHARE`)."""
        return self.off_share <= MAX_OFF_SHARE

    @property
    def radius_cm(self) -> float:
        return float(equal_area_radius(self.shape, self.theta))


def _bounds(
    shape: str, view: Viewpoint, height: float | None = None
) -> tuple[FloatArray, FloatArray]:
    """Each parameter's range; ``height``: the height held there (declared)."""
    p = parameter_count(shape)
    lo, hi = np.full(p, -np.inf), np.full(p, np.inf)
    lo[2] = MIN_SIZE_CM
    if shape == "box":
        lo[3] = MIN_SIZE_CM
    lo[-1], hi[-1] = MIN_HEIGHT_CM, 0.95 * MAX_HEIGHT_SHARE * view.height_cm
    if height is not None:
        lo[-1] = hi[-1] = min(max(height, lo[-1]), hi[-1])
    return lo, hi


def _cost(r: FloatArray) -> FloatArray:
    z = (r / LOSS_PX) ** 2
    return (2.0 * LOSS_PX**2 * (np.sqrt(1.0 + z) - 1.0)).sum(-1)


def levenberg_marquardt(
    residuals: Residuals,
    theta0: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    *,
    iterations: int = ITERATIONS,
) -> tuple[FloatArray, FloatArray]:
    """Minimise the soft-L1 cost of ``residuals`` (M, P) → (M, N) from each of the
    starts ``theta0`` (B, P) within the bounds; returns the solutions and their costs.
    Forward-difference Jacobians; every start's step is solved at once."""
    theta = np.clip(np.array(theta0, dtype=np.float64), lo, hi)
    b, p = theta.shape
    step = 1e-4 * np.maximum(1.0, np.abs(theta))
    r = residuals(theta)
    cost = _cost(r)
    damping = np.full(b, 1e-3)
    eye = np.eye(p)
    active = np.ones(b, dtype=bool)
    for _ in range(iterations):
        if not active.any():
            break
        moved = (theta[:, None, :] + step[:, None, :] * eye).reshape(b * p, p)
        jac = (residuals(moved).reshape(b, p, -1) - r[:, None, :]) / step[:, :, None]
        weight = 1.0 / np.sqrt(1.0 + (r / LOSS_PX) ** 2)
        a = np.einsum("bpn,bqn,bn->bpq", jac, jac, weight)
        g = np.einsum("bpn,bn,bn->bp", jac, r, weight)
        diag = np.einsum("bpp->bp", a)
        lhs = a + (damping[:, None] * np.maximum(diag, 1e-12))[:, :, None] * eye
        try:
            delta = -np.linalg.solve(lhs, g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            delta = -np.linalg.lstsq(lhs[0], g[0], rcond=None)[0][None]
        trial = np.clip(theta + delta, lo, hi)
        r_trial = residuals(trial)
        c_trial = _cost(r_trial)
        better = active & (c_trial < cost)
        gain = np.where(better, (cost - c_trial) / np.maximum(cost, 1e-12), 0.0)
        theta[better], r[better], cost[better] = trial[better], r_trial[better], c_trial[better]
        damping = np.where(better, damping / 3.0, damping * 4.0)
        active &= ~(better & (gain < 1e-7)) & (damping < 1e8)
    return theta, cost


def _single(shape: str, floor: FloorOutline, view: Viewpoint) -> Residuals:
    def residuals(theta: FloatArray) -> FloatArray:
        return floor.px_per_cm * signed_distance(shape, theta, floor.points, view)

    return residuals


def radial_height(floor: FloorOutline, view: Viewpoint, tol_px: float = 0.35) -> float | None:
    """The height the silhouette's two radial sides give (module docstring), or None
    where none is seen (the camera's foot inside or in line with the footprint)."""
    rel = floor.points - view.foot
    rho = np.hypot(rel[:, 0], rel[:, 1])
    if rho.min() <= 0.0:
        return None
    ang = np.arctan2(rel[:, 1], rel[:, 0])
    mean = np.mean(rel / rho[:, None], 0)
    if np.hypot(*mean) < 0.5:  # the foot within the silhouette: no sides
        return None
    off = (ang - math.atan2(mean[1], mean[0]) + math.pi) % (2.0 * math.pi) - math.pi
    scales = []
    for k in (int(off.argmax()), int(off.argmin())):
        across = np.abs(np.sin(off - off[k])) * rho * floor.px_per_cm
        on = across < tol_px
        if on.sum() >= 3:
            scales.append(rho[on].max() / rho[on].min())
    if not scales:
        return None
    s = float(np.median(scales))
    return view.height_cm * (1.0 - 1.0 / s) if s > 1.0 else None


class RoughFootprint(NamedTuple):
    """:func:`rough_footprint`'s estimate: the footprint centre (2,) cm and the
    covariance (2, 2) cm² of where it may be."""

    centre: FloatArray
    covariance: FloatArray


def rough_footprint(floor: FloorOutline, view: Viewpoint) -> RoughFootprint | None:
    """A quick estimate of a one-solid outline's footprint centre (cm), before any fit,
    whatever its height: the outline's side facing the camera's foot is the foot of
    the walls, on the floor; the centre lies half the footprint's width (that side's
    extent across the line of sight) beyond it. How far beyond is a guess: the centre
    lies anywhere between that side and the outline's far end on the floor, and across
    the line of sight anywhere along that side (uniform over each, its covariance). None
    where the camera's foot is in line with the outline (no side faces it)."""
    rel = floor.points - view.foot
    rho = np.hypot(rel[:, 0], rel[:, 1])
    mean = np.mean(rel / np.maximum(rho, 1e-9)[:, None], 0)
    if np.hypot(*mean) < 0.5:  # the foot within the silhouette
        return None
    u = mean / np.hypot(*mean)
    v = np.array([-u[1], u[0]])
    near = (floor.normals * rel).sum(1) < -0.3 * rho
    if near.sum() < 3:
        return None
    along, across = rel[near] @ u, rel[near] @ v
    width = float(across.max() - across.min())
    centre = (
        view.foot
        + u * (float(along.min()) + 0.5 * width)
        + v * float(0.5 * (across.max() + across.min()))
    )
    depth = float((rel @ u).max() - along.min())
    axes = np.column_stack([u, v])
    covariance = axes @ np.diag([depth**2, width**2]) @ axes.T / 12.0
    return RoughFootprint(centre, covariance)


def _footprint_points(floor: FloorOutline, view: Viewpoint, height: float) -> FloatArray:
    """Points of the footprint's outline as the silhouette shows it at ``height``: the
    near side as it is, the far side shrunk by S about the camera's foot."""
    rel = floor.points - view.foot
    facing = (floor.normals * rel).sum(1) / np.maximum(np.hypot(rel[:, 0], rel[:, 1]), 1e-9)
    s = view.height_cm / (view.height_cm - height)
    pts = np.vstack([floor.points[facing < -0.3], view.foot + rel[facing > 0.3] / s])
    return pts if len(pts) >= 5 else floor.points


def _hull(points: FloatArray) -> FloatArray:
    h = cv2.convexHull(points.astype(np.float32), returnPoints=False).ravel()
    return points[h]


def _starts(shape: str, floor: FloorOutline, view: Viewpoint, height: float) -> FloatArray:
    """Start vectors of a shape for an outline, at ``height``."""
    pts = _footprint_points(floor, view, height)
    hull = _hull(pts)
    centre = hull.mean(0)
    area = max(float(cv2.contourArea(hull.astype(np.float32))), 0.5)
    if shape == "cylinder":
        return np.array([[centre[0], centre[1], math.sqrt(area / math.pi), height]])
    if shape == "box":
        (cx, cy), (a, b), deg = cv2.minAreaRect(hull.astype(np.float32))
        yaw = math.radians(deg)
        if b > a:
            a, b, yaw = b, a, yaw + 0.5 * math.pi
        a, b = max(a, 2 * MIN_SIZE_CM), max(b, 2 * MIN_SIZE_CM)
        return np.array(
            [
                [cx, cy, a, b, yaw, height],
                [cx, cy, math.sqrt(a * b), math.sqrt(a * b), yaw + 0.25 * math.pi, height],
            ]
        )
    n = shape_sides(shape)
    d = hull - centre
    edge = np.roll(hull, -1, 0) - hull
    length = np.hypot(edge[:, 0], edge[:, 1])
    theta = np.arctan2(d[:, 1], d[:, 0])
    rho = np.hypot(d[:, 0], d[:, 1])
    z = np.sum(length * rho * np.exp(1j * n * theta))
    yaw = float(np.angle(z)) / n
    circum = math.sqrt(2.0 * area / (n * math.sin(2.0 * math.pi / n)))
    return np.array(
        [
            [centre[0], centre[1], circum, yaw, height],
            [centre[0], centre[1], circum, yaw + math.pi / n, height],
        ]
    )


def _price(shape: str) -> float:
    return PARAMETER_PRICE * parameter_count(shape)


def _near_side(floor: FloorOutline, view: Viewpoint, heights: FloatArray) -> FloatArray:
    """Per point of the outline, how wide (px) the wall below its edge is in the frame
    where its outward normal faces the camera's foot (the walls' feet, where a thin dark
    wall blurs into the floor), −1 where it does not. ``heights``: per point, the height
    (cm) of the solid whose edge it is. A wall's width across the outline is the top
    face's offset there, ``(S − 1)`` times the distance of the point's edge line from the
    camera's foot."""
    rel = floor.points - view.foot
    facing = -(floor.normals * rel).sum(1)
    wall = (top_scale(heights, view) - 1.0) * facing * floor.px_per_cm
    return np.where(facing > 0.0, wall, -1.0)


class _Spread(NamedTuple):
    """A solution's covariance, root-mean-square residual (px), the shift a bias of
    some edges would cause and the share of points off by more than :data:`OFF_PX`."""

    cov: FloatArray
    rms: float
    shift: FloatArray
    off_share: float


def _covariance(
    residuals: Residuals,
    theta: FloatArray,
    walls: FloatArray | None = None,
    evidence: NDArray[np.bool_] | None = None,
) -> _Spread:
    """Covariance of a solution (scaled residual spread times the inverse normal
    matrix, plus the shifts two biases would cause: every edge of the walls' feet
    :data:`EDGE_BIAS_PX` further out; every edge on a wall narrower than
    :data:`THIN_WALL_PX` as far out as its wall is wide, found at the top face's rim),
    its root-mean-square residual (px), the first shift and the share of points off.
    ``walls``: the leading points' walls' widths (px; −1: no wall faces the camera's
    foot there; default: every point biased, none thin: :func:`_near_side`);
    ``evidence``: the leading points that count for the covariance (the rest count for
    the residuals only: :func:`_junctions`)."""
    p = theta.size
    step = 1e-4 * np.maximum(1.0, np.abs(theta))
    r = residuals(theta[None])[0]
    moved = theta + step[:, None] * np.eye(p)
    jac = (residuals(moved) - r) / step[:, None]
    rms, off = float(np.sqrt(np.mean(r * r))), float(np.mean(np.abs(r) > OFF_PX))
    weight = 1.0 / np.sqrt(1.0 + (r / LOSS_PX) ** 2)
    if evidence is not None:
        weight[: evidence.size] *= evidence
    a = (jac * weight) @ jac.T
    spread = max(float((weight * r * r).sum() / max(weight.sum() - p, 1.0)), MIN_SPREAD_PX**2)
    try:
        inv = np.linalg.inv(a)
    except np.linalg.LinAlgError:
        if evidence is None:
            return _Spread(np.full((p, p), np.inf), rms, np.full(p, np.inf), off)
        # a solid no point counts for along some direction (its walls' foot hidden behind
        # another): that direction's variance without bound, the others' as they are
        inv = np.linalg.inv(a + UNPINNED * np.eye(p))
    offset = np.zeros(r.size)
    thin = np.zeros(r.size)
    if walls is None:
        offset[:] = EDGE_BIAS_PX
    else:
        offset[: walls.size] = EDGE_BIAS_PX * (walls >= 0.0)
        thin[: walls.size] = np.where((walls >= 0.0) & (walls < THIN_WALL_PX), walls, 0.0)
    shift = inv @ ((jac * weight) @ offset)  # those edges EDGE_BIAS_PX further out
    rims = inv @ ((jac * weight) @ thin)  # the thin walls' edges at their feet
    cov = inv * spread * CORRELATION + np.outer(shift, shift) + np.outer(rims, rims)
    return _Spread(cov, rms, shift, off)


def fit_piece(
    floor: FloorOutline,
    view: Viewpoint,
    shapes: Sequence[str] = SHAPES,
    *,
    height: float | None = None,
) -> Solid:
    """The one solid whose silhouette best explains an outline (module docstring);
    ``height``: its height is known (declared), only the rest is fitted."""
    every = max(1, len(floor.points) // SEARCH_POINTS)
    few = floor.take(slice(None, None, every))
    radial = radial_height(few, view) if height is None else height
    h0 = float(np.clip(6.0 if radial is None else radial, 0.5, 0.8 * view.height_cm))
    trials: list[tuple[float, str, FloatArray]] = []
    for shape in shapes:  # every shape a few steps, the likeliest ones to the end
        lo, hi = _bounds(shape, view, height)
        starts = _starts(shape, few, view, h0)
        theta, cost = levenberg_marquardt(
            _single(shape, few, view), starts, lo, hi, iterations=SELECT_ITERATIONS
        )
        k = int(cost.argmin())
        trials.append((float(cost[k]) + _price(shape), shape, theta[k]))
    best: tuple[float, str, FloatArray] | None = None
    for _, shape, start in sorted(trials, key=lambda t: t[0])[:SELECT_KEEP]:
        lo, hi = _bounds(shape, view, height)
        theta, cost = levenberg_marquardt(
            _single(shape, few, view), start[None], lo, hi,
            iterations=ITERATIONS - SELECT_ITERATIONS,
        )  # fmt: skip
        score = float(cost[0]) + _price(shape)
        if best is None or score < best[0]:
            best = (score, shape, theta[0])
    assert best is not None
    _, shape, theta = best
    lo, hi = _bounds(shape, view, height)
    heights = [] if height is not None else HEIGHT_STARTS
    heights = [h for h in heights if abs(h - theta[-1]) > 1.0 and h < hi[-1]]
    if heights:
        starts = np.vstack([theta[None]] + [_starts(shape, few, view, h) for h in heights])
        thetas, cost = levenberg_marquardt(_single(shape, few, view), starts, lo, hi)
        theta = thetas[int(cost.argmin())]
    start = Solid(shape, theta, np.zeros((0, 0)), 0.0, 0, np.zeros(0))
    solid = refit(start, floor, view, height=height)
    if solid.explains or height is not None:  # a height held: no radial height misled it
        return solid
    return _from_every_start(solid, floor, view, shapes, h0)


def _from_every_start(
    found: Solid,
    floor: FloorOutline,
    view: Viewpoint,
    shapes: Sequence[str],
    h0: float,
) -> Solid:
    """A fit of free height that does not explain its outline (:attr:`Solid.explains`)
    made again with every shape started from every height (``h0``, the radial sides',
    and :data:`HEIGHT_STARTS`), not the chosen shape alone: where the radial sides give a
    wrong height, every shape's start is in a wrong valley (a box's yaw among them) and
    the shape chosen there is wrong. The fit of least cost (residuals plus a price per
    parameter), ``found`` among them."""
    every = max(1, len(floor.points) // SEARCH_POINTS)
    few = floor.take(slice(None, None, every))

    def score(solid: Solid) -> float:
        r = _single(solid.shape, floor, view)(solid.theta[None])
        return float(_cost(r)[0]) + _price(solid.shape)

    best, best_score = found, score(found)
    for shape in shapes:
        lo, hi = _bounds(shape, view)
        heights = [h for h in (h0, *HEIGHT_STARTS) if h <= hi[-1]]
        starts = np.vstack([_starts(shape, few, view, h) for h in heights])
        theta, cost = levenberg_marquardt(_single(shape, few, view), starts, lo, hi)
        start = Solid(shape, theta[int(cost.argmin())], np.zeros((0, 0)), 0.0, 0, np.zeros(0))
        solid = refit(start, floor, view)
        if (s := score(solid)) < best_score:
            best, best_score = solid, s
    return best


def refit(
    solid: Solid,
    floor: FloorOutline,
    view: Viewpoint,
    *,
    height: float | None = None,
    iterations: int = ITERATIONS,
) -> Solid:
    """The solid fitted again to an outline from where it was (its shape kept)."""
    lo, hi = _bounds(solid.shape, view, height)
    residuals = _single(solid.shape, floor, view)
    theta = levenberg_marquardt(residuals, solid.theta[None], lo, hi, iterations=iterations)
    theta = theta[0][0]
    walls = _near_side(floor, view, np.full(len(floor.points), theta[-1]))
    fit = _covariance(residuals, theta, walls)
    return Solid(solid.shape, theta, fit.cov, fit.rms, len(floor.points), fit.shift, fit.off_share)


def held_height(
    solid: Solid, floor: FloorOutline, view: Viewpoint, height: float, sigma: float
) -> Solid:
    """A solid whose height the outline does not pin (thin walls near the camera's
    foot: its footprint slides toward the foot as its height grows), ``sigma`` its
    height's uncertainty (1σ, cm), fitted again with its height held at ``height`` (the
    configured one) where that is within :data:`HELD_SIGMAS` σ of the fitted one (the
    outline does not rule it out), else the solid as it was. The held fit keeps the free
    fit's edge shift, and its covariance widened by the step from it
    (:func:`held_covariance`): its height is no better known for being held."""
    if not abs(float(solid.theta[-1]) - height) <= HELD_SIGMAS * sigma:
        return solid
    start = solid.theta.copy()
    start[-1] = height
    held = refit(solid._replace(theta=start), floor, view, height=height)
    return held._replace(covariance=held_covariance(solid, held.theta), edge_shift=solid.edge_shift)


def held_covariance(free: Solid, theta: FloatArray) -> FloatArray:
    """The covariance of a solution ``theta`` held away from a free fit along the
    ambiguity (its height held where the outline does not pin it): the free fit's
    covariance plus the outer product of the step between them — the expected squared
    error about the held solution if the truth lies about the free fit as its covariance
    says (a footprint held at the configured height near the camera's nadir is off along
    the line of sight by as much as that height is)."""
    step = theta - free.theta
    return free.covariance + np.outer(step, step)


def robot_misfit(
    floor: FloorOutline, view: Viewpoint, size: tuple[float, float], height: float
) -> float:
    """How far (rms px) an outline is from the silhouette of a box of ``size`` (length,
    width) and ``height`` standing where it fits best (its footprint centre and yaw
    fitted from a few yaws, its size and height held): which of a frame's blobs is most
    like the configured robot, before any of them is fitted."""
    every = max(1, len(floor.points) // SEARCH_POINTS)
    few = floor.take(slice(None, None, every))
    centre = _hull(few.points).mean(0)
    yaws = np.arange(4) * 0.25 * math.pi
    starts = np.column_stack(
        [
            np.full((4, 2), centre),
            np.full(4, size[0]),
            np.full(4, size[1]),
            yaws,
            np.full(4, height),
        ]
    )
    lo, hi = starts[0].copy(), starts[0].copy()
    lo[[0, 1, 4]], hi[[0, 1, 4]] = -np.inf, np.inf
    residuals = _single("box", few, view)
    theta, _ = levenberg_marquardt(residuals, starts, lo, hi, iterations=SELECT_ITERATIONS)
    r = residuals(theta)
    return float(np.sqrt((r * r).mean(1)).min())


def _union(
    shapes: Sequence[str], floor: FloorOutline, view: Viewpoint
) -> tuple[Residuals, NDArray[np.int64]]:
    cuts = np.cumsum([0] + [parameter_count(s) for s in shapes])

    def residuals(theta: FloatArray) -> FloatArray:
        d = None
        for k, shape in enumerate(shapes):
            dk = signed_distance(shape, theta[..., cuts[k] : cuts[k + 1]], floor.points, view)
            d = dk if d is None else np.minimum(d, dk)
        assert d is not None
        return floor.px_per_cm * d

    return residuals, cuts


def fit_union(
    pieces: Sequence[Solid],
    floor: FloorOutline,
    view: Viewpoint,
    *,
    height: float | None = None,
) -> list[Solid]:
    """Several solids fitted together to one outline, from each piece's own fit: each
    point's residual is its distance to the union of their silhouettes."""
    return refit_with_tops(pieces, floor, [None] * len(pieces), view, height=height)


def _total_cost(solids: Sequence[Solid], floor: FloorOutline, view: Viewpoint) -> float:
    """Soft-L1 cost of an outline against the union of solids, plus their price."""
    residuals, _ = _union([s.shape for s in solids], floor, view)
    theta = np.concatenate([s.theta for s in solids])
    return float(_cost(residuals(theta[None]))[0]) + sum(_price(s.shape) for s in solids)


def fit_blob(
    floor: FloorOutline,
    pieces: Sequence[NDArray[np.int64]],
    view: Viewpoint,
    shapes: Sequence[str] = SHAPES,
    *,
    height: float | None = None,
) -> list[Solid]:
    """The solids of one blob. One solid fitted to the whole outline; when the outline
    was cut into ``pieces`` (index arrays into ``floor``), one solid per piece fitted
    together (:func:`fit_union`), then two pieces merged into one solid while that
    explains the outline at less cost (a cut at a dent of one solid, between its top
    face and its walls, is undone), then a solid dropped while the others do without it
    (:func:`_without_redundant`); whichever of these costs least (residuals plus a price
    per parameter). One solid that still does not explain its outline may be two
    in line with the camera (:func:`_split_along_sight`)."""
    whole = fit_piece(floor, view, shapes, height=height)
    best = _cut_pieces(whole, floor, pieces, view, shapes, height)
    if len(best) == 1 and not best[0].explains:
        return _split_along_sight(best[0], floor, view, shapes, height)
    return best


def _cut_pieces(
    whole: Solid,
    floor: FloorOutline,
    pieces: Sequence[NDArray[np.int64]],
    view: Viewpoint,
    shapes: Sequence[str],
    height: float | None,
) -> list[Solid]:
    """:func:`fit_blob`'s choice between ``whole`` and the solids of the pieces."""
    parts = [p for p in pieces if len(p) >= MIN_PIECE_POINTS]
    if len(parts) < 2:
        return [whole]
    alone = [fit_piece(floor.take(p), view, shapes, height=height) for p in parts]
    best = fit_union(alone, floor, view, height=height)
    best_cost = _total_cost(best, floor, view)
    while len(parts) > 2:
        trials = []
        for i in range(len(parts)):
            for j in range(i + 1, len(parts)):
                merged = np.concatenate([parts[i], parts[j]])
                one = fit_piece(floor.take(merged), view, shapes, height=height)
                rest = [s for k, s in enumerate(best) if k not in (i, j)]
                solids = fit_union([*rest, one], floor, view, height=height)
                keep = [p for k, p in enumerate(parts) if k not in (i, j)]
                trials.append((_total_cost(solids, floor, view), solids, [*keep, merged]))
        cost, solids, merged_parts = min(trials, key=lambda t: t[0])
        if cost >= best_cost:
            break
        best, best_cost, parts = solids, cost, merged_parts
    best, best_cost = _without_redundant(best, best_cost, floor, view, height)
    return best if best_cost < _total_cost([whole], floor, view) else [whole]


def _without_redundant(
    solids: list[Solid],
    cost: float,
    floor: FloorOutline,
    view: Viewpoint,
    height: float | None,
) -> tuple[list[Solid], float]:
    """A union's solids (of total cost ``cost``) less those it does not need: one at a
    time, the solid without which the others, fitted again together, explain the
    outline at the least cost (residuals plus a price per parameter) is dropped while
    that cost is less and no more of the outline's points are left unexplained
    (:data:`OFF_PX`). A union fitted from pieces that each hold parts of two solids
    (a near tall solid's top seen over a far one's) can settle where one solid of its
    own, low and wide, covers what the others placed right would: a solid too many."""
    while len(solids) > 1:
        trials = []
        for k in range(len(solids)):
            others = [s for j, s in enumerate(solids) if j != k]
            rest = fit_union(others, floor, view, height=height)
            if rest[0].off_share <= solids[0].off_share:
                trials.append((_total_cost(rest, floor, view), rest))
        if not trials:
            break
        least, rest = min(trials, key=lambda t: t[0])
        if least >= cost:
            break
        solids, cost = rest, least
    return solids, cost


def _split_along_sight(
    whole: Solid,
    floor: FloorOutline,
    view: Viewpoint,
    shapes: Sequence[str],
    height: float | None,
) -> list[Solid]:
    """Two solids one behind the other in line with the camera, where one solid does not
    explain the outline (:attr:`Solid.explains`): the near one's top hides the far one's
    foot and their sides run on in line, so the outline turns inward little or not at
    all (no cut by :func:`~ovis.common.vision.outline.split_outline`) and one long solid
    is fitted to both. The outline is cut across the line of sight (by distance from the
    camera's foot) at :data:`SIGHT_CUTS` of its extent, the near and far pieces fitted
    alone and then together; the first cut whose two solids explain the outline at less
    cost than ``whole`` (residuals plus a price per parameter), their footprints apart, is
    kept, else ``whole``."""
    rel = floor.points - view.foot
    rho = np.hypot(rel[:, 0], rel[:, 1])
    lo, hi = float(rho.min()), float(rho.max())
    whole_cost = _total_cost([whole], floor, view)
    for share in SIGHT_CUTS:
        at = lo + share * (hi - lo)
        beside = np.abs(rho - at) * floor.px_per_cm < SIGHT_GAP_PX
        near = np.flatnonzero((rho < at) & ~beside)
        far = np.flatnonzero((rho > at) & ~beside)
        if min(len(near), len(far)) < MIN_PIECE_POINTS:
            continue
        alone = [fit_piece(floor.take(p), view, shapes, height=height) for p in (near, far)]
        solids = fit_union(alone, floor, view, height=height)
        if (
            solids[0].explains
            and not _footprints_overlap(solids)
            and _total_cost(solids, floor, view) < whole_cost
        ):
            return solids
    return [whole]


def feet_hidden(solids: Sequence[Solid], view: Viewpoint) -> list[bool]:
    """Per solid, whether its walls' foot (its footprint's edges facing the camera's
    foot) lies mostly (:data:`FOOT_HIDDEN_SHARE`) inside the other solids' silhouettes:
    behind another solid, where the outline shows little or nothing of where it stands
    and a fit to its top edges may slide it along the line of sight (onto the other)."""
    out = []
    for k, s in enumerate(solids):
        others = [o for j, o in enumerate(solids) if j != k]
        poly = footprint_polygon(s.shape, s.theta)
        ahead = np.roll(poly, -1, axis=0)
        e = ahead - poly
        f = view.foot
        near = e[:, 1] * (f[0] - poly[:, 0]) - e[:, 0] * (f[1] - poly[:, 1]) > 0
        along = np.array([0.25, 0.75])[:, None, None]
        pts = (poly[near] + along * e[near]).reshape(-1, 2)
        if not others or not len(pts):
            out.append(False)
            continue
        inside = np.min([signed_distance(o.shape, o.theta, pts, view) for o in others], axis=0)
        out.append(bool(np.mean(inside < 0.0) >= FOOT_HIDDEN_SHARE))
    return out


def _sizes(shape: str) -> list[int]:
    """Where a shape's parameter vector holds its footprint's sizes (cm)."""
    return [2, 3] if shape == "box" else [2]


def along_sight(solid: Solid, heights: FloatArray, view: Viewpoint) -> FloatArray:
    """The parameter vectors (B, P) of the solids one camera cannot tell from ``solid``
    by its top face, at ``heights`` (B,): the top face seen where it is, the footprint
    (centre and size) scaled about the camera's foot by ``(H − h) / (H − h₀)``. Their
    silhouettes differ only at the foot (module :mod:`~ovis.common.solids.silhouette`)."""
    h = np.asarray(heights, dtype=np.float64)
    q = (view.height_cm - h) / (view.height_cm - float(solid.theta[-1]))
    theta = np.repeat(solid.theta[None], h.size, axis=0)
    theta[:, 0:2] = view.foot + q[:, None] * (solid.theta[0:2] - view.foot)
    theta[:, _sizes(solid.shape)] *= q[:, None]
    theta[:, -1] = h
    return theta


def _behind_ok(
    solid: Solid,
    others: Sequence[Solid],
    heights: FloatArray,
    view: Viewpoint,
    tol_cm: float,
) -> NDArray[np.bool_]:
    """Per height (:func:`along_sight`), whether ``solid`` could stand there unseen at the
    foot: its footprint's edges facing the camera's foot inside the others' silhouettes
    (within ``tol_cm``: so not in front of them, where their silhouettes do not reach),
    and its footprint clear of theirs."""
    thetas = along_sight(solid, heights, view)
    poly = footprint_polygon(solid.shape, thetas)  # (B, k, 2)
    e = np.roll(poly[0], -1, axis=0) - poly[0]
    mid = poly[0] + 0.5 * e
    normal = np.column_stack([e[:, 1], -e[:, 0]]) / np.maximum(np.hypot(*e.T), 1e-12)[:, None]
    to_foot = view.foot - mid
    facing = (normal * to_foot).sum(1) > FACING_COS * np.hypot(*to_foot.T)
    along = np.linspace(0.1, 0.9, 5)[:, None, None]
    ahead = np.roll(poly, -1, axis=1)
    pts = poly[:, facing] + along[:, None] * (ahead[:, facing] - poly[:, facing])[None]
    flat = pts.transpose(1, 0, 2, 3).reshape(-1, 2)  # (B · 5 · m, 2)
    inside = np.min([signed_distance(o.shape, o.theta, flat, view) for o in others], axis=0)
    hidden = (inside.reshape(len(heights), -1) < tol_cm).all(1) if facing.any() else False
    theirs = [footprint_polygon(o.shape, o.theta).astype(np.float32) for o in others]
    clear = np.array(
        [
            all(cv2.intersectConvexConvex(p.astype(np.float32), t)[0] <= 0.0 for t in theirs)
            for p in poly
        ]
    )
    return np.asarray(hidden & clear, dtype=bool)


def bound_behind(
    solids: Sequence[Solid], k: int, floor: FloorOutline, view: Viewpoint
) -> Solid | None:
    """Solid ``k`` of a blob, whose walls' foot is hidden behind the others
    (:func:`feet_hidden`), placed where the frame allows it to stand; None where nothing
    does, or where its fit has no finite covariance. Its top face is seen, and the
    solids that show that top face (:func:`along_sight`: lower and farther, or taller and
    nearer) differ only at the foot, so the outline leaves its height free. The others
    bound it: its footprint is clear of theirs, and its foot, where it faces the camera,
    lies within their silhouettes (within :data:`OFF_PX` of them: a foot farther out
    would show in the outline; nearer the camera than they stand, they do not hide it).
    It is placed halfway between the lowest and the tallest height allowed (and so
    halfway in distance), its covariance the fit's with the height held (conditioned
    on it) plus a uniform spread over those bounds along the line of sight; that
    spread also counts as its edge shift (bounds are no better known for being fitted
    again)."""
    solid, others = solids[k], [s for j, s in enumerate(solids) if j != k]
    lo, hi = _bounds(solid.shape, view)
    heights = np.arange(float(lo[-1]), float(hi[-1]), BOUND_STEP_CM)
    tol = OFF_PX / float(np.median(floor.px_per_cm))
    ok = _behind_ok(solid, others, heights, view, tol)
    if not ok.any():
        return None
    allowed = np.flatnonzero(ok)  # where several stretches allow it: first to last
    first, last = int(allowed[0]), int(allowed[-1])

    def edge(inner: int, outer: int) -> float:
        """The bound between an allowed height and one not, by bisection."""
        if not 0 <= outer < len(heights):
            return float(heights[inner])
        a, b = float(heights[inner]), float(heights[outer])
        while abs(b - a) > BOUND_TOL_CM:
            m = 0.5 * (a + b)
            a, b = (m, b) if _behind_ok(solid, others, np.array([m]), view, tol)[0] else (a, m)
        return a

    h_lo, h_hi = edge(first, first - 1), edge(last, last + 1)
    h_mid = 0.5 * (h_lo + h_hi)
    theta = along_sight(solid, np.array([h_mid]), view)[0]
    span = view.height_cm - h_mid
    tangent = np.zeros(theta.size)  # d theta / dh along the family
    tangent[0:2] = -(theta[0:2] - view.foot) / span
    tangent[_sizes(solid.shape)] = -theta[_sizes(solid.shape)] / span
    tangent[-1] = 1.0
    spread = max(h_hi - h_lo, BOUND_TOL_CM) / math.sqrt(12.0)
    cov, shift = solid.covariance, solid.edge_shift
    if not (np.isfinite(cov).all() and np.isfinite(shift).all() and cov[-1, -1] > 0):
        return None
    held = cov - np.outer(cov[:, -1], cov[-1, :]) / cov[-1, -1]
    shift = shift - shift[-1] * tangent
    return solid._replace(
        theta=theta,
        covariance=held + spread * spread * np.outer(tangent, tangent),
        edge_shift=shift + spread * tangent,
    )


def height_spread(view: Viewpoint) -> float:
    """The σ (cm) of a height known only to lie within the range a fit allows
    (uniform over it)."""
    lo, hi = _bounds("cylinder", view)
    return float(hi[-1] - lo[-1]) / math.sqrt(12.0)


def unplaced_covariance(solid: Solid, view: Viewpoint) -> FloatArray:
    """A covariance for a solid whose fit has none that is finite (a wrong shape fitted
    to the part of a solid that another hides, where the outline pins it nowhere): its
    footprint's centre anywhere on the footprint fitted (the polygon's second moments:
    uniform over it), its height anywhere within the range (:func:`height_spread`),
    each size as uncertain as it is large, its yaw unknown; no correlations. What it
    says is how little the frame tells, not a fit's precision."""
    poly = footprint_polygon(solid.shape, solid.theta).astype(np.float32)
    m = cv2.moments(poly)  # signed by the corners' turn: so are the central moments
    area = m["m00"] if abs(m["m00"]) > 1e-9 else 1e-9
    cov = np.zeros((solid.theta.size, solid.theta.size))
    cov[0, 0], cov[1, 1] = m["mu20"] / area, m["mu02"] / area
    cov[0, 1] = cov[1, 0] = m["mu11"] / area
    for k in _sizes(solid.shape):
        cov[k, k] = float(solid.theta[k]) ** 2
    if solid.theta.size > len(_sizes(solid.shape)) + 3:  # a yaw: any
        cov[-2, -2] = math.pi**2 / 3.0
    cov[-1, -1] = height_spread(view) ** 2
    return cov


def _footprints_overlap(solids: Sequence[Solid]) -> bool:
    """Whether two solids' footprints overlap (no two solids stand in one place)."""
    polygons = [footprint_polygon(s.shape, s.theta).astype(np.float32) for s in solids]
    return any(
        cv2.intersectConvexConvex(polygons[i], polygons[j])[0] > 0.0
        for i in range(len(polygons))
        for j in range(i + 1, len(polygons))
    )


def union_offsets(solids: Sequence[Solid], floor: FloorOutline, view: Viewpoint) -> FloatArray:
    """How far out (px) an outline lies from each solid's silhouette, over the points
    nearest it (median): a rougher outline than the fit's (the threshold's pixel chain)
    is offset from the fitted edge, the same way from frame to frame."""
    d = np.stack(
        [floor.px_per_cm * signed_distance(s.shape, s.theta, floor.points, view) for s in solids]
    )
    nearest = np.abs(d).argmin(0)
    return np.array(
        [
            float(np.median(d[k, nearest == k])) if (nearest == k).any() else 0.0
            for k in range(len(solids))
        ]
    )


#: :func:`follow_union`'s difference step (cm) for a cylinder's centre, and its moves:
#: where it is, moved in x, moved in y.
_FOLLOW_STEP = 1e-3
_FOLLOW_MOVES = ((0.0, 0.0), (_FOLLOW_STEP, 0.0), (0.0, _FOLLOW_STEP))


def follow_union(
    solids: Sequence[Solid],
    offsets: FloatArray,
    floor: FloorOutline,
    view: Viewpoint,
    turning: Sequence[bool] | None = None,
) -> list[FloatArray]:
    """The parameter vectors that put the union of ``solids`` (shapes, sizes and heights
    kept) on an outline, each solid's edge ``offsets`` px further out
    (:func:`union_offsets`): their centres moved and the polygons ``turning`` says
    (None: every one) turned (a robot turns as it drives), one Gauss–Newton step from
    where they are (they moved little since the last frame). A point's residual is its
    distance to the nearest solid's silhouette, so it moves with that solid only: the
    Jacobian is each point's nearest solid's derivatives (a polygon's in closed form,
    :func:`~ovis.common.solids.silhouette.signed_distance_jacobian`; a cylinder's by
    differences)."""
    k, n = len(solids), len(floor.points)
    turns = [True] * k if turning is None else turning
    q1 = np.ones((n, 3))  # the outline's points as (x, y, 1)
    q1[:, :2] = floor.points
    here: list[FloatArray] = [np.empty(0)] * k  # each solid's residuals (px)
    slopes: list[FloatArray] = [np.empty(0)] * k  # their derivatives (px per cm, per rad)
    free: list[bool] = [False] * k  # whether a solid turns
    cylinders = [j for j, s in enumerate(solids) if s.shape == "cylinder"]
    for j, s in enumerate(solids):
        if s.shape != "cylinder":
            free[j] = turns[j]
            d, jac = signed_distance_jacobian(s.shape, s.theta.tolist(), q1, view, free[j])
            here[j] = d * floor.px_per_cm - offsets[j]
            slopes[j] = jac * floor.px_per_cm
    if cylinders:  # every cylinder's rows at once, each moved a step in x and in y
        rows = []
        for j in cylinders:
            theta = solids[j].theta.tolist()
            rows += [[theta[0] + mx, theta[1] + my, *theta[2:]] for mx, my in _FOLLOW_MOVES]
        d = signed_distance_few("cylinder", rows, q1, view)
        d *= floor.px_per_cm
        for c, j in enumerate(cylinders):
            own = d[3 * c : 3 * c + 3] - offsets[j]
            here[j] = own[0]
            slopes[j] = (own[1:] - own[0]) / _FOLLOW_STEP
    if k == 1:
        r, jac = here[0], slopes[0]
    else:  # each point moves with the solid nearest it
        stacked = np.stack(here)
        nearest = stacked.argmin(0)
        r = stacked[nearest, np.arange(n)]
        jac = np.vstack([np.where(nearest == j, slopes[j], 0.0) for j in range(k)])
    weight = 1.0 / np.sqrt(1.0 + (r / LOSS_PX) ** 2)
    p = len(jac)
    normal = ((jac * weight) @ np.vstack([jac, r]).T).tolist()  # JᵀWJ (p, p) beside JᵀWr
    for i in range(p):
        normal[i][i] += 1e-9
    step = solve_small(normal)
    out = [s.theta.copy() for s in solids]
    if step is None:
        return out
    at = 0
    for j, s in enumerate(solids):
        out[j][0:2] -= step[at : at + 2]
        if free[j]:
            out[j][yaw_index(s.shape)] -= step[at + 2]
        at += 3 if free[j] else 2
    return out


def follow_union_steps(
    solids: Sequence[Solid],
    offsets: FloatArray,
    floor: FloorOutline,
    view: Viewpoint,
    steps: int,
    tol_cm: float,
    turning: Sequence[bool] | None = None,
) -> list[Solid]:
    """:func:`follow_union` repeated from where each step puts the solids, at most
    ``steps`` times, until a step moves no centre more than ``tol_cm``."""
    now = list(solids)
    for _ in range(steps):
        moved = follow_union(now, offsets, floor, view, turning)
        shift = max(
            float(np.abs(m[0:2] - s.theta[0:2]).max()) for m, s in zip(moved, now, strict=True)
        )
        now = [s._replace(theta=m) for s, m in zip(now, moved, strict=True)]
        if shift <= tol_cm:
            break
    return now


def solve_small(rows: list[list[float]]) -> FloatArray | None:
    """x with A·x = b, from the rows of [A | b] (a few unknowns), by Gaussian elimination
    with partial pivoting in plain Python (for four unknowns a LAPACK call costs more
    than the arithmetic); None where A is singular. ``rows`` are overwritten."""
    n = len(rows)
    for c in range(n):
        best = max(range(c, n), key=lambda i: abs(rows[i][c]))
        if rows[best][c] == 0.0:
            return None
        rows[c], rows[best] = rows[best], rows[c]
        top = rows[c]
        for i in range(c + 1, n):
            f = rows[i][c] / top[c]
            row = rows[i]
            for j in range(c, n + 1):
                row[j] -= f * top[j]
    x = [0.0] * n
    for i in reversed(range(n)):
        row = rows[i]
        x[i] = (row[n] - sum(row[j] * x[j] for j in range(i + 1, n))) / row[i]
    return np.array(x)


def _with_tops(
    shapes: Sequence[str],
    floor: FloorOutline,
    tops: Sequence[FloorOutline | None],
    view: Viewpoint,
) -> tuple[Residuals, NDArray[np.int64]]:
    """Residuals (px) of an outline against the union of silhouettes, then of each
    solid's top-edge points against its top face's outline."""
    union, cuts = _union(shapes, floor, view)

    def residuals(theta: FloatArray) -> FloatArray:
        parts = [union(theta)]
        for k, (shape, top) in enumerate(zip(shapes, tops, strict=True)):
            if top is not None and len(top.points):
                t = theta[..., cuts[k] : cuts[k + 1]]
                parts.append(top.px_per_cm * top_distance(shape, t, top.points, view))
        return np.concatenate(parts, axis=-1)

    return residuals, cuts


def _junctions(
    shapes: Sequence[str],
    theta: FloatArray,
    cuts: NDArray[np.int64],
    floor: FloorOutline,
    view: Viewpoint,
) -> NDArray[np.bool_]:
    """The outline's points within :data:`JUNCTION_PX` of two of the solids'
    silhouettes: where one solid's silhouette meets another's (a concave corner the blur
    rounds) or runs along it (one solid behind another in line with the camera), a point
    does not tell which solid's edge it is. Such points are no evidence of where either
    stands: a solid whose walls' foot is hidden behind another is pinned by nothing else
    along the line of sight (its top seen, its height free), and these points alone would
    say its height is measured (the fit slides its foot to the edge of what hides it)."""
    near = [
        np.abs(
            floor.px_per_cm * signed_distance(s, theta[cuts[k] : cuts[k + 1]], floor.points, view)
        )
        < JUNCTION_PX
        for k, s in enumerate(shapes)
    ]
    return np.sum(near, axis=0) >= 2


def refit_with_tops(
    solids: Sequence[Solid],
    floor: FloorOutline,
    tops: Sequence[FloorOutline | None],
    view: Viewpoint,
    *,
    height: float | None = None,
    iterations: int = ITERATIONS,
    held: Sequence[bool] | None = None,
) -> list[Solid]:
    """Solids fitted again together to their outline and to the edges of their top
    faces seen inside it (``tops``, per solid: the top face against the walls below it,
    :func:`~ovis.common.solids.silhouette.top_near_edges`): where the silhouette alone
    leaves the height free (a box seen square-on shows four lines for six unknowns;
    thin walls seen from above), the top face's near edge pins it. ``held``: per solid,
    whether it stays as it is (its covariance is still worked out)."""
    shapes = [s.shape for s in solids]
    residuals, cuts = _with_tops(shapes, floor, tops, view)
    bounds = [
        (s.theta, s.theta) if held is not None and held[k] else _bounds(s.shape, view, height)
        for k, s in enumerate(solids)
    ]
    lo = np.concatenate([b[0] for b in bounds])
    hi = np.concatenate([b[1] for b in bounds])
    start = np.concatenate([s.theta for s in solids])[None]
    theta = levenberg_marquardt(residuals, start, lo, hi, iterations=iterations)[0][0]
    evidence = None if len(solids) < 2 else ~_junctions(shapes, theta, cuts, floor, view)
    near = np.abs(
        [
            signed_distance(shape, theta[cuts[k] : cuts[k + 1]], floor.points, view)
            for k, shape in enumerate(shapes)
        ]
    ).argmin(0)  # the solid whose edge each point is
    walls = _near_side(floor, view, theta[cuts[1:] - 1][near])
    fit = _covariance(residuals, theta, walls, evidence)
    n = len(floor.points) + sum(len(t.points) for t in tops if t is not None)
    return [
        Solid(
            shape,
            theta[cuts[k] : cuts[k + 1]],
            fit.cov[cuts[k] : cuts[k + 1], cuts[k] : cuts[k + 1]],
            fit.rms,
            n,
            fit.shift[cuts[k] : cuts[k + 1]],
            fit.off_share,
        )
        for k, shape in enumerate(shapes)
    ]
