"""The same robot or obstacle seen by several cameras, reported once.

A robot is the same by its marker id. Two obstacle sightings from different cameras are
the same obstacle when their distance lies within ``gate_sigmas`` of the error both
cameras expect there (the larger axis of the summed covariances, plus
``gate_floor_cm``) and their radii agree within ``radius_gate_cm``. The merged position
is the inverse-covariance (information) weighted mean, so the camera that sees a point
more sharply counts more; its covariance is the inverse of the summed information.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.config import FusionConfig

__all__ = ["Fused", "Sighting", "fuse", "weighted_mean"]

FloatArray = NDArray[np.float64]


class Sighting(msgspec.Struct, kw_only=True, frozen=True):
    """One object as one camera saw it, on the shared floor frame (cm, degrees);
    ``cov_cm2`` is the position covariance ``(xx, xy, yy)``, see
    :func:`ovis.common.fusion.accuracy.position_covariance`."""

    camera: str
    kind: str  # "robot" or "obstacle"
    x_cm: float
    y_cm: float
    z_cm: float
    radius_cm: float
    cov_cm2: tuple[float, float, float]
    marker_id: int | None = None
    heading_deg: float | None = None


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


def _cov(s: Sighting) -> FloatArray:
    xx, xy, yy = s.cov_cm2
    return np.array([[xx, xy], [xy, yy]])


def weighted_mean(points: FloatArray, covs: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Information-weighted mean of ``(n, 2)`` points with ``(n, 2, 2)`` covariances,
    and its covariance ``(Σ Cᵢ⁻¹)⁻¹``."""
    info = np.linalg.inv(covs)
    P = np.linalg.inv(info.sum(axis=0))
    return P @ np.einsum("nij,nj->i", info, points), P


def _merge(group: list[Sighting]) -> Fused:
    if len(group) == 1:  # seen by one camera: as it saw it
        s = group[0]
        xx, xy, yy = s.cov_cm2
        largest = (xx + yy) / 2 + math.hypot((xx - yy) / 2, xy)
        return Fused(kind=s.kind, x_cm=s.x_cm, y_cm=s.y_cm, z_cm=s.z_cm,
                     radius_cm=s.radius_cm, sigma_cm=math.sqrt(largest), cameras=[s.camera],
                     marker_id=s.marker_id, heading_deg=s.heading_deg)  # fmt: skip
    pts = np.array([[s.x_cm, s.y_cm] for s in group])
    covs = np.stack([_cov(s) for s in group])
    mean, P = weighted_mean(pts, covs)
    w = 1.0 / np.trace(covs, axis1=1, axis2=2)
    headings = [
        (s.heading_deg, wi) for s, wi in zip(group, w, strict=True) if s.heading_deg is not None
    ]
    heading = None
    if headings:
        a = np.radians([h for h, _ in headings])
        ww = np.array([wi for _, wi in headings])
        heading = math.degrees(math.atan2(ww @ np.sin(a), ww @ np.cos(a)))
    return Fused(
        kind=group[0].kind,
        x_cm=float(mean[0]),
        y_cm=float(mean[1]),
        z_cm=float(np.average([s.z_cm for s in group], weights=w)),
        radius_cm=float(np.average([s.radius_cm for s in group], weights=w)),
        sigma_cm=float(math.sqrt(np.linalg.eigvalsh(P)[-1])),
        cameras=sorted(s.camera for s in group),
        marker_id=group[0].marker_id,
        heading_deg=heading,
    )


def _obstacle_groups(obs: list[Sighting], cfg: FusionConfig) -> list[list[int]]:
    """Greedy agglomeration, closest pairs first; a group holds one sighting per camera."""
    n = len(obs)
    if n == 0:
        return []
    pts = np.array([[s.x_cm, s.y_cm] for s in obs])
    covs = np.stack([_cov(s) for s in obs])
    radii = np.array([s.radius_cm for s in obs])
    cams = np.array([s.camera for s in obs])
    dist = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    spread = np.linalg.eigvalsh(covs[:, None] + covs[None])[..., -1]
    gate = cfg.gate_sigmas * np.sqrt(spread) + cfg.gate_floor_cm
    ok = (
        (dist <= gate)
        & (np.abs(radii[:, None] - radii[None]) <= cfg.radius_gate_cm)
        & (cams[:, None] != cams[None])
        & np.triu(np.ones((n, n), bool), 1)
    )
    label = list(range(n))
    members = {i: [i] for i in range(n)}
    ii, jj = np.nonzero(ok)
    for k in np.argsort((dist / gate)[ii, jj], kind="stable"):
        a, b = label[ii[k]], label[jj[k]]
        if a == b or set(cams[members[a]]) & set(cams[members[b]]):
            continue
        # every pair across the two groups must pass the gate (no chaining)
        if not (ok | ok.T)[np.ix_(members[a], members[b])].all():
            continue
        for m in members[b]:
            label[m] = a
        members[a] += members.pop(b)
    return list(members.values())


def fuse(
    sightings: list[Sighting],
    cfg: FusionConfig,
    footprints: Sequence[tuple[float, float, float]] = (),
) -> list[Fused]:
    """Every object once: robots by marker id, obstacles by gated position and size;
    robots first (by marker id), then obstacles. A blob whose centre lies inside a
    robot's footprint (its radius round a robot of this frame, or one of
    ``footprints``: (x, y, radius) of robots seen just before, whose camera's frame is
    late) is part of that robot as another camera saw it (partly, its marker not found
    there) and is no obstacle."""
    robots: dict[int, list[Sighting]] = {}
    obstacles: list[Sighting] = []
    for s in sightings:
        if s.kind == "robot" and s.marker_id is not None:
            robots.setdefault(s.marker_id, []).append(s)
        else:
            obstacles.append(s)
    out = [_merge(robots[m]) for m in sorted(robots)]
    disks = [(r.x_cm, r.y_cm, r.radius_cm) for r in out] + list(footprints)
    obstacles = [o for o in obstacles if not any(
        math.hypot(o.x_cm - x, o.y_cm - y) < r for x, y, r in disks
    )]  # fmt: skip
    out += [_merge([obstacles[i] for i in g]) for g in _obstacle_groups(obstacles, cfg)]
    return out
