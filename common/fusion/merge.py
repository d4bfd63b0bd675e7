"""The same robot or obstacle seen by several cameras, reported once.

A robot is the same by its marker id. Two obstacle sightings from different cameras are
the same obstacle when their distance lies within ``gate_sigmas`` of the error both
cameras expect there (the larger axis of the summed covariances, plus
``gate_floor_cm``) and their radii agree within ``radius_gate_cm``. The merged position
is the inverse-covariance (information) weighted mean, so the camera that sees a point
more sharply counts more; its covariance is the inverse of the summed information.

Every group of a world frame is merged at once: the 2×2 inverses in closed form, the
sums over each group's members with :func:`numpy.bincount` on the group labels.
"""

from __future__ import annotations

from collections.abc import Sequence

import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.config import FusionConfig
from ovis.common.fusion.sightings import (
    CXX,
    CXY,
    CYY,
    HEADING,
    MARKER,
    R,
    Sighting,
    Sightings,
    X,
    Y,
    Z,
)

__all__ = ["Fused", "Sighting", "Sightings", "fuse"]

FloatArray = NDArray[np.float64]


class Fused(msgspec.Struct, kw_only=True):
    """One object of the world, merged from its sightings (no identity yet)."""

    kind: str
    x_cm: float
    y_cm: float
    z_cm: float
    radius_cm: float
    sigma_cm: float  # square root of the larger axis of the merged covariance
    cameras: list[str]
    marker_id: int | None = None
    heading_deg: float | None = None


def _inverse(a: FloatArray, b: FloatArray, c: FloatArray) -> tuple[FloatArray, ...]:
    """Closed-form inverse of the symmetric 2×2 matrices ``[[a, b], [b, c]]``."""
    det = a * c - b * b
    return c / det, -b / det, a / det


def _largest_eigenvalue(a: FloatArray, b: FloatArray, c: FloatArray) -> FloatArray:
    """Larger eigenvalue of the symmetric 2×2 matrices ``[[a, b], [b, c]]``."""
    return (a + c) / 2 + np.hypot((a - c) / 2, b)


def _merge_groups(d: FloatArray, label: NDArray[np.intp], groups: int,
                  first: NDArray[np.intp]) -> FloatArray:  # fmt: skip
    """Every group at once: ``(groups, 6)`` x, y, z, radius, sigma, heading (NaN: none).

    Per sighting, its information ``Cᵢ⁻¹`` (closed-form 2×2 inverse), ``Cᵢ⁻¹ xᵢ``, the
    weight ``wᵢ = 1 / trace Cᵢ`` (for height, radius and heading) and the heading's unit
    vector; per group their sums (one matrix product with the group indicator); then
    ``P = (Σ Cᵢ⁻¹)⁻¹``, ``x = P Σ Cᵢ⁻¹ xᵢ``, sigma ``√λmax(P)`` and the weighted circular
    mean of the headings. A group of one is reported as its camera saw it."""
    n = len(d)
    a, b, c = d[:, CXX], d[:, CXY], d[:, CYY]
    w = np.empty((n, 11))
    # columns: information (xx, xy, yy), information × position (x, y), weight,
    # weight × (z, radius), weight × heading's (sin, cos), has a heading
    np.divide(d[:, CYY : CXX - 1 : -1], (a * c - b * b)[:, None], out=w[:, 0:3])
    w[:, 1] *= -1.0
    x, y = d[:, X], d[:, Y]
    w[:, 3] = w[:, 0] * x + w[:, 1] * y
    w[:, 4] = w[:, 1] * x + w[:, 2] * y
    weight = np.reciprocal(a + c, out=w[:, 5])
    np.multiply(d[:, Z : R + 1], weight[:, None], out=w[:, 6:8])
    heading = np.radians(d[:, HEADING])
    has = heading == heading
    heading[~has] = 0.0
    w[:, 10] = has
    np.sin(heading, out=w[:, 8])
    np.cos(heading, out=w[:, 9])
    w[:, 8:10] *= (weight * w[:, 10])[:, None]
    member = np.zeros((groups, n))
    member[label, np.arange(n)] = 1.0
    total = member @ w
    sa, sb, sc, sx, sy, sw, _, _, hs, hc, hn = total.T
    det = sa * sc - sb * sb
    pa, pb, pc = sc / det, -sb / det, sa / det
    out = np.empty((groups, 6))
    out[:, 0] = pa * sx + pb * sy
    out[:, 1] = pb * sx + pc * sy
    np.divide(total[:, 6:8], sw[:, None], out=out[:, 2:4])
    out[:, 4] = np.sqrt(_largest_eigenvalue(pa, pb, pc))
    out[:, 5] = np.where(hn > 0, np.degrees(np.arctan2(hs, hc)), np.nan)
    one = np.flatnonzero(member.sum(axis=1) == 1)
    if len(one):
        own = d[first[one]]
        out[one, :4] = own[:, X : R + 1]
        out[one, 5] = own[:, HEADING]
    return out


