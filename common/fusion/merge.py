"""The same robot or obstacle seen by several cameras, reported once.

A robot is the same by its marker id. Two obstacle sightings from different cameras are
the same obstacle when their distance lies within ``gate_sigmas`` of the error both
cameras expect there (the larger axis of the summed covariances, plus
``gate_floor_cm``) and their radii agree within ``radius_gate_cm``.

The merged footprint and height are the information-weighted mean of the sightings'
(x, y, z): each sighting's information is the inverse of its covariance, 3 × 3 where its
camera measured the height (a solid fitted to its silhouette,
:mod:`ovis.common.world.heights`), its 2 × 2 (x, y) block alone where the height is
configured or not measurable there (it says nothing about z); the merged covariance is
the inverse of the summed information. So every camera that sees a solid contributes
its footprint, and each one that measured its height contributes that too, weighted by
how sharply it sees it: the paper's future work (§7 (2)), several views of one object.
Where no camera measured the height, it is the mean of the configured ones.

Cameras whose measured positions and heights disagree beyond their combined
uncertainty (the sightings' χ² about the merged point above the ``1 − disagree_p``
quantile of χ² with 3 (k − 1) degrees of freedom) are not averaged: the sighting that
disagrees most (of two: the one with the less certain height) has its height left out
until the rest agree, and is named in :attr:`Fused.disagreeing`.

Every group of a world frame is merged at once: the sums over each group's members are
one matrix product with the group indicator, the 3 × 3 inverses one batched call.
"""

from __future__ import annotations

from collections.abc import Sequence

import msgspec
import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from ovis.common.config import FusionConfig
from ovis.common.fusion.sightings import (
    CXX,
    CXY,
    CXZ,
    CYY,
    CYZ,
    CZZ,
    HEADING,
    MARKER,
    Z_SOURCES,
    ZFIT,
    ZSRC,
    R,
    Sighting,
    Sightings,
    X,
    Y,
    Z,
)

__all__ = ["Fused", "Sighting", "Sightings", "fuse", "information"]

FloatArray = NDArray[np.float64]

#: information (1/cm²) on z of a sighting whose height is not measured: none to speak
#: of beside a measured one, enough to make the mean of configured heights the answer
#: where no camera measured it
UNMEASURED_Z_INFO = 1e-9
_ONE_CAMERA, _CAMERAS = Z_SOURCES.index("one camera"), Z_SOURCES.index("cameras")


class Fused(msgspec.Struct, kw_only=True):
    """One object of the world, merged from its sightings (no identity yet): ``z_cm``
    with its 1σ ``z_sigma_cm`` (None: not measured) and where it comes from
    (``z_source``, one of :data:`~ovis.common.fusion.sightings.Z_SOURCES`: "cameras"
    where two or more measured it); ``disagreeing``, the cameras whose measured height
    disagreed with the others' and was left out."""

    kind: str
    x_cm: float
    y_cm: float
    z_cm: float
    radius_cm: float
    sigma_cm: float  # square root of the larger axis of the merged (x, y) covariance
    cameras: list[str]
    marker_id: int | None = None
    heading_deg: float | None = None
    z_sigma_cm: float | None = None
    z_source: str = "configured"
    disagreeing: list[str] = []


def _largest_eigenvalue(a: FloatArray, b: FloatArray, c: FloatArray) -> FloatArray:
    """Larger eigenvalue of the symmetric 2×2 matrices ``[[a, b], [b, c]]``."""
    return (a + c) / 2 + np.hypot((a - c) / 2, b)


