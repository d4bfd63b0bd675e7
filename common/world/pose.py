"""Robot vs obstacles, and identities kept from frame to frame (paper §5.2).

* :func:`pick_robot`: the robot is told apart by a configurable shape/size rule — the
  least compact blob (eq. 13) among those with compactness ≤ ``robot_max_compactness``
  and floor area within ``robot_area_cm2``. Obstacles are every other blob.
* :class:`Tracker`: keeps an obstacle's id while it moves, by an optimal assignment of
  this frame's obstacles to the last frame's (positions predicted with their velocity),
  within a gate of ``track_gate_cm``; an unmatched obstacle gets a new id. Ids are
  unique across kinds: the unmarked robot always has id 0, a marked robot its configured
  id, and an obstacle an id no robot has or had (:meth:`Tracker.reserve`), live and
  offline alike.
* :func:`gated_assignment`: that assignment. For a few obstacles, one dense
  ``linear_sum_assignment``. For many: when every track's nearest detection within
  the gate is a different one (the usual case: obstacles move little between frames),
  matching each track to it is optimal — each pair is at its least possible distance and
  every track that can be matched is — so one k-d tree query settles it. Otherwise the
  optimal assignment is solved on the sparse graph of in-gate pairs: a pair that is each
  other's only candidate is matched outright, the rest by ``linear_sum_assignment``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ovis.common.config import PoseConfig

__all__ = [
    "ROBOT_ID",
    "TrackStep",
    "Tracker",
    "gated_assignment",
    "gated_pairs_few",
    "pick_robot",
    "robot_ids",
]

ROBOT_ID = 0


def robot_ids(pose: PoseConfig) -> set[int]:
    """The ids robots use under ``pose``: the unmarked robot's and every marked robot's."""
    return {ROBOT_ID, *(r.id for r in pose.robots)}


def pick_robot(
    compactness: NDArray[np.float64], area_cm2: NDArray[np.float64], pose: PoseConfig
) -> int:
    """Index of the robot's blob, or −1 when no blob passes the robot rule."""
    lo, hi = pose.robot_area_cm2
    if not compactness.size:
        return -1
    score = np.where((area_cm2 >= lo) & (area_cm2 <= hi), compactness, np.inf)
    best = int(score.argmin())
    return best if score[best] <= pose.robot_max_compactness else -1


#: Up to this many track × detection pairs, :func:`gated_assignment` solves the dense
#: problem (k-d trees cost more than they save for a handful of obstacles).
DENSE_PAIRS = 400

#: Cost of a pair outside the gate in the dense assignment: any number of in-gate pairs
#: costs less than one such pair, so the most pairs are matched first.
_OUT_OF_GATE = 1e9


