"""The figures of many runs (``ovis navigate``'s summary), per feed.

* ``runs``: scenarios driven;
* ``success_rate``: share (0–1) of scenarios in which every robot reached its goal with
  no contact;
* ``collisions``: scenarios with any contact (MuJoCo's) between a robot and another
  solid;
* ``timeouts``: scenarios without a contact in which a robot had not reached its goal
  at the timeout;
* ``time_ratio_p50``: median, over the robots that reached their goal, of the time it
  took over the straight-line distance at top speed (None: none reached it);
* ``min_clearance_cm``: the closest any robot came to another solid in any run (cm,
  MuJoCo's geometry; ≤ 0: touching);
* ``frames_processed``: frames its planners were given (rendered and detected for
  ovis, truth read for the oracle);
* ``latency_ms_p50``: median latency (frame → command at the robot) applied.
"""

from __future__ import annotations

from collections.abc import Sequence

import msgspec
import numpy as np

from ovis.common.navigation.episode import EpisodeResult

__all__ = ["FeedSummary", "NavigateSummary", "summarize"]


class FeedSummary(msgspec.Struct, kw_only=True):
    """The figures of one feed's runs (module docstring)."""

    runs: int
    success_rate: float
    collisions: int
    timeouts: int
    time_ratio_p50: float | None
    min_clearance_cm: float | None
    frames_processed: int
    latency_ms_p50: float | None


class NavigateSummary(FeedSummary, kw_only=True):
    """``ovis navigate --json``: the runs fed by ovis's detection, and the same
    scenarios with the planner fed the truth (``oracle``; None when only the oracle
    ran: the fields above are then its own)."""

    oracle: FeedSummary | None


def summarize(results: Sequence[EpisodeResult]) -> FeedSummary:
    """The figures of ``results`` (module docstring)."""
    robots = [r for e in results for r in e.robots]
    ratios = [r.time_ratio for r in robots if r.goal_reached]
    latency = [ms for e in results for ms in e.latency_ms]
    n = len(results)
    return FeedSummary(
        runs=n,
        success_rate=round(sum(e.success for e in results) / n, 4) if n else 0.0,
        collisions=sum(e.collided for e in results),
        timeouts=sum(e.timed_out for e in results),
        time_ratio_p50=round(float(np.median(ratios)), 4) if ratios else None,
        min_clearance_cm=round(min(r.min_clearance_cm for r in robots), 3) if robots else None,
        frames_processed=sum(e.frames for e in results),
        latency_ms_p50=round(float(np.median(latency)), 2) if latency else None,
    )
