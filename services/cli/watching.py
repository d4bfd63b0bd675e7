"""What `ovis up`, `ovis watch` and `ovis status` show: live view, status, summary."""

from __future__ import annotations

import collections
import contextlib
import threading
import time
from collections.abc import Callable
from typing import Any

import msgspec
import numpy as np
import zenoh

from ovis.common.analysis.evaluation import match_objects
from ovis.common.messages import (
    MessageError,
    ObstacleFrame,
    ServiceStatus,
    Topics,
    TruthFrame,
    decode,
)

__all__ = [
    "LiveView",
    "RunSummary",
    "collect_status",
    "format_obstacles",
    "status_table",
    "summary_table",
]

STAGES = ("capture", "preprocess", "label", "pose", "calibrator")


def format_obstacles(msg: ObstacleFrame) -> str:
    """One frame of the obstacle topic as a few readable lines."""
    head = f"frame {msg.seq}  age {msg.frame_age_ms:.1f} ms  calibration v{msg.calibration_version}"
    lines = [head]
    if msg.robot is None:
        lines.append("  robot: not found")
    else:
        r = msg.robot
        lines.append(f"  R    x {r.x_cm:7.2f}  y {r.y_cm:7.2f}  r {r.radius_cm:5.2f} cm")
    plan = {p.obstacle_id: p for p in msg.planner}
    for o in msg.obstacles:
        p = plan.get(o.id)
        extra = f"   distance {p.distance_cm:7.2f} cm  angle {p.angle_deg:+7.1f}°" if p else ""
        lines.append(
            f"  O{o.id:<3d} x {o.x_cm:7.2f}  y {o.y_cm:7.2f}  r {o.radius_cm:5.2f} cm" + extra
        )
    if not msg.obstacles:
        lines.append("  no obstacles")
    return "\n".join(lines)


class ServiceReport(msgspec.Struct):
    """One service in `ovis status`: alive per liveliness, and its last status."""

    service: str
    alive: bool
    status: ServiceStatus | None = None


def alive_services(session: zenoh.Session, topics: Topics, timeout: float = 1.5) -> set[str]:
    """The services of the arena whose liveliness token is up."""
    alive = set()
    for reply in session.liveliness().get(topics.alive_all, timeout=timeout):
        if reply.ok is not None:
            alive.add(str(reply.ok.key_expr).rsplit("/", 1)[-1])
    return alive


def collect_status(
    session: zenoh.Session, topics: Topics, timeout: float = 1.5
) -> list[ServiceReport]:
    """Liveliness tokens and status replies of every service of the arena."""
    alive = alive_services(session, topics, timeout)
    statuses: dict[str, ServiceStatus] = {}
    for reply in session.get(topics.status_all, timeout=timeout):
        if reply.ok is None:
            continue
        try:
            st = decode(reply.ok.payload.to_bytes(), ServiceStatus)
        except MessageError:
            continue
        statuses[st.service] = st
    names = list(STAGES) + sorted((alive | set(statuses)) - set(STAGES))
    return [ServiceReport(n, n in alive, statuses.get(n) if n in alive else None) for n in names]


def status_table(report: list[ServiceReport], topics: Topics):
    from rich.table import Table

    t = Table(title=f"ovis services of arena {topics.arena}", title_justify="left")
    for col in (
        "service",
        "alive",
        "state",
        "fps",
        "in",
        "out",
        "dropped",
        "errors",
        "calib",
        "pid@host",
    ):
        t.add_column(col, justify="right" if col in ("fps", "in", "out", "dropped") else "left")
    for r in report:
        s = r.status
        if s is None:
            t.add_row(
                r.service,
                "yes" if r.alive else "[red]NO[/]",
                "-",
                "-",
                "-",
                "-",
                "-",
                "-",
                "-",
                "-",
            )
            continue
        errors = ", ".join(f"{k} {v}" for k, v in s.errors.items()) or "0"
        t.add_row(
            r.service,
            "yes",
            s.state,
            f"{s.fps:.1f}",
            str(s.frames_in),
            str(s.frames_out),
            str(s.dropped),
            errors,
            f"v{s.calibration_version}",
            f"{s.pid}@{s.host}",
        )
    return t


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


