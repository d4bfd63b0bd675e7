"""A solid's silhouette on the floor, seen through the camera's centre.

An upright prism of footprint F and height h seen by a camera whose centre C stands
``H`` above the floor at the foot ``f``: the top face, back-projected through C onto the
floor (Z = 0), is F scaled by ``S = H / (H − h)`` about f, and the silhouette, carried
onto the floor the same way, is the convex hull of F and of that scaled copy (a
projection keeps convex hulls; lens distortion is undone by the back-projection of each
pixel). Its near side is the foot of the walls (the footprint's edge), its far side the
top face's far edge: how far the far side reaches is the height.

The hull has a closed form. An edge of F lies on it when the foot is outside that edge's
line (the edge faces the camera's foot), else the same edge of the scaled copy does;
where the two meet, a radial edge (a vertical edge of the prism) joins them. So each
polygon of k corners gives k edges and k radial slots (empty ones collapse onto a hull
corner), the same count for every parameter vector: a batch of silhouettes is a few
array operations. A cylinder's silhouette is the hull of two disks (exact signed
distance, :func:`capsule_distance`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ovis.common.camera.projection import camera_centre_cm, project
from ovis.common.config import CameraModel
from ovis.common.solids.shapes import footprint_polygon, shape_sides

__all__ = [
    "MAX_HEIGHT_SHARE",
    "Viewpoint",
    "capsule_distance",
    "hull_edges",
    "image_axis",
    "image_moments",
    "signed_distance",
    "signed_distance_few",
    "signed_distance_jacobian",
    "top_distance",
    "top_near_edges",
    "top_scale",
]

FloatArray = NDArray[np.float64]

#: Heights are kept below this share of the camera's height (a top at the camera's
#: height would be scaled without bound).
MAX_HEIGHT_SHARE = 0.9


class Viewpoint(NamedTuple):
    """Where the camera's centre stands: its foot on the floor (cm) and its height."""

    foot: FloatArray
    height_cm: float

    @classmethod
    def of(cls, camera: CameraModel) -> Viewpoint:
        x, y, z = camera_centre_cm(camera)
        return cls(np.array([x, y], dtype=np.float64), float(z))


def top_scale(h: FloatArray, view: Viewpoint) -> FloatArray:
    """``S = H / (H − h)``: how much larger the top face's back-projection is."""
    H = view.height_cm
    return H / (H - np.minimum(h, MAX_HEIGHT_SHARE * H))


@functools.lru_cache(maxsize=16)
def _next(k: int, step: int = 1) -> NDArray[np.int64]:
    """Each of k polygon vertices' ``step``-th next index (made once per k: it is asked
    for at every residual evaluation of a fit)."""
    out = (np.arange(k) + step) % k
    out.flags.writeable = False
    return out


def hull_edges(
    footprint: FloatArray, scale: FloatArray, view: Viewpoint
) -> tuple[FloatArray, FloatArray]:
    """The silhouette's boundary as directed edges (start, end), each (..., 2k, 2), going
    counter-clockwise: for footprints (..., k, 2) and top scales (...)."""
    f = view.foot
    k = footprint.shape[-2]
    nxt, prv = _next(k), _next(k, -1)
    top = f + scale[..., None, None] * (footprint - f)
    ahead = footprint[..., nxt, :]
    e = ahead - footprint
    # the foot outside an edge's line (outward normal (ey, −ex)): the edge faces it
    near = e[..., 1] * (f[0] - footprint[..., 0]) - e[..., 0] * (f[1] - footprint[..., 1]) > 0
    n3 = near[..., None]
    start = np.where(n3, footprint, top)
    end = np.where(n3, ahead, top[..., nxt, :])
    prev = near[..., prv][..., None]
    up = prev & ~n3  # near → far: from the footprint's corner up to the top's
    down = ~prev & n3
    r_start = np.where(down, top, footprint)  # no radial edge: a hull corner, twice
    r_start = np.where(up | down | n3, r_start, top)
    r_end = np.where(up, top, np.where(down, footprint, r_start))
    return (
        np.concatenate([start, r_start], axis=-2),
        np.concatenate([end, r_end], axis=-2),
    )