def information(d: FloatArray, use_z: NDArray[np.bool_], bias_cm: float = 0.0) -> FloatArray:
    """``(n, 3, 3)`` information (inverse covariance) of sightings' (x, y, z): the full
    3 × 3 inverse where ``use_z`` (a fitted height), its (x, y) variances raised by
    ``bias_cm``² (what a fit's own covariance leaves out: its edges' bias, the
    calibration); elsewhere the 2 × 2 (x, y) block's inverse and
    :data:`UNMEASURED_Z_INFO` on z. A covariance that is not positive definite (the
    sighting's ``use_z`` is then cleared) gives its (x, y) block, and one whose (x, y)
    block is not either gives nothing to speak of."""
    n = len(d)
    cov = np.empty((n, 3, 3))
    cov[:, 0, 0], cov[:, 1, 1], cov[:, 2, 2] = d[:, CXX], d[:, CYY], d[:, CZZ]
    cov[:, 0, 1] = cov[:, 1, 0] = d[:, CXY]
    cov[:, 0, 2] = cov[:, 2, 0] = d[:, CXZ]
    cov[:, 1, 2] = cov[:, 2, 1] = d[:, CYZ]
    cov[use_z, 0, 0] += bias_cm**2
    cov[use_z, 1, 1] += bias_cm**2
    if use_z.any():
        use_z &= np.linalg.eigvalsh(np.where(use_z[:, None, None], cov, np.eye(3)))[:, 0] > 0
    flat = ~use_z
    cov[flat, 0:2, 2] = cov[flat, 2, 0:2] = 0.0
    cov[flat, 2, 2] = 1.0 / UNMEASURED_Z_INFO
    a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    bad = ~((a > 0) & (a * c - b * b > 0))
    cov[bad, 0:2, 0:2] = np.eye(2) / UNMEASURED_Z_INFO
    return np.linalg.inv(cov)


