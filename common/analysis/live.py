"""What ``ovis up`` keeps of a running pipeline: the obstacle frames as they arrive
(latency from capture), each scored against the simulator's ground truth of the same
frame when both have come, and the end-of-run summary."""

from __future__ import annotations

import collections
import threading
from collections.abc import Mapping
from typing import NamedTuple, Protocol

import msgspec
import numpy as np

from ovis.common.analysis.evaluation import TrackingScore
from ovis.common.config import PoseConfig
from ovis.common.messages import (
    IDLE_STATES,
    SOURCE_LOST,
    ObstacleFrame,
    RobotDrive,
    ServiceStatus,
    SourceGap,
    TruthFrame,
)

__all__ = [
    "IDLE_STATES",
    "SOURCE_LOST",
    "UNSCORED_SHARE",
    "AfterFits",
    "BasisErrors",
    "CpuUse",
    "LiveScore",
    "NavigationRobot",
    "NavigationRun",
    "RunSummary",
    "heights_basis",
    "navigation_run",
    "position_error_flag",
    "with_verdict",
]


class Counts(Protocol):
    """A service's counts: its status, or its totals over restarts
    (:class:`ovis.common.pipeline.totals.ServiceTotals`)."""

    frames_out: int
    dropped: int
    errors: dict[str, int]


#: Frames (and truths) kept while waiting for their partner.
KEEP = 512


class CpuUse(msgspec.Struct, kw_only=True):
    """The CPU time of a run's processes (from /proc) over a window of it, per frame
    delivered in that window (obstacle frames; world frames with several cameras)."""

    window_s: float
    frames: int
    #: every process the run started together (router, stages, spares); None: no frame
    ms_per_frame: float | None
    by_process_ms: dict[str, float | None] = {}
    #: `ovis up`'s own process (its live view and this summary), not in the above
    own_ms_per_frame: float | None = None


class BasisErrors(msgspec.Struct):
    """The matched objects whose heights rest on one basis (``RunSummary.by_height``):
    how many (over all frames), their position error (cm) and their reported top height
    less the true one (cm, absolute): mean and largest; how many were of the wrong
    kind."""

    objects: int
    position_error_cm_mean: float
    position_error_cm_max: float
    height_error_cm_mean: float
    height_error_cm_max: float
    #: of them reported as the other kind (an obstacle as the robot, or the robot as an
    #: obstacle)
    wrong_kind: int = 0


class NavigationRobot(msgspec.Struct, kw_only=True):
    """One driven robot at the end of a run (``ovis up --drive``): whether it reached
    its goal, when (s since the world's start; None: not reached), its contacts with
    other solids (MuJoCo's) and its closest approach to any (cm; ≤ 0 touching); what
    it followed (``follows``: "ovis" or "cmd_vel", :class:`RobotDrive`)."""

    id: int
    goal_reached: bool
    time_s: float | None
    collisions: int
    min_clearance_cm: float | None
    commands: int = 0
    refused: int = 0
    follows: str = "ovis"
    clamped: int = 0


class NavigationRun(msgspec.Struct, kw_only=True):
    """The driven robots of a run, each as its last drive report said."""

    robots: list[NavigationRobot]


def navigation_run(last: Mapping[int, RobotDrive]) -> NavigationRun:
    """The summary's navigation part from each robot's last :class:`RobotDrive`."""
    return NavigationRun(
        robots=[
            NavigationRobot(
                id=d.robot_id,
                goal_reached=d.goal_reached,
                time_s=d.time_s,
                collisions=d.collisions,
                min_clearance_cm=d.min_clearance_cm,
                commands=d.commands,
                refused=d.refused,
                follows=d.follows,
                clamped=d.clamped,
            )
            for _, d in sorted(last.items())
        ]
    )


class AfterFits(msgspec.Struct, kw_only=True):
    """The score of the frames after the last one in which an object waited for its
    fit (measured heights; ``RunSummary.after_fits``): how many frames, objects matched,
    missed and spurious, found within their stated uncertainty, and the matched ones'
    position error (cm: mean and largest)."""

    frames: int
    objects_matched: int
    objects_missed: int
    objects_spurious: int
    objects_within_stated: int
    position_error_cm_mean: float | None
    position_error_cm_max: float | None


