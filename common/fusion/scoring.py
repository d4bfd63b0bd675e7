"""How good a fused world is, against ground truth: duplicates, identity swaps, the jump
at a hand-over between cameras and the position error (``ovis up --cameras``, tests).

Each world frame's objects are matched to the true objects (optimal assignment on
distance, within ``gate_cm``). A *duplicate* is a second world object within the gate
of a true object already matched; an *identity swap* is a world id that starts to follow
another true object, or a true object that gets another world id; a *hand-over jump* is,
at a frame where the set of cameras seeing an object changes, how much its fused
displacement differs from its true displacement.
"""

from __future__ import annotations

import math

import msgspec
import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = ["WorldScore", "WorldScorer"]


class WorldScore(msgspec.Struct, kw_only=True):
    """The score of a run of world frames (distances in cm)."""

    frames: int
    duplicates: int
    missed: int  # true objects seen by some camera but absent from the world
    phantoms: int  # world objects near no true object
    identity_swaps: int
    handovers: int
    handover_jump_cm: float  # the largest
    world_error_cm_mean: float
    world_error_cm_max: float
    #: the matched objects' top height less the true one, absolute (when heights are
    #: given to :meth:`WorldScorer.add`; None: none were)
    height_error_cm_mean: float | None = None
    height_error_cm_max: float | None = None
    #: the same by what each height rests on (the world object's ``z_source``, when
    #: given): ``[count, mean, max]``
    height_error_by_source_cm: dict[str, list[float]] = {}


class WorldScorer:
    """Feed it each world frame with its truth; :meth:`score` sums up."""

    def __init__(self, gate_cm: float = 5.0) -> None:
        self.gate_cm = gate_cm
        self.frames = self.duplicates = self.missed = self.phantoms = self.swaps = 0
        self.handovers = 0
        self.jump = 0.0
        self.errors: list[float] = []
        self.height_errors: list[float] = []
        self.height_sources: list[str] = []
        self._id_of_truth: dict[int, int] = {}
        self._truth_of_id: dict[int, int] = {}
        self._last: dict[int, tuple[float, float, float, float, tuple[str, ...]]] = {}

    def add(
        self,
        world: list[tuple[int, float, float, tuple[str, ...]]],
        truth: list[tuple[int, float, float]],
        seen: set[int] | None = None,
        heights: tuple[list[float], list[float]] | None = None,
        sources: list[str] | None = None,
    ) -> None:
        """One frame: world objects ``(world id, x, y, cameras)`` and true objects
        ``(truth id, x, y)``; ``seen``, the truth ids some camera saw (default all);
        ``heights``, the world objects' and the true objects' top heights (cm), in
        their orders, for the height error; ``sources``, what each world object's
        height rests on (its ``z_source``)."""
        self.frames += 1
        w = np.array([[o[1], o[2]] for o in world]).reshape(-1, 2)
        t = np.array([[o[1], o[2]] for o in truth]).reshape(-1, 2)
        d = np.linalg.norm(w[:, None] - t[None], axis=-1)
        rows, cols = (
            linear_sum_assignment(np.where(d <= self.gate_cm, d, 1e9)) if d.size else ([], [])
        )
        pairs = [(r, c) for r, c in zip(rows, cols, strict=True) if d[r, c] <= self.gate_cm]
        matched_w = {r for r, _ in pairs}
        matched_t = {c for _, c in pairs}
        for r in set(range(len(world))) - matched_w:
            if d.shape[1] and d[r].min() <= self.gate_cm:
                self.duplicates += 1
            else:
                self.phantoms += 1
        want = (
            set(range(len(truth)))
            if seen is None
            else {k for k, o in enumerate(truth) if o[0] in seen}
        )
        self.missed += len(want - matched_t)
        for r, c in pairs:
            wid, x, y, cams = world[r]
            tid, tx, ty = truth[c]
            self.errors.append(float(d[r, c]))
            if heights is not None:
                self.height_errors.append(abs(heights[0][r] - heights[1][c]))
                self.height_sources.append("" if sources is None else sources[r])
            if self._id_of_truth.setdefault(tid, wid) != wid:
                self.swaps += 1
                self._id_of_truth[tid] = wid
            if self._truth_of_id.setdefault(wid, tid) != tid:
                self.swaps += 1
                self._truth_of_id[wid] = tid
            last = self._last.get(tid)
            if last is not None and last[4] != tuple(cams):
                self.handovers += 1
                jump = math.hypot((x - last[0]) - (tx - last[2]), (y - last[1]) - (ty - last[3]))
                self.jump = max(self.jump, jump)
            self._last[tid] = (x, y, tx, ty, tuple(cams))

    def score(self) -> WorldScore:
        """The totals so far."""
        e = np.array(self.errors) if self.errors else np.zeros(1)
        dz = np.array(self.height_errors)
        src = np.array(self.height_sources)
        by_source = {
            name: [float((src == name).sum()), float(dz[src == name].mean()),
                   float(dz[src == name].max())]
            for name in sorted(set(self.height_sources) - {""})
        }  # fmt: skip
        return WorldScore(
            frames=self.frames,
            duplicates=self.duplicates,
            missed=self.missed,
            phantoms=self.phantoms,
            identity_swaps=self.swaps,
            handovers=self.handovers,
            handover_jump_cm=self.jump,
            world_error_cm_mean=float(e.mean()),
            world_error_cm_max=float(e.max()),
            height_error_cm_mean=float(dz.mean()) if dz.size else None,
            height_error_cm_max=float(dz.max()) if dz.size else None,
            height_error_by_source_cm=by_source,
        )
