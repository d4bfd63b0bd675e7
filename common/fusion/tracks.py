"""World identities kept across frames and across hand-overs between cameras.

A robot's identity is its marker. An obstacle's is a world id given when it is first
seen and kept while its fused position moves less than ``track_gate_cm`` per frame
(optimal assignment, :func:`scipy.optimize.linear_sum_assignment`), whichever cameras see
it; an obstacle unseen for ``lost_frames`` frames is dropped and its id is not reused.
A frame counts as unseeing only where a camera of that frame could have reported the
obstacle (``covered``, see :func:`ovis.common.fusion.coverage.reportable`): one late
camera's obstacles keep their ids however long its frames are missing.
"""

from __future__ import annotations

from collections.abc import Callable

import msgspec
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from ovis.common.config import FusionConfig
from ovis.common.fusion.merge import Fused

__all__ = ["Covered", "Tracked", "WorldTracker"]

#: (x, y, z, radius arrays) → which of those objects a frame's cameras could report
Covered = Callable[[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                    NDArray[np.float64]], NDArray[np.bool_]]  # fmt: skip

#: World ids of obstacles start here, so they never collide with robot ids (markers).
OBSTACLE_ID_BASE = 1000


class Tracked(msgspec.Struct, kw_only=True):
    """A fused object with its world identity."""

    id: int
    obj: Fused


class WorldTracker:
    """Gives each fused object its world id, frame after frame."""

    def __init__(self, cfg: FusionConfig) -> None:
        self.cfg = cfg
        self._next = OBSTACLE_ID_BASE
        #: id → x, y, z, radius, frames unseen
        self._tracks: dict[int, tuple[float, float, float, float, int]] = {}

    def update(self, fused: list[Fused], covered: Covered | None = None) -> list[Tracked]:
        """The world ids of this frame's objects (robots: marker id); ``covered`` says
        which of the unseen obstacles (x, y, z, radius arrays) this frame's cameras could
        have reported (default: all)."""
        out = [Tracked(id=f.marker_id, obj=f) for f in fused if f.marker_id is not None]
        obs = [f for f in fused if f.marker_id is None]
        ids = list(self._tracks)
        taken: dict[int, int] = {}
        if ids and obs:
            prev = np.array([self._tracks[i][:2] for i in ids])
            now = np.array([[f.x_cm, f.y_cm] for f in obs])
            cost = np.linalg.norm(now[:, None] - prev[None], axis=-1)
            rows, cols = linear_sum_assignment(np.where(cost <= self.cfg.track_gate_cm, cost, 1e9))
            taken = {
                int(r): ids[c]
                for r, c in zip(rows, cols, strict=True)
                if cost[r, c] <= self.cfg.track_gate_cm
            }
        seen: set[int] = set()
        for k, f in enumerate(obs):
            tid = taken.get(k)
            if tid is None:
                tid, self._next = self._next, self._next + 1
            self._tracks[tid] = (f.x_cm, f.y_cm, f.z_cm, f.radius_cm, 0)
            seen.add(tid)
            out.append(Tracked(id=tid, obj=f))
        gone = [tid for tid in self._tracks if tid not in seen]
        if gone and covered is not None:
            where = np.array([self._tracks[tid][:4] for tid in gone]).T
            gone = [tid for tid, c in zip(gone, covered(*where).tolist(), strict=True) if c]
        for tid in gone:
            x, y, z, r, unseen = self._tracks[tid]
            if unseen + 1 >= self.cfg.lost_frames:
                del self._tracks[tid]
            else:
                self._tracks[tid] = (x, y, z, r, unseen + 1)
        return out