class _FrameScore(NamedTuple):
    """One scored frame: its capture stamp (ns), what it added to the run's score, and
    its matched objects' position errors (cm)."""

    stamp_ns: int
    matched: int
    missed: int
    spurious: int
    within_stated: int
    errors: list[float]


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
    #: services whose last status says something is wrong, and why: any state but "ok",
    #: except that of a service not at work (:data:`IDLE_STATES`) that handled frames
    health: dict[str, str] = {}
    #: why the position error is not the whole story (objects missed or spurious), or ""
    position_error_flag: str = ""
    #: times the capture's source was lost, the seconds without it, and the latest losses
    source_gaps: int = 0
    source_gap_s: float = 0.0
    gaps: list[SourceGap] = []
    #: `ovis up`'s exit code (0 frames processed with a calibration, 3 nothing usable
    #: came out, 1 a process failed) and why it is not 0
    exit_code: int = 0
    reason: str = ""
    #: the matched objects' reported top height less the true one (cm): mean of the
    #: absolute errors and the largest; ``heights`` says what the reported ones rest on
    height_error_cm_mean: float | None = None
    height_error_cm_max: float | None = None
    heights: str = ""
    #: what the run's processes cost per frame, from 1 s after the first frame to the end
    cpu: CpuUse | None = None
    #: the same errors by what each matched object's height rests on
    #: (:func:`~ovis.common.analysis.evaluation.height_basis`): "one camera" (measured:
    #: its ``x_cm``, ``y_cm`` the footprint), "marker", "configured (pending)" (its fit
    #: still to come: its centroid on its class's plane), "configured (not measurable)"…
    by_height: dict[str, BasisErrors] = {}
    #: obstacle frames that arrived but did not decode as one (not counted as processed),
    #: and why the last did not
    frames_refused: int = 0
    refused_because: str = ""
    #: matched objects reported as the other kind (an obstacle as the robot, or the
    #: robot as an obstacle)
    objects_wrong_kind: int = 0
    #: detections whose position is not measurable (a solid whose foot is hidden), found
    #: within the uncertainty they state (:mod:`~ovis.common.analysis.stated`; not in
    #: the matched, missed or spurious counts nor the position error): how many, their
    #: largest error and their largest stated 1σ (cm)
    objects_within_stated: int = 0
    within_stated_error_cm_max: float | None = None
    within_stated_sigma_cm_max: float | None = None
    #: measured heights: capture seconds from the first frame processed to the last one
    #: in which an object still waited for its fit ("pending"; None: none waited), and
    #: the latency of the frames after it (ms: median, 99th percentile)
    fits_pending_s: float | None = None
    latency_after_fits_ms_p50: float | None = None
    latency_after_fits_ms_p99: float | None = None
    #: measured heights, where an object waited for its fit: the score of the frames
    #: after (the run's steady state once every blob has had its fit)
    after_fits: AfterFits | None = None
    #: ``ovis up --drive``: each driven robot's outcome
    navigation: NavigationRun | None = None


#: The position error is flagged when the objects missed plus spurious exceed this share
#: of the objects matched (it is computed over the matched ones only).
UNSCORED_SHARE = 0.05