def _combine(info: FloatArray, p: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Information-weighted mean of points ``p`` ``(k, 3)`` and its covariance."""
    cov = np.linalg.inv(info.sum(axis=0))
    return cov @ np.einsum("kij,kj->i", info, p), cov


def _disagreeing(p: FloatArray, d: FloatArray, info: FloatArray, use_z: NDArray[np.bool_],
                 group: NDArray[np.intp], p_value: float) -> list[int]:  # fmt: skip
    """The members of one group (rows ``group``, at points ``p``) whose fitted height
    is left out for disagreeing with the others' (module docstring); ``use_z`` and
    ``info`` are updated."""
    out: list[int] = []
    while True:
        k = group[use_z[group]]
        if len(k) < 2:
            return out
        mean, _ = _combine(info[k], p[k])
        r = p[k] - mean
        terms = np.einsum("ki,kij,kj->k", r, info[k], r)
        if terms.sum() <= chi2.ppf(1.0 - p_value, 3 * (len(k) - 1)):
            return out
        worst = int(k[np.argmax(d[k, CZZ])]) if len(k) == 2 else int(k[np.argmax(terms)])
        use_z[worst] = False
        info[worst] = information(d[worst : worst + 1], np.zeros(1, bool))[0]
        out.append(worst)


def _merge_groups(d: FloatArray, label: NDArray[np.intp], groups: int,
                  first: NDArray[np.intp], cfg: FusionConfig
                  ) -> tuple[FloatArray, list[list[int]]]:  # fmt: skip
    """Every group at once: ``(groups, 8)`` x, y, z, radius, sigma, heading (NaN: none),
    z's σ (NaN: not measured) and z's source code; and per group the members whose
    height disagreed.

    Per sighting its information ``Iᵢ`` (:func:`information`), ``Iᵢ pᵢ`` (``pᵢ`` with
    its fitted height), the weight ``wᵢ = 1 / trace Cᵢ`` (for radius and heading) and
    the heading's unit vector; per group their sums (one matrix product with the group
    indicator); then ``P = (Σ Iᵢ)⁻¹``, ``p = P Σ Iᵢ pᵢ``, sigma ``√λmax`` of P's (x, y)
    block and the weighted circular mean of the headings. The merged height counts as
    measured where its σ ``√P_zz`` is at most ``height_sigma_max_cm``; else it is the
    mean of the reported (configured) ones. A group of one is reported as its camera
    saw it."""
    n = len(d)
    use_z = np.isfinite(d[:, CZZ]) & np.isfinite(d[:, ZFIT])
    info = information(d, use_z, cfg.footprint_bias_cm)
    p = d[:, [X, Y, ZFIT]]
    p[~use_z, 2] = d[~use_z, Z]
    member = np.zeros((groups, n))
    member[label, np.arange(n)] = 1.0
    disagree: list[list[int]] = [[] for _ in range(groups)]
    for g in np.flatnonzero(member @ use_z >= 2).tolist():
        members = np.flatnonzero(label == g)
        disagree[g] = _disagreeing(p, d, info, use_z, members, cfg.disagree_p)
    counted = member @ use_z
    w = np.empty((n, 17))
    # columns: information (9), information × position (3), weight × radius, weight ×
    # heading's (sin, cos), weight, reported height
    w[:, 0:9] = info.reshape(n, 9)
    w[:, 9:12] = np.einsum("nij,nj->ni", info, p)
    weight = np.reciprocal(d[:, CXX] + d[:, CYY])
    heading = np.radians(d[:, HEADING])
    has = heading == heading
    heading[~has] = 0.0
    w[:, 12] = weight * d[:, R]
    w[:, 13] = np.sin(heading) * weight * has
    w[:, 14] = np.cos(heading) * weight * has
    w[:, 15] = weight
    w[:, 16] = d[:, Z]
    total = member @ w
    cov = np.linalg.inv(total[:, 0:9].reshape(groups, 3, 3))
    out = np.empty((groups, 8))
    out[:, 0:3] = np.einsum("gij,gj->gi", cov, total[:, 9:12])
    out[:, 3] = total[:, 12] / total[:, 15]
    out[:, 4] = np.sqrt(_largest_eigenvalue(cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]))
    out[:, 5] = np.where(member @ has > 0, np.degrees(np.arctan2(total[:, 13], total[:, 14])),
                         np.nan)  # fmt: skip
    z_sigma = np.sqrt(cov[:, 2, 2])
    measured = (counted > 0) & (z_sigma <= cfg.height_sigma_max_cm)
    out[:, 2] = np.where(measured, out[:, 2], total[:, 16] / member.sum(axis=1))
    out[:, 6] = np.where(measured, z_sigma, np.nan)
    out[:, 7] = np.where(measured, np.where(counted >= 2, _CAMERAS, _ONE_CAMERA),
                         d[first, ZSRC])  # fmt: skip
    one = np.flatnonzero(member.sum(axis=1) == 1)
    if len(one):
        own = d[first[one]]
        out[one, :4] = own[:, X : R + 1]
        out[one, 5] = own[:, HEADING]
        out[one, 6] = np.where(own[:, ZSRC] >= _ONE_CAMERA, np.sqrt(own[:, CZZ]), np.nan)
        out[one, 7] = own[:, ZSRC]
    return out, disagree


def _fused(s: Sightings, rows: NDArray[np.intp], label: list[int], first: list[int],
           cfg: FusionConfig) -> list[Fused]:  # fmt: skip
    """The groups of the sightings ``s.data[rows]`` (group ``label`` each; ``first``:
    each group's first member) merged, as :class:`Fused`."""
    merged, disagree = _merge_groups(s.data[rows], np.array(label, np.intp), len(first),
                                     np.array(first, np.intp), cfg)  # fmt: skip
    names: list[list[str]] = [[] for _ in first]
    cams = s.cam[rows].tolist()
    for g, c in zip(label, cams, strict=True):
        names[g].append(s.cameras[c])
    lead = rows[first]
    robot, marker = s.robot[lead].tolist(), s.data[lead, MARKER].tolist()
    return [
        Fused(kind="robot" if rb else "obstacle", x_cm=x, y_cm=y, z_cm=z, radius_cm=r,
              sigma_cm=sg, cameras=sorted(cs), marker_id=None if mk != mk else int(mk),
              heading_deg=None if h != h else h, z_sigma_cm=None if zs != zs else zs,
              z_source=Z_SOURCES[int(src)],
              disagreeing=sorted(s.cameras[cams[m]] for m in out))
        for rb, mk, (x, y, z, r, sg, h, zs, src), cs, out in zip(
            robot, marker, merged.tolist(), names, disagree, strict=True)
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
    if not first:
        return []
    return _fused(s, np.concatenate([rob, obs]), label + grouped, first, cfg)