class LiveView:
    """Subscribes to obstacles (and the simulator's truth) and keeps the numbers."""

    def __init__(self, topics: Topics, config: Any) -> None:
        self.topics = topics
        self.config = config
        self.latest: ObstacleFrame | None = None
        self.latency_ms: list[float] = []
        self.truth: collections.OrderedDict[int, TruthFrame] = collections.OrderedDict()
        self.truth_frames = 0
        self.pending: collections.OrderedDict[int, ObstacleFrame] = collections.OrderedDict()
        self.pos_err: list[float] = []
        self.matched = self.missed = self.spurious = 0
        self.frames = 0
        self._lock = threading.Lock()

    def attach(self, session: zenoh.Session) -> None:
        session.declare_subscriber(self.topics.obstacles, self._on_obstacles)
        session.declare_subscriber(self.topics.truth, self._on_truth)

    def _on_truth(self, sample: zenoh.Sample) -> None:
        try:
            t = decode(sample.payload.to_bytes(), TruthFrame)
        except MessageError:
            return
        with self._lock:
            self.truth_frames = self.truth_frames + 1
            self.truth[t.seq] = t
            while len(self.truth) > 512:
                self.truth.popitem(last=False)
            self._score()

    def _on_obstacles(self, sample: zenoh.Sample) -> None:
        now = time.time_ns()
        try:
            msg = decode(sample.payload.to_bytes(), ObstacleFrame)
        except MessageError:
            return
        with self._lock:
            self.latency_ms.append((now - msg.stamp_ns) / 1e6)
            self.latest = msg
            self.frames += 1
            self.pending[msg.seq] = msg
            while len(self.pending) > 512:
                self.pending.popitem(last=False)
            self._score()

    def _score(self) -> None:
        for seq in [s for s in self.pending if s in self.truth]:
            msg = self.pending.pop(seq)
            truth = self.truth[seq]
            objs = ([msg.robot] if msg.robot else []) + msg.obstacles
            acc = match_objects(objs, truth.objects)
            self.pos_err.extend(acc.position_error_cm.tolist())
            self.matched += acc.truth_index.size
            self.missed += acc.missed
            self.spurious += acc.spurious

    def run(
        self,
        stop: threading.Event,
        *,
        until: float | None,
        live: bool,
        supervise: Callable[[], list[str]],
        quiet: bool = False,
    ) -> None:
        """Show the newest frame until ``stop`` or ``until`` (monotonic); every tick, let
        the supervisor restart what died, and say so."""
        from rich.console import Console
        from rich.live import Live
        from rich.text import Text

        console = Console(highlight=False, stderr=quiet)

        def render() -> Text:
            with self._lock:
                msg = self.latest
                lat = self.latency_ms[-200:]
            if msg is None:
                return Text("waiting for the first obstacle message …")
            p50 = np.median(lat) if lat else float("nan")
            return Text(
                format_obstacles(msg) + f"\n  {self.frames} frames, latency p50 {p50:.1f} ms"
            )

        ctx = Live(render(), console=console, refresh_per_second=4) if live else None
        last_print = 0.0
        with ctx if ctx is not None else contextlib.nullcontext():
            while not stop.is_set():
                if until is not None and time.monotonic() >= until:
                    break
                for event in supervise():
                    console.print(f"[yellow]{event}[/]")
                if ctx is not None:
                    ctx.update(render())
                elif not quiet and time.monotonic() - last_print > 5.0 and self.latest:
                    last_print = time.monotonic()
                    console.print(render(), highlight=False)
                stop.wait(0.25)

    def poll_status(self, session: zenoh.Session) -> dict[str, ServiceStatus]:
        return {r.service: r.status for r in collect_status(session, self.topics) if r.status}

    def summary(
        self,
        statuses: dict[str, ServiceStatus],
        codes: dict[str, int],
        duration: float,
        restarts: dict[str, int] | None = None,
    ) -> RunSummary:
        with self._lock:
            lat = np.asarray(self.latency_ms)
            err = np.asarray(self.pos_err)
        capture = statuses.get("capture")
        versions = [s.calibration_version for s in statuses.values()]
        return RunSummary(
            duration_s=round(duration, 2),
            frames_captured=capture.frames_out if capture else 0,
            frames_processed=self.frames,
            latency_ms_p50=float(np.percentile(lat, 50)) if lat.size else None,
            latency_ms_p99=float(np.percentile(lat, 99)) if lat.size else None,
            latency_ms_max=float(lat.max()) if lat.size else None,
            objects_matched=self.matched,
            objects_missed=self.missed,
            objects_spurious=self.spurious,
            position_error_cm_mean=float(err.mean()) if err.size else None,
            position_error_cm_max=float(err.max()) if err.size else None,
            calibration_version=(
                self.latest.calibration_version if self.latest else max(versions, default=-1)
            ),
            dropped={n: s.dropped for n, s in statuses.items()},
            errors={n: s.errors for n, s in statuses.items() if s.errors},
            exit_codes=codes,
            restarts={n: r for n, r in (restarts or {}).items() if r},
            truth_frames=self.truth_frames,
        )


def summary_table(s: RunSummary):
    from rich.table import Table

    t = Table(title="ovis up: summary", title_justify="left")
    t.add_column("measure")
    t.add_column("value", justify="right")

    def fmt(v: float | None, unit: str, digits: int = 2) -> str:
        return "-" if v is None else f"{v:.{digits}f} {unit}"

    t.add_row("duration", fmt(s.duration_s, "s", 1))
    t.add_row("frames captured / processed", f"{s.frames_captured} / {s.frames_processed}")
    t.add_row(
        "latency capture → obstacles p50 / p99",
        f"{fmt(s.latency_ms_p50, 'ms')} / {fmt(s.latency_ms_p99, 'ms')}",
    )
    if s.truth_frames:  # no truth lines for data that has no truth
        t.add_row(
            "objects matched to truth",
            f"{s.objects_matched} ({s.objects_missed} missed, {s.objects_spurious} spurious)",
        )
        t.add_row(
            "position error mean / max",
            f"{fmt(s.position_error_cm_mean, 'cm', 3)} / {fmt(s.position_error_cm_max, 'cm', 3)}",
        )
    t.add_row("calibration version", str(s.calibration_version))
    t.add_row("dropped frames", ", ".join(f"{k} {v}" for k, v in s.dropped.items()) or "0")
    errs = "; ".join(f"{k}: {v}" for k, v in s.errors.items())
    t.add_row("errors", errs or "0")
    t.add_row("restarts", ", ".join(f"{k} {v}" for k, v in s.restarts.items()) or "0")
    return t