def heights_basis(pose: PoseConfig) -> str:
    """What the reported heights rest on: measured (``[pose] heights = "measured"``,
    where a height can be measured) or the configured ones."""
    if getattr(pose, "heights", "configured") == "measured":
        return 'measured where they can be ([pose] heights = "measured"), else configured'
    return (
        f"configured ([pose] obstacle_height_cm {pose.obstacle_height_cm:g}, "
        f"robot_height_cm {pose.robot_height_cm:g}), not measured"
    )


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
        #: latencies by the capture's stream identity: a run counts only its own
        self._by_stream: dict[str, list[float]] = collections.defaultdict(list)
        self.truth_frames = 0
        self.score = TrackingScore()
        self._truth: collections.OrderedDict[int, TruthFrame] = collections.OrderedDict()
        self._pending: collections.OrderedDict[int, ObstacleFrame] = collections.OrderedDict()
        self._lock = threading.Lock()
        self._closed = False
        self.refused = 0
        self.refused_because = ""
        #: capture stamps (ns) and latencies of the frames, and the last stamp of a frame
        #: in which an object waited for its fit
        self._stamps: list[int] = []
        self._waited_ns: int | None = None
        self._frame_scores: list[_FrameScore] = []

    def refuse(self, why: str) -> None:
        """An obstacle frame that arrived but could not be decoded: counted, and why."""
        with self._lock:
            if not self._closed:
                self.refused += 1
                self.refused_because = why

    def close(self) -> None:
        """Count no more obstacle frames: every frame counted was captured before any
        count the capture gives after this (processed never exceeds captured)."""
        with self._lock:
            self._closed = True

    def add_truth(self, truth: TruthFrame) -> None:
        with self._lock:
            self.truth_frames += 1
            _keep(self._truth, truth.seq, truth)
            self._match()

    def add_obstacles(self, msg: ObstacleFrame, received_ns: int) -> None:
        """An obstacle frame that arrived at ``received_ns`` (its latency from capture)."""
        with self._lock:
            if self._closed:
                return
            latency = (received_ns - msg.stamp_ns) / 1e6
            self.latency_ms.append(latency)
            self._by_stream[msg.stream].append(latency)
            self._stamps.append(msg.stamp_ns)
            objects = ([msg.robot] if msg.robot else []) + msg.obstacles
            if any(o.z_unmeasured == "pending" for o in objects):
                self._waited_ns = max(self._waited_ns or msg.stamp_ns, msg.stamp_ns)
            self.latest = msg
            self.frames += 1
            _keep(self._pending, msg.seq, msg)
            self._match()

    def _match(self) -> None:
        for seq in [s for s in self._pending if s in self._truth]:
            msg = self._pending.pop(seq)
            objects = ([msg.robot] if msg.robot else []) + msg.obstacles
            sc = self.score
            was = (sc.matched, sc.missed, sc.spurious, sc.within_stated, len(sc.position_error_cm))
            sc.add(objects, self._truth[seq].objects)
            self._frame_scores.append(
                _FrameScore(
                    msg.stamp_ns,
                    sc.matched - was[0],
                    sc.missed - was[1],
                    sc.spurious - was[2],
                    sc.within_stated - was[3],
                    sc.position_error_cm[was[4] :],
                )
            )

    def _after_fits(self) -> tuple[float | None, np.ndarray]:
        """Seconds until the last frame with an object waiting for its fit (None: none
        waited), and the latencies (ms) of the frames after it (all, when none waited)."""
        stamps, lat = np.asarray(self._stamps), np.asarray(self.latency_ms)
        if self._waited_ns is None or not stamps.size:
            return None, lat
        return (self._waited_ns - int(stamps.min())) / 1e9, lat[stamps > self._waited_ns]

    def _score_after_fits(self) -> AfterFits | None:
        """The score of the frames after the last one with an object waiting for its
        fit (None: none waited)."""
        if self._waited_ns is None:
            return None
        after = [f for f in self._frame_scores if f.stamp_ns > self._waited_ns]
        err = np.array([e for f in after for e in f.errors])
        return AfterFits(
            frames=len(after),
            objects_matched=sum(f.matched for f in after),
            objects_missed=sum(f.missed for f in after),
            objects_spurious=sum(f.spurious for f in after),
            objects_within_stated=sum(f.within_stated for f in after),
            position_error_cm_mean=float(err.mean()) if err.size else None,
            position_error_cm_max=float(err.max()) if err.size else None,
        )

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
        streams: set[str] | None = None,
    ) -> RunSummary:
        """The run's summary, with the services' last statuses and exit codes; counts
        from ``totals`` (over every process of a service) where given; frames only of
        the capture ``streams`` given (the run's own: an empty set, none), or of every
        stream (None)."""
        with self._lock:
            own = [v for k, v in self._by_stream.items() if streams is None or k in streams]
            lat = np.concatenate([np.asarray(v) for v in own]) if own else np.zeros(0)
            err = np.asarray(self.score.position_error_cm)
            dz = np.abs(np.asarray(self.score.height_error_cm))
            basis = np.asarray(self.score.height_basis, dtype=object)
            right = np.asarray(self.score.kind_correct, dtype=bool)
            waited, after = self._after_fits()
            after_fits = self._score_after_fits()
            score = self.score
        versions = [s.calibration_version for s in statuses.values()]
        counts: dict[str, Counts] = {**statuses, **(totals or {})}
        captured = counts.get("capture")
        source = statuses.get("capture")  # its source's losses
        return RunSummary(
            duration_s=round(duration, 2),
            frames_captured=captured.frames_out if captured else 0,
            frames_processed=int(lat.size),
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
            health={n: _said(s) for n, s in statuses.items() if _unwell(s)},
            position_error_flag=position_error_flag(score.matched, score.missed, score.spurious),
            source_gaps=source.source_gaps if source else 0,
            source_gap_s=source.source_gap_s if source else 0.0,
            gaps=source.gaps if source else [],
            height_error_cm_mean=float(dz.mean()) if dz.size else None,
            height_error_cm_max=float(dz.max()) if dz.size else None,
            by_height=_by_basis(basis, err, dz, right),
            fits_pending_s=waited,
            latency_after_fits_ms_p50=float(np.percentile(after, 50)) if after.size else None,
            latency_after_fits_ms_p99=float(np.percentile(after, 99)) if after.size else None,
            objects_wrong_kind=score.wrong_kind,
            after_fits=after_fits,
            objects_within_stated=score.within_stated,
            within_stated_error_cm_max=max(score.stated_error_cm, default=None),
            within_stated_sigma_cm_max=max(score.stated_sigma_cm, default=None),
            frames_refused=self.refused,
            refused_because=self.refused_because,
        )