def _segments_distance(q: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    """Signed distance of points q (N, 2) to convex polygons given by their directed
    counter-clockwise edges a → b (..., m, 2), negative inside: the largest signed
    distance to an edge's line (exact inside and beside an edge; beyond a corner, the
    distance to the nearer of its two lines). Result (..., N). The distances are laid
    out edge by edge, (..., m, N): the largest is then taken across whole rows, not
    along each point's few edges (the same numbers, in far fewer steps)."""
    e = b - a
    length = np.sqrt((e * e).sum(-1))
    real = length > 1e-12
    nx = np.where(real, e[..., 1] / np.where(real, length, 1.0), 0.0)
    ny = np.where(real, -e[..., 0] / np.where(real, length, 1.0), 0.0)
    c = nx * a[..., 0] + ny * a[..., 1]
    c = np.where(real, c, np.inf)  # an empty edge never counts
    d = q[:, 0] * nx[..., None] + q[:, 1] * ny[..., None] - c[..., None]
    return d.max(-2)


def capsule_distance(
    q: FloatArray, c1: FloatArray, r1: FloatArray, c2: FloatArray, r2: FloatArray
) -> FloatArray:
    """Signed distance of points q (N, 2) to the hulls of two disks (c1, r1), (c2, r2),
    batched over (...,): the silhouette of a cylinder. Result (..., N)."""
    d = c2 - c1
    length = np.hypot(d[..., 0], d[..., 1])
    safe = np.maximum(length, 1e-12)
    u = d / safe[..., None]
    px = q[:, 0] - c1[..., 0, None]
    py = q[:, 1] - c1[..., 1, None]
    along = px * u[..., 0, None] + py * u[..., 1, None]
    across = np.abs(-px * u[..., 1, None] + py * u[..., 0, None])
    b = np.clip((r1 - r2) / safe, -1.0, 1.0)[..., None]
    a = np.sqrt(1.0 - b * b)
    k = -b * across + a * along
    side = across * a + along * b - r1[..., None]
    near_end = np.hypot(across, along) - r1[..., None]
    far_end = np.hypot(across, along - length[..., None]) - r2[..., None]
    out = np.where(k < 0.0, near_end, np.where(k > a * length[..., None], far_end, side))
    nested = (length <= np.abs(r2 - r1))[..., None]  # one disk holds the other
    if not nested.any():
        return out
    outer_c = np.where((r2 >= r1)[..., None], c2, c1)
    outer_r = np.maximum(r1, r2)[..., None]
    big = np.hypot(q[:, 0] - outer_c[..., 0, None], q[:, 1] - outer_c[..., 1, None]) - outer_r
    return np.where(nested, big, out)


def signed_distance(shape: str, theta: FloatArray, q: FloatArray, view: Viewpoint) -> FloatArray:
    """Signed distance (cm, negative inside) of floor points q (N, 2) to the silhouettes
    of parameter vectors ``theta`` (..., P) of one shape. Result (..., N)."""
    theta = np.asarray(theta, dtype=np.float64)
    scale = top_scale(theta[..., -1], view)
    if shape == "cylinder":
        c1 = theta[..., 0:2]
        c2 = view.foot + scale[..., None] * (c1 - view.foot)
        return capsule_distance(q, c1, theta[..., 2], c2, scale * theta[..., 2])
    a, b = hull_edges(footprint_polygon(shape, theta), scale, view)
    return _segments_distance(q, a, b)


def signed_distance_few(
    shape: str, theta: Sequence[Sequence[float]], q1: FloatArray, view: Viewpoint
) -> FloatArray:
    """:func:`signed_distance` of a few parameter vectors ``theta`` (B, P), plain lists
    of floats (a frame's follow of a blob's solids), at floor points ``q1`` (N, 3)
    given as (x, y, 1). The silhouettes' edges (or a cylinder's axis) are worked out in
    plain Python — the same operations in the same order as :func:`footprint_polygon`,
    :func:`hull_edges`, :func:`_segments_distance` and :func:`capsule_distance`: for a
    few footprints a hundred array calls on a dozen corners cost more than the
    arithmetic —, then each point's distances to their lines in one matrix product
    (these may differ from :func:`signed_distance`'s in a float's last bits). Result
    (B, N)."""
    if shape == "cylinder":
        return _capsules_few(theta, q1, view)
    lines = [[line for line, _ends in _hull_lines(shape, row, view)[1]] for row in theta]
    m = max(len(mine) for mine in lines)  # each silhouette's lines, its first repeated
    table = np.array([mine + mine[:1] * (m - len(mine)) for mine in lines]).reshape(-1, 3)
    return (table @ q1.T).reshape(len(lines), m, -1).max(1)


#: An end of a hull edge: which footprint corner, scaled how far about the camera's foot
#: (1: on the floor; S: the top face's corner carried onto the floor).
_End = tuple[int, float]


def _hull_lines(
    shape: str, row: Sequence[float], view: Viewpoint
) -> tuple[
    list[tuple[float, float]],
    list[tuple[tuple[float, float, float], tuple[_End, _End, float, float, float]]],
]:
    """One polygon silhouette's footprint corners, and the lines (nx, ny, −c) of its hull
    edges (empty edges left out), each with where its ends come from and its start and
    length, (start's corner, end's corner, ax, ay, length): what
    :func:`signed_distance_jacobian` moves."""
    fx, fy = (float(v) for v in view.foot)
    big = view.height_cm
    s = big / (big - min(row[-1], MAX_HEIGHT_SHARE * big))  # top_scale
    foot = _corners(shape, row)
    top = [(fx + s * (x - fx), fy + s * (y - fy)) for x, y in foot]
    k = len(foot)
    near = []
    for i in range(k):
        (x0, y0), (x1, y1) = foot[i], foot[(i + 1) % k]
        near.append((y1 - y0) * (fx - x0) - (x1 - x0) * (fy - y0) > 0)
    ends: list[tuple[_End, _End]] = [
        ((i, 1.0), ((i + 1) % k, 1.0)) if near[i] else ((i, s), ((i + 1) % k, s)) for i in range(k)
    ]
    for i in range(k):  # the radial edges: near → far (up) or far → near (down)
        if near[i - 1] and not near[i]:
            ends.append(((i, 1.0), (i, s)))
        elif near[i] and not near[i - 1]:
            ends.append(((i, s), (i, 1.0)))
    out = []
    for a, b in ends:
        ax, ay = foot[a[0]] if a[1] == 1.0 else top[a[0]]
        bx, by = foot[b[0]] if b[1] == 1.0 else top[b[0]]
        ex, ey = bx - ax, by - ay
        length = math.sqrt(ex * ex + ey * ey)
        if length > 1e-12:  # an empty edge never counts
            nx, ny = ey / length, -ex / length
            out.append(((nx, ny, -(nx * ax + ny * ay)), (a, b, ax, ay, length)))
    return foot, out


def signed_distance_jacobian(
    shape: str, row: Sequence[float], q1: FloatArray, view: Viewpoint, turn: bool
) -> tuple[FloatArray, FloatArray]:
    """A polygon silhouette's :func:`signed_distance_few` at floor points ``q1`` (N, 3)
    as (x, y, 1), and its derivatives by the footprint's centre x, y (and yaw, where
    ``turn``), (2 or 3, N), sizes and height held. A point's distance is to the hull
    line it lies furthest out of, n·(q − A) for the edge from A to B; moving the ends
    by ∂A, ∂B moves it by −[(1 − u)·n·∂A + u·n·∂B], u the point's place along the edge
    (0 at A, 1 at B). A footprint corner P moves by ∂P (x: (1, 0); y: (0, 1); yaw:
    P − centre turned a right angle), its top corner by S·∂P."""
    foot, hull = _hull_lines(shape, row, view)
    x, y = row[0], row[1]
    table = []  # per line: its own row, then each parameter's (linear in q as well)
    for line, ((ia, sa), (ib, sb), ax, ay, length) in hull:
        nx, ny = line[0], line[1]
        w = 1.0 / length
        ux, uy = -ny * w, nx * w  # u = (ux, uy)·q + uc: the edge's direction over its length
        uc = -(ux * ax + uy * ay)
        (pax, pay), (pbx, pby) = foot[ia], foot[ib]
        ends = [(sa * nx, sb * nx), (sa * ny, sb * ny)]  # (n·∂A, n·∂B) by x, by y
        if turn:  # n·(P − centre turned a right angle), scaled like the corner
            ends.append(
                (sa * (nx * (y - pay) + ny * (pax - x)), sb * (nx * (y - pby) + ny * (pbx - x)))
            )
        table.append(line)
        for a, b in ends:  # −[a + (b − a)·u]
            g = a - b
            table.append((g * ux, g * uy, g * uc - a))
    rows = len(table) // len(hull)
    out = (np.array(table) @ q1.T).reshape(len(hull), rows, -1)  # (lines, 1 + p, N)
    picked = out[out[:, 0].argmax(0), :, np.arange(out.shape[2])].T  # each point's line
    return picked[0], picked[1:]


def _capsules_few(theta: Sequence[Sequence[float]], q1: FloatArray, view: Viewpoint) -> FloatArray:
    """:func:`signed_distance_few` of cylinders (:func:`capsule_distance`; the axes'
    lengths by ``np.hypot``, which ``math.hypot`` may differ from in the last bit)."""
    fx, fy = (float(v) for v in view.foot)
    big = view.height_cm
    rows = []
    for x, y, r, h in theta:
        s = big / (big - min(h, MAX_HEIGHT_SHARE * big))  # top_scale
        r2 = s * r
        rows.append((x, y, r, r2, fx + s * (x - fx) - x, fy + s * (y - fy) - y))
    length = np.hypot([row[4] for row in rows], [row[5] for row in rows]).tolist()
    axes, cols = [], []
    for (x, y, r1, r2, dx, dy), ell in zip(rows, length, strict=True):
        if ell <= abs(r2 - r1):  # one disk holds the other: rare, left to the general case
            return signed_distance("cylinder", np.array(theta), q1[:, :2], view)
        safe = max(ell, 1e-12)
        ux, uy = dx / safe, dy / safe
        b = min(max((r1 - r2) / safe, -1.0), 1.0)
        a = math.sqrt(1.0 - b * b)
        axes.append((ux, uy, -(x * ux + y * uy)))  # along the axis from the near disk
        axes.append((-uy, ux, x * uy - y * ux))  # across it
        cols.append((b, -b, a, r1, r2, ell, a * ell))
    along, across = (np.array(axes) @ q1.T).reshape(-1, 2, len(q1)).transpose(1, 0, 2)
    across = np.abs(across)
    c = np.array(cols).T[:, :, None]  # each (B, 1)
    k = c[1] * across + c[2] * along
    side = across * c[2] + along * c[0] - c[3]
    near_end = np.hypot(across, along) - c[3]
    far_end = np.hypot(across, along - c[5]) - c[4]
    return np.where(k < 0.0, near_end, np.where(k > c[6], far_end, side))


def _corners(shape: str, theta: Sequence[float]) -> list[tuple[float, float]]:
    """:func:`~ovis.common.solids.shapes.footprint_polygon` of one parameter vector of a
    polygon shape, in plain Python (the same operations in the same order)."""
    x, y = theta[0], theta[1]
    if shape == "box":
        hl, hw, yaw = 0.5 * theta[2], 0.5 * theta[3], theta[4]
        cu, su = math.cos(yaw), math.sin(yaw)
        return [
            (x + a * (hl * cu) + b * (hw * -su), y + a * (hl * su) + b * (hw * cu))
            for a, b in _BOX_SIGNS
        ]
    n = shape_sides(shape)
    r, yaw = theta[2], theta[3]
    turns = [yaw + 2.0 * math.pi * j / n for j in range(n)]
    return [(x + math.cos(t) * r, y + math.sin(t) * r) for t in turns]


_BOX_SIGNS = ((1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0))


def top_distance(shape: str, theta: FloatArray, q: FloatArray, view: Viewpoint) -> FloatArray:
    """Signed distance (cm) of floor points q (N, 2) to the top faces' outlines carried
    onto the floor (the footprint scaled by S about the camera's foot), batched over
    ``theta`` (..., P). Result (..., N)."""
    theta = np.asarray(theta, dtype=np.float64)
    scale = top_scale(theta[..., -1], view)
    if shape == "cylinder":
        c = view.foot + scale[..., None] * (theta[..., 0:2] - view.foot)
        r = scale * theta[..., 2]
        return np.hypot(q[:, 0] - c[..., 0, None], q[:, 1] - c[..., 1, None]) - r[..., None]
    top = view.foot + scale[..., None, None] * (footprint_polygon(shape, theta) - view.foot)
    ahead = top[..., _next(top.shape[-2]), :]
    return _segments_distance(q, top, ahead)


def top_near_edges(
    shape: str,
    theta: FloatArray,
    view: Viewpoint,
    camera: CameraModel,
    spacing_px: float = 1.0,
    min_wall_px: float = 0.0,
) -> tuple[FloatArray, FloatArray]:
    """Points (n, 2) (col, row) on the top face's edges that face the camera's foot (its
    edges inside the silhouette, against the walls below them), every ``spacing_px`` in
    the frame, and their image normals pointing away from the top face; only where the
    wall below is at least ``min_wall_px`` tall in the frame (else the top's edge and
    the wall's foot are one blurred edge)."""
    theta = np.asarray(theta, dtype=np.float64)
    h = float(theta[-1])
    poly = footprint_polygon(shape, theta)
    ahead = poly[_next(len(poly))]
    e = ahead - poly
    f = view.foot
    near = e[:, 1] * (f[0] - poly[:, 0]) - e[:, 0] * (f[1] - poly[:, 1]) > 0
    if not near.any():
        return np.zeros((0, 2)), np.zeros((0, 2))
    a, b = poly[near], ahead[near]
    pa, pb = (
        project(a[:, 0], a[:, 1], np.full(len(a), h), camera),
        project(b[:, 0], b[:, 1], np.full(len(b), h), camera),
    )
    length = np.hypot(pb.col - pa.col, pb.row - pa.row)
    pts, nrm = [], []
    centre = project(theta[0], theta[1], h, camera)
    for k in range(len(a)):
        m = max(int(length[k] / spacing_px), 1)
        s = (np.arange(m) + 0.5) / m
        xy = a[k] + s[:, None] * (b[k] - a[k])
        p = project(xy[:, 0], xy[:, 1], np.full(m, h), camera)
        foot = project(xy[:, 0], xy[:, 1], np.zeros(m), camera)
        tall = np.hypot(p.col - foot.col, p.row - foot.row) >= min_wall_px
        if not tall.any():
            continue
        d = np.array([pb.col[k] - pa.col[k], pb.row[k] - pa.row[k]])
        n = np.array([d[1], -d[0]]) / max(float(np.hypot(*d)), 1e-9)
        away = np.array([np.mean(p.col) - float(centre.col), np.mean(p.row) - float(centre.row)])
        if n @ away < 0:
            n = -n
        pts.append(np.column_stack([p.col, p.row])[tall])
        nrm.append(np.repeat(n[None], int(tall.sum()), axis=0))
    if not pts:
        return np.zeros((0, 2)), np.zeros((0, 2))
    return np.vstack(pts), np.vstack(nrm)


def _image_edges(
    shape: str, theta: FloatArray, view: Viewpoint, camera: CameraModel, steps: int
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, tuple[int, ...]]:
    """Each silhouette's (..., P) hull edges cut into ``steps`` pieces, projected into
    the frame: the pieces' starts and ends (row, col) and the axes that run over them."""
    theta = np.asarray(theta, dtype=np.float64)
    a, b = hull_edges(footprint_polygon(shape, theta), top_scale(theta[..., -1], view), view)
    if steps > 1:
        s = np.arange(steps + 1) / steps
        pts = a[..., None, :] + s[:, None] * (b - a)[..., None, :]  # (..., m, steps+1, 2)
    else:
        pts = np.stack([a, b], axis=-2)
    p = project(pts[..., 0], pts[..., 1], np.zeros(pts.shape[:-1]), camera)
    r, c = p.row, p.col
    axes = tuple(range(-(r.ndim - theta.ndim + 1), 0))
    return r[..., :-1], c[..., :-1], r[..., 1:], c[..., 1:], axes


def image_moments(
    shape: str,
    theta: FloatArray,
    view: Viewpoint,
    camera: CameraModel,
    *,
    steps: int = 1,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Area (px²) and centroid (row, col) of each silhouette (..., P) in the camera's
    frame: its hull edges cut into ``steps`` pieces each and projected (straight lines
    on the floor bend a little under lens distortion), by the shoelace formula."""
    r0, c0, r1, c1, axes = _image_edges(shape, theta, view, camera, steps)
    cross = c0 * r1 - c1 * r0
    area2 = cross.sum(axis=axes)
    row = ((r0 + r1) * cross).sum(axis=axes) / (3.0 * area2)
    col = ((c0 + c1) * cross).sum(axis=axes) / (3.0 * area2)
    return np.abs(0.5 * area2), row, col


def image_axis(
    shape: str, theta: FloatArray, view: Viewpoint, camera: CameraModel
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Centroid (row, col) and major axis (rad, as :func:`~ovis.common.vision.shape.
    orientation` gives a blob's) of each silhouette (..., P) in the camera's frame: the
    polygon's second moments by Green's theorem, about its first corner (fewer digits
    lost than about the frame's origin)."""
    r0, c0, r1, c1, axes = _image_edges(shape, theta, view, camera, 1)
    first = tuple(slice(None) for _ in range(r0.ndim - len(axes))) + (0,) * len(axes)
    ref_r, ref_c = r0[first], c0[first]
    ex = (...,) + (None,) * len(axes)
    r0, r1 = r0 - ref_r[ex], r1 - ref_r[ex]
    c0, c1 = c0 - ref_c[ex], c1 - ref_c[ex]
    cross = c0 * r1 - c1 * r0
    area2 = cross.sum(axis=axes)
    row = ((r0 + r1) * cross).sum(axis=axes) / (3.0 * area2)
    col = ((c0 + c1) * cross).sum(axis=axes) / (3.0 * area2)
    rr = ((r0 * r0 + r0 * r1 + r1 * r1) * cross).sum(axis=axes) / (6.0 * area2) - row * row
    cc = ((c0 * c0 + c0 * c1 + c1 * c1) * cross).sum(axis=axes) / (6.0 * area2) - col * col
    rc = ((c0 * r1 + 2.0 * c0 * r0 + 2.0 * c1 * r1 + c1 * r0) * cross).sum(axis=axes) / (
        12.0 * area2
    ) - row * col
    return row + ref_r, col + ref_c, 0.5 * np.arctan2(2.0 * rc, rr - cc)
