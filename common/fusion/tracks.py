"""World identities kept across frames and across hand-overs between cameras.

A robot's identity is its marker. An obstacle's is a world id given when it is first
seen and kept while its fused position moves less than ``track_gate_cm`` per frame
(optimal assignment, :func:`scipy.optimize.linear_sum_assignment`), whichever cameras see
it; an obstacle unseen for ``lost_frames`` frames is dropped and its id is not reused.
"""

from __future__ import annotations

import msgspec
import numpy as np
from scipy.optimize import linear_sum_assignment

from ovis.common.config import FusionConfig
from ovis.common.fusion.merge import Fused

__all__ = ["Tracked", "WorldTracker"]

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
        self._tracks: dict[int, tuple[float, float, int]] = {}  # id → x, y, frames unseen

    def update(self, fused: list[Fused]) -> list[Tracked]:
        """The world ids of this frame's objects (robots: marker id)."""
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
            self._tracks[tid] = (f.x_cm, f.y_cm, 0)
            seen.add(tid)
            out.append(Tracked(id=tid, obj=f))
        for tid in list(self._tracks):
            if tid not in seen:
                x, y, unseen = self._tracks[tid]
                if unseen + 1 >= self.cfg.lost_frames:
                    del self._tracks[tid]
                else:
                    self._tracks[tid] = (x, y, unseen + 1)
        return out