def _fused(s: Sightings, rows: NDArray[np.intp], label: list[int], first: list[int]) -> list[Fused]:
    """The groups of the sightings ``s.data[rows]`` (group ``label`` each; ``first``:
    each group's first member) merged, as :class:`Fused`."""
    merged = _merge_groups(s.data[rows], np.array(label, np.intp), len(first),
                           np.array(first, np.intp))  # fmt: skip
    names: list[list[str]] = [[] for _ in first]
    for g, c in zip(label, s.cam[rows].tolist(), strict=True):
        names[g].append(s.cameras[c])
    lead = rows[first]
    robot, marker = s.robot[lead].tolist(), s.data[lead, MARKER].tolist()
    return [
        Fused(kind="robot" if rb else "obstacle", x_cm=x, y_cm=y, z_cm=z, radius_cm=r,
              sigma_cm=sg, cameras=sorted(cams), marker_id=None if mk != mk else int(mk),
              heading_deg=None if h != h else h)
        for rb, mk, (x, y, z, r, sg, h), cams in zip(robot, marker, merged.tolist(), names,
                                                     strict=True)
    ]  # fmt: skip


def _obstacle_groups(d: FloatArray, cam: NDArray[np.intp], cfg: FusionConfig) -> list[list[int]]:
    """Greedy agglomeration, closest pairs first; a group holds one sighting per camera."""
    n = len(d)
    if n == 0:
        return []
    x, y, r = d[:, X], d[:, Y], d[:, R]
    dist = np.hypot(x[:, None] - x[None], y[:, None] - y[None])
    sa, sb, sc = (d[:, k][:, None] + d[:, k][None] for k in (CXX, CXY, CYY))
    gate = cfg.gate_sigmas * np.sqrt(_largest_eigenvalue(sa, sb, sc)) + cfg.gate_floor_cm
    ok = (
        (dist <= gate)
        & (np.abs(r[:, None] - r[None]) <= cfg.radius_gate_cm)
        & (cam[:, None] != cam[None])
    )
    ii, jj = np.nonzero(ok)
    upper = ii < jj  # each pair once
    ii, jj = ii[upper], jj[upper]
    members = {i: [i] for i in range(n)}
    if not len(ii):
        return list(members.values())
    order = np.argsort((dist / gate)[ii, jj], kind="stable")
    ii, jj = ii[order].tolist(), jj[order].tolist()
    passing = set(zip(ii, jj, strict=True))
    cams = cam.tolist()
    label = list(range(n))
    for i, j in zip(ii, jj, strict=True):
        a, b = label[i], label[j]
        if a == b:
            continue
        ma, mb = members[a], members[b]
        if len(ma) + len(mb) > 2 and (  # two single sightings: (i, j) passed already
            {cams[m] for m in ma} & {cams[m] for m in mb}
            # every pair across the two groups must pass the gate (no chaining)
            or not all((min(p, q), max(p, q)) in passing for p in ma for q in mb)
        ):
            continue
        for m in mb:
            label[m] = a
        members[a] += members.pop(b)
    return list(members.values())


def fuse(
    sightings: Sightings | Sequence[Sighting],
    cfg: FusionConfig,
    footprints: Sequence[tuple[float, float, float]] = (),
) -> list[Fused]:
    """Every object once: robots by marker id, obstacles by gated position and size;
    robots first (by marker id), then obstacles. A blob whose centre lies inside a
    robot's footprint (its radius round a robot of this frame, or one of
    ``footprints``: (x, y, radius) of robots seen just before, whose camera's frame is
    late) is part of that robot as another camera saw it (partly, its marker not found
    there) and is no obstacle."""
    s = sightings if isinstance(sightings, Sightings) else Sightings.of(sightings)
    d = s.data
    marked = s.robot & ~np.isnan(d[:, MARKER])
    rob, obs = np.flatnonzero(marked), np.flatnonzero(~marked)
    label: list[int] = []
    first: list[int] = []
    if len(rob):  # robots by marker, in marker order (a few: plain Python)
        markers = d[rob, MARKER].tolist()
        group = {m: g for g, m in enumerate(sorted(set(markers)))}
        label = [group[m] for m in markers]
        first = [markers.index(m) for m in group]
    # a blob inside a robot's footprint: its own robot sightings' or the footprints given
    disks = np.concatenate([d[rob][:, [X, Y, R]], np.asarray(footprints, float).reshape(-1, 3)])
    if len(obs) and len(disks):
        inside = np.hypot(d[obs, X][:, None] - disks[:, 0], d[obs, Y][:, None] - disks[:, 1])
        obs = obs[~(inside < disks[:, 2]).any(axis=1)]
    robots = len(first)
    grouped = [0] * len(obs)
    for g, members in enumerate(_obstacle_groups(d[obs], s.cam[obs], cfg)):
        for m in members:
            grouped[m] = robots + g
        first.append(len(rob) + members[0])
    return _fused(s, np.concatenate([rob, obs]), label + grouped, first) if first else []