def gated_assignment(
    a: NDArray[np.float64], b: NDArray[np.float64], gate: float
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Match points ``a`` (n, 2) to points ``b`` (m, 2) one-to-one, only pairs at most
    ``gate`` apart: as many pairs as possible, then the least total distance.

    Returns
    -------
    rows, cols : int64 arrays
        ``a[rows[k]]`` is matched to ``b[cols[k]]``.
    """
    none = np.zeros(0, dtype=np.int64)
    if not (a.size and b.size):
        return none, none
    if len(a) * len(b) <= DENSE_PAIRS:  # a few obstacles: the whole cost matrix is cheaper
        cost = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1])
        near = cost <= gate  # (NaN: not)
        if near.sum(0).max() <= 1 and near.sum(1).max() <= 1:
            # each point has at most one candidate (obstacles apart, as most frames'):
            # those pairs are the one assignment with the most pairs
            rows, cols = np.nonzero(near)
            return rows.astype(np.int64), cols.astype(np.int64)
        cost[~near] = _OUT_OF_GATE
        return _optimal(cost)
    from scipy.spatial import cKDTree  # on first use: most processes never match many

    tree = cKDTree(b)
    _, nearest = tree.query(a, distance_upper_bound=gate)
    rows = np.flatnonzero(nearest < len(b))  # tracks with a candidate (else: len(b))
    cols = nearest[rows]
    if not cols.size or np.bincount(cols).max() == 1:
        return rows, cols.astype(np.int64)
    pairs = cKDTree(a).sparse_distance_matrix(tree, gate, output_type="ndarray")
    i, j, dist = pairs["i"].astype(np.int64), pairs["j"].astype(np.int64), pairs["v"]
    if not i.size:
        return none, none
    # A pair whose two points have no other candidate is matched in every optimum.
    alone = (np.bincount(i)[i] == 1) & (np.bincount(j)[j] == 1)
    rows, cols = i[alone], j[alone]
    rest = ~alone
    if rest.any():
        ri, ai = np.unique(i[rest], return_inverse=True)
        rj, bj = np.unique(j[rest], return_inverse=True)
        cost = np.full((ri.size, rj.size), _OUT_OF_GATE)
        cost[ai, bj] = dist[rest]
        r, c = _optimal(cost)
        rows = np.concatenate([rows, ri[r]])
        cols = np.concatenate([cols, rj[c]])
    return rows, cols


def gated_pairs_few(
    a: list[tuple[float, float]], b: list[tuple[float, float]], gate: float
) -> list[tuple[int, int]] | None:
    """:func:`gated_assignment` of a few points (``a``, ``b``: lists of (x, y)) where
    each has at most one candidate within ``gate`` (obstacles apart, as most frames'):
    its pairs (index into ``a``, into ``b``) in ``a``'s order, in plain Python (for a
    handful of points its dozen array calls cost more than the arithmetic); None where
    a point has several candidates, a distance is the gate's to the last bits or the
    points are too many (ask :func:`gated_assignment`)."""
    if len(a) * len(b) > DENSE_PAIRS:
        return None
    pairs: list[tuple[int, int]] = []
    taken: set[int] = set()
    close = 4.0 * math.ulp(gate)  # math.hypot and numpy's may differ in the last bit
    far, sure = gate + close, gate - close
    for i, (ax, ay) in enumerate(a):
        near = -1
        for j, (bx, by) in enumerate(b):
            d = math.hypot(ax - bx, ay - by)
            if d > far or d != d:  # out of the gate (NaN: too)
                continue
            if d >= sure or near >= 0 or j in taken:
                return None
            near = j
        if near >= 0:
            taken.add(near)
            pairs.append((i, near))
    return pairs


def _optimal(cost: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The optimal assignment of a cost matrix whose out-of-gate entries are
    ``_OUT_OF_GATE``, without those pairs."""
    from scipy.optimize import linear_sum_assignment  # on first use (the import is slow)

    r, c = linear_sum_assignment(cost)
    ok = cost[r, c] < _OUT_OF_GATE
    return r[ok].astype(np.int64), c[ok].astype(np.int64)


class TrackStep(NamedTuple):
    """One frame of :class:`Tracker`: each obstacle's id, displacement (cm per frame) and
    whether it continues a track (its displacement measured)."""

    ids: NDArray[np.int64]
    step: NDArray[np.float64]
    tracked: NDArray[np.bool_]


@dataclass
class Tracker:
    """Frame-to-frame identities of obstacles on the floor (world cm).

    Tracks are arrays (ids, positions, velocities); an update is one
    :func:`gated_assignment`, whatever the number of obstacles. New ids are never one of
    the ``reserved`` (the robots'), so an id names one object whatever its kind.
    """

    gate_cm: float = 20.0
    _ids: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    _xy: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    _velocity: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    _next_id: int = ROBOT_ID + 1
    reserved: set[int] = field(default_factory=lambda: {ROBOT_ID})

    def reserve(self, ids: set[int]) -> None:
        """Keep ``ids`` for robots from now on (a calibration that adds marked robots): new
        obstacles are numbered above them, and a tracked obstacle holding one of them gets
        a new id."""
        self.reserved |= ids
        self._next_id = max(self._next_id, max(self.reserved) + 1)
        taken = np.isin(self._ids, list(ids))
        if taken.any():
            self._ids[taken] = self._fresh(int(taken.sum()))

    def _fresh(self, n: int) -> list[int]:
        """``n`` new ids: the next ones not reserved."""
        out: list[int] = []
        while len(out) < n:
            if self._next_id not in self.reserved:
                out.append(self._next_id)
            self._next_id += 1
        return out

    def track(self, xy: NDArray[np.float64]) -> TrackStep:
        """Assign ids to this frame's obstacle centres (N, 2): each one's id, displacement
        (cm per frame; 0 for a new obstacle) and whether it continues a track (its
        displacement measured; a new one's 0 is not). Tracks not seen this frame are
        dropped."""
        xy = np.array(xy, dtype=np.float64).reshape(-1, 2)  # a copy: kept as the tracks
        ids = np.full(xy.shape[0], -1, dtype=np.int64)
        step = np.zeros(xy.shape)
        if self._ids.size and xy.size:
            rows, cols = gated_assignment(self._xy + self._velocity, xy, self.gate_cm)
            ids[cols] = self._ids[rows]
            step[cols] = xy[cols] - self._xy[rows]
        new = ids < 0
        fresh = int(new.sum())
        if fresh:
            ids[new] = self._fresh(fresh)
        self._ids, self._xy, self._velocity = ids, xy, step
        return TrackStep(ids.copy(), step.copy(), ~new)
