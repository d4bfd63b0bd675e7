"""Robot vs obstacles, and identities kept from frame to frame (paper §5.2).

* :func:`pick_robot`: the robot is told apart by a configurable shape/size rule — the
  least compact blob (eq. 13) among those with compactness ≤ ``robot_max_compactness``
  and floor area within ``robot_area_cm2``. Obstacles are every other blob.
* :class:`Tracker`: keeps an obstacle's id while it moves, by an optimal assignment of
  this frame's obstacles to the last frame's (positions predicted with their velocity),
  within a gate of ``track_gate_cm``; an unmatched obstacle gets a new id. The robot
  always has id 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from ovis.common.config import PoseConfig

__all__ = ["ROBOT_ID", "Tracker", "pick_robot"]

ROBOT_ID = 0


def pick_robot(
    compactness: NDArray[np.float64], area_cm2: NDArray[np.float64], pose: PoseConfig
) -> int:
    """Index of the robot's blob, or −1 when no blob passes the robot rule."""
    lo, hi = pose.robot_area_cm2
    candidate = (compactness <= pose.robot_max_compactness) & (area_cm2 >= lo) & (area_cm2 <= hi)
    if not candidate.any():
        return -1
    return int(np.argmin(np.where(candidate, compactness, np.inf)))


@dataclass
class Tracker:
    """Frame-to-frame identities of obstacles on the floor (world cm).

    Tracks are arrays (ids, positions, velocities), so an update is one cost matrix and
    one optimal assignment whatever the number of obstacles.
    """

    gate_cm: float = 20.0
    _ids: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    _xy: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    _velocity: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    _next_id: int = ROBOT_ID + 1

    def update(self, xy: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Assign ids to this frame's obstacle centres (N, 2); return (ids, displacements).

        Displacements are in cm per frame (0 for a new obstacle). Tracks not seen this
        frame are dropped.
        """
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        ids = np.full(xy.shape[0], -1, dtype=np.int64)
        step = np.zeros_like(xy)
        if self._ids.size and xy.size:
            predicted = self._xy + self._velocity
            cost = np.linalg.norm(predicted[:, None, :] - xy[None, :, :], axis=2)
            rows, cols = linear_sum_assignment(np.where(cost <= self.gate_cm, cost, 1e9))
            ok = cost[rows, cols] <= self.gate_cm
            rows, cols = rows[ok], cols[ok]
            ids[cols] = self._ids[rows]
            step[cols] = xy[cols] - self._xy[rows]
        new = ids < 0
        ids[new] = np.arange(self._next_id, self._next_id + int(new.sum()))
        self._next_id += int(new.sum())
        self._ids, self._xy, self._velocity = ids.copy(), xy.copy(), step.copy()
        return ids, step