def _by_basis(
    basis: np.ndarray, position: np.ndarray, height: np.ndarray, right: np.ndarray
) -> dict[str, BasisErrors]:
    """The matched objects' errors grouped by their heights' basis (``right``: whether
    each was of the right kind)."""
    out = {}
    for name in sorted(set(basis.tolist())):
        on = basis == name
        p, h = position[on], height[on]
        out[str(name)] = BasisErrors(
            int(on.sum()),
            float(p.mean()),
            float(p.max()),
            float(h.mean()),
            float(h.max()),
            int((~right[on]).sum()),
        )
    return out


def _unwell(status: ServiceStatus) -> bool:
    """Whether ``status`` says something is wrong (see :attr:`RunSummary.health`)."""
    if status.state == "ok":
        return False
    return not (status.state.startswith(IDLE_STATES) and status.frames_out > 0)


def _said(status: ServiceStatus) -> str:
    """A service's state, and why when it says."""
    why = status.reason or status.last_error
    return f"{status.state}: {why}" if why else status.state


#: The stages of the frame path, in order: the first one that says why is the reason.
FRAME_PATH = ("capture", "preprocess", "label", "pose", "calibrator")


def _why(summary: RunSummary) -> str:
    """What the services said was wrong, frame path first (their health, else errors)."""
    names = sorted(summary.health.keys() | summary.errors.keys(), key=_path_order)
    said = []
    for n in names:
        if n in summary.health:
            said.append(f"{n} {summary.health[n]}")
        else:
            said.append(f"{n}: " + ", ".join(f"{k} x{c}" for k, c in summary.errors[n].items()))
    return "; ".join(said)


def _path_order(name: str) -> tuple[int, str]:
    return (FRAME_PATH.index(name) if name in FRAME_PATH else len(FRAME_PATH), name)


def with_verdict(
    summary: RunSummary, capture: ServiceStatus | None, failures: list[str]
) -> RunSummary:
    """The summary with `ovis up`'s exit code and its reason: 3 when no frame was
    processed or the capture's source was lost at the end, 1 when a process failed
    (``failures``: why), else 0. Nothing processed is never "ok": the health says so."""
    health = dict(summary.health)
    lost = capture is not None and capture.state == SOURCE_LOST
    if summary.frames_processed == 0:
        if capture is None:
            reason = "no frame was captured: the capture never answered (not started yet, or dead)"
        elif summary.frames_captured == 0:
            source = capture.reason or capture.last_error or f"its state: {capture.state}"
            reason = f"no frame was captured: {source}"
        else:
            why = _why(summary) or "no stage said why"
            if summary.frames_refused:
                why = (
                    f"{summary.frames_refused} obstacle frames did not decode "
                    f"({summary.refused_because}); {why}"
                )
            reason = f"{summary.frames_captured} frames captured, none processed: {why}"
        code = 3
        reason = "; ".join([reason, *failures])
        health["run"] = "no frame processed"
    elif failures:
        code, reason = 1, "; ".join(failures)
    elif lost:
        assert capture is not None
        code = 3
        why = capture.reason or capture.last_error
        reason = f"the source was lost (and not back at the end): {why}"
    else:
        code, reason = 0, ""
    return msgspec.structs.replace(summary, exit_code=code, reason=reason, health=health)


def _keep(store: collections.OrderedDict, seq: int, item: object) -> None:
    store[seq] = item
    while len(store) > KEEP:
        store.popitem(last=False)
