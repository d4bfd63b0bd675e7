"""What ``ovis up`` keeps of a running pipeline: the obstacle frames as they arrive
(latency from capture), each scored against the simulator's ground truth of the same
frame when both have come, and the end-of-run summary."""

from __future__ import annotations

import collections
import threading
from collections.abc import Mapping
from typing import Protocol

import msgspec
import numpy as np

from ovis.common.analysis.evaluation import TrackingScore
from ovis.common.messages import ObstacleFrame, ServiceStatus, SourceGap, TruthFrame

__all__ = ["UNSCORED_SHARE", "LiveScore", "RunSummary", "position_error_flag"]


class Counts(Protocol):
    """A service's counts: its status, or its totals over restarts
    (:class:`ovis.common.pipeline.totals.ServiceTotals`)."""

    frames_out: int
    dropped: int
    errors: dict[str, int]


#: Frames (and truths) kept while waiting for their partner.
KEEP = 512


class RunSummary(msgspec.Struct):
    """The end-of-run summary of `ovis up`."""

    duration_s: float
    frames_captured: int
    frames_processed: int
    latency_ms_p50: float | None
    latency_ms_p99: float | None
    latency_ms_max: float | None
    objects_matched: int
    objects_missed: int
    objects_spurious: int
    position_error_cm_mean: float | None
    position_error_cm_max: float | None
    calibration_version: int
    dropped: dict[str, int]
    errors: dict[str, dict[str, int]]
    exit_codes: dict[str, int]
    restarts: dict[str, int] = {}
    #: frames with ground truth seen (the simulator's); 0: nothing to match against
    truth_frames: int = 0
    #: services whose last status was "degraded", "failing" or "source lost", and why
    health: dict[str, str] = {}
    #: why the position error is not the whole story (objects missed or spurious), or ""
    position_error_flag: str = ""
    #: times the capture's source was lost, the seconds without it, and the latest losses
    source_gaps: int = 0
    source_gap_s: float = 0.0
    gaps: list[SourceGap] = []


#: The position error is flagged when the objects missed plus spurious exceed this share
#: of the objects matched (it is computed over the matched ones only).
UNSCORED_SHARE = 0.05


def position_error_flag(matched: int, missed: int, spurious: int) -> str:
    """Why the position error (over matched objects only) misleads, or ""."""
    if missed + spurious <= UNSCORED_SHARE * max(matched, 1) and (matched or not missed):
        return ""
    return (
        f"over {matched} matched objects only: {missed} missed and {spurious} spurious "
        "are not in it"
    )


class LiveScore:
    """Obstacle frames and truths as they come (from any thread), and their score."""

    def __init__(self) -> None:
        self.latest: ObstacleFrame | None = None
        self.latency_ms: list[float] = []
        self.frames = 0
        self.truth_frames = 0
        self.score = TrackingScore()
        self._truth: collections.OrderedDict[int, TruthFrame] = collections.OrderedDict()
        self._pending: collections.OrderedDict[int, ObstacleFrame] = collections.OrderedDict()
        self._lock = threading.Lock()

    def add_truth(self, truth: TruthFrame) -> None:
        with self._lock:
            self.truth_frames += 1
            _keep(self._truth, truth.seq, truth)
            self._match()

    def add_obstacles(self, msg: ObstacleFrame, received_ns: int) -> None:
        """An obstacle frame that arrived at ``received_ns`` (its latency from capture)."""
        with self._lock:
            self.latency_ms.append((received_ns - msg.stamp_ns) / 1e6)
            self.latest = msg
            self.frames += 1
            _keep(self._pending, msg.seq, msg)
            self._match()

    def _match(self) -> None:
        for seq in [s for s in self._pending if s in self._truth]:
            msg = self._pending.pop(seq)
            objects = ([msg.robot] if msg.robot else []) + msg.obstacles
            self.score.add(objects, self._truth[seq].objects)

    def recent(self, n: int = 200) -> tuple[ObstacleFrame | None, list[float]]:
        """The newest frame and the latencies of the last ``n``."""
        with self._lock:
            return self.latest, self.latency_ms[-n:]

    def summary(
        self,
        statuses: dict[str, ServiceStatus],
        codes: dict[str, int],
        duration: float,
        restarts: dict[str, int] | None = None,
        totals: Mapping[str, Counts] | None = None,
    ) -> RunSummary:
        """The run's summary, with the services' last statuses and exit codes; counts
        from ``totals`` (over every process of a service) where given."""
        with self._lock:
            lat = np.asarray(self.latency_ms)
            err = np.asarray(self.score.position_error_cm)
            score = self.score
        versions = [s.calibration_version for s in statuses.values()]
        counts: dict[str, Counts] = {**statuses, **(totals or {})}
        captured = counts.get("capture")
        source = statuses.get("capture")  # its source's losses
        return RunSummary(
            duration_s=round(duration, 2),
            frames_captured=captured.frames_out if captured else 0,
            frames_processed=self.frames,
            latency_ms_p50=float(np.percentile(lat, 50)) if lat.size else None,
            latency_ms_p99=float(np.percentile(lat, 99)) if lat.size else None,
            latency_ms_max=float(lat.max()) if lat.size else None,
            objects_matched=score.matched,
            objects_missed=score.missed,
            objects_spurious=score.spurious,
            position_error_cm_mean=float(err.mean()) if err.size else None,
            position_error_cm_max=float(err.max()) if err.size else None,
            calibration_version=(
                self.latest.calibration_version if self.latest else max(versions, default=-1)
            ),
            dropped={n: s.dropped for n, s in counts.items()},
            errors={n: s.errors for n, s in counts.items() if s.errors},
            exit_codes=codes,
            restarts={n: r for n, r in (restarts or {}).items() if r},
            truth_frames=self.truth_frames,
            health={
                n: f"{s.state}: {s.reason}"
                for n, s in statuses.items()
                if s.state in ("degraded", "failing", "source lost")
            },
            position_error_flag=position_error_flag(score.matched, score.missed, score.spurious),
            source_gaps=source.source_gaps if source else 0,
            source_gap_s=source.source_gap_s if source else 0.0,
            gaps=source.gaps if source else [],
        )


def _keep(store: collections.OrderedDict, seq: int, item: object) -> None:
    store[seq] = item
    while len(store) > KEEP:
        store.popitem(last=False)
