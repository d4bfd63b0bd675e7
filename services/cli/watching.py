"""What `ovis up`, `ovis watch` and `ovis status` show: live view, status, summary."""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import msgspec
import numpy as np
import zenoh

from ovis.common.analysis.live import CpuUse, LiveScore, RunSummary
from ovis.common.messages import (
    MessageError,
    ObstacleFrame,
    ServiceStatus,
    StreamHealth,
    Topics,
    TruthFrame,
    decode,
)
from ovis.common.pipeline.totals import claimed_once
from ovis.common.view.health import STAGES, listed
from ovis.services.cli.ui import table, velocity_text
from ovis.services.stopping import Stopping
from ovis.services.trust import every_reply, unproven, verifier_for

__all__ = [
    "LiveView",
    "RunSummary",
    "UnprovenCount",
    "arena_status",
    "camera_statuses",
    "collect_status",
    "format_cpu",
    "format_gaps",
    "format_health",
    "format_obstacles",
    "format_shm",
    "query_statuses",
    "status_table",
    "summary_table",
]


def format_obstacles(msg: ObstacleFrame) -> str:
    """One frame of the obstacle topic as a few readable lines."""
    head = f"frame {msg.seq}  age {msg.frame_age_ms:.1f} ms  calibration v{msg.calibration_version}"
    lines = [head]
    if msg.robot is None:
        lines.append("  robot: not found")
    else:
        r = msg.robot
        lines.append(
            f"  R    x {r.x_cm:7.2f}  y {r.y_cm:7.2f}  r {r.radius_cm:5.2f} cm  "
            f"v {velocity_text(r)} cm/s"
        )
    plan = {p.obstacle_id: p for p in msg.planner}
    for o in msg.obstacles:
        p = plan.get(o.id)
        extra = f"   distance {p.distance_cm:7.2f} cm  angle {p.angle_deg:+7.1f}°" if p else ""
        lines.append(
            f"  O{o.id:<3d} x {o.x_cm:7.2f}  y {o.y_cm:7.2f}  r {o.radius_cm:5.2f} cm  "
            f"v {velocity_text(o)} cm/s" + extra
        )
    if not msg.obstacles:
        lines.append("  no obstacles")
    return "\n".join(lines)


def format_health(msg: StreamHealth) -> str:
    """A health message that is not "ok", as one line: no data, why, and since when."""
    since = msg.seconds_since_frame
    ago = f"the last frame ({msg.last_seq}) came {since:.1f} s ago" if since else "no frame yet"
    if msg.state == "source lost":
        return f"NO DATA: source lost ({msg.reason}); {ago}"
    return f"NO DATA: frames {msg.state}; {ago}" + (f"; {msg.reason}" if msg.reason else "")


class UnprovenCount:
    """Messages dropped for lack of a signer's proof (none, a bad one, or the proof of a
    replayed message), and the line that says so: at the
    first one, then every ``every_s`` while more come, and at the end (thread-safe:
    Zenoh's threads count, the main thread says)."""

    def __init__(self, signer: str, every_s: float = 5.0) -> None:
        self.signer, self.every_s = signer, every_s
        self.n, self.why = 0, ""
        self._said, self._said_at = 0, -every_s
        self._lock = threading.Lock()

    def add(self, why: str) -> None:
        with self._lock:
            self.n += 1
            self.why = why

    def line(self, *, final: bool = False) -> str | None:
        """The count line when it is due (``final``: if any was dropped), else None."""
        now = time.monotonic()
        with self._lock:
            due = self.n > self._said and (final or now - self._said_at >= self.every_s)
            if not due and not (final and self.n):
                return None
            self._said, self._said_at = self.n, now
            return (
                f"dropped {self.n} message(s) without a current proof of origin from "
                f"{self.signer} (last: {self.why})"
            )


class ServiceReport(msgspec.Struct):
    """One service in `ovis status`: alive per liveliness, and its last status; of one
    camera of several (``camera``), or of the arena."""

    service: str
    alive: bool
    status: ServiceStatus | None = None
    camera: str | None = None


def alive_services(session: zenoh.Session, topics: Topics, timeout: float = 1.5) -> set[str]:
    """The services of the arena whose liveliness token is up."""
    alive = set()
    for reply in session.liveliness().get(topics.alive_all, timeout=timeout):
        if reply.ok is not None:
            alive.add(str(reply.ok.key_expr).rsplit("/", 1)[-1])
    return alive


def _status_replies(
    session: zenoh.Session, key: str, timeout: float
) -> Iterator[tuple[str, ServiceStatus]]:
    """Every status reply to a query of ``key`` (each queryable's answer), with the key
    it answered on; one that does not decode is skipped."""
    for reply in every_reply(session, key, timeout=timeout):
        if reply.ok is None:
            continue
        try:
            yield str(reply.ok.key_expr), decode(reply.ok.payload.to_bytes(), ServiceStatus)
        except MessageError:
            continue


def query_statuses(
    session: zenoh.Session,
    topics: Topics,
    timeout: float = 1.5,
    accept: Callable[[ServiceStatus], bool] | None = None,
) -> dict[str, ServiceStatus]:
    """The status replies of the arena's services, by name (a bad reply is skipped, and
    one that ``accept`` refuses: another system's process). Every reply is asked for;
    several for one service give the smallest counters and the worse state, said
    (:func:`~ovis.common.pipeline.totals.claimed_once`: a client answering in a
    service's name cannot raise them, nor hide a failing stage behind an "ok")."""
    statuses: dict[str, ServiceStatus] = {}
    for _key, st in _status_replies(session, topics.status_all, timeout):
        if accept is None or accept(st):
            seen = statuses.get(st.service)
            statuses[st.service] = st if seen is None else claimed_once(seen, st)
    return statuses


def collect_status(
    session: zenoh.Session,
    topics: Topics,
    timeout: float = 1.5,
    accept: Callable[[ServiceStatus], bool] | None = None,
) -> list[ServiceReport]:
    """Liveliness tokens and status replies of every service of the arena."""
    alive = alive_services(session, topics, timeout)
    statuses = query_statuses(session, topics, timeout, accept)
    names = listed(alive, statuses)  # the stages, then the optional services running
    return [ServiceReport(n, n in alive, statuses.get(n) if n in alive else None) for n in names]


def _camera_of(key: str) -> str:
    """The camera of a key ``ovis/<arena>/cam/<camera>/…``."""
    return key.split("/")[3]


def camera_statuses(
    session: zenoh.Session, topics: Topics, timeout: float = 1.5
) -> list[ServiceReport]:
    """Every camera's services (``ovis/<arena>/cam/<camera>/…``), camera by camera: the
    stages always (one missing is not running), then every other one alive or answering;
    the same rules as :func:`collect_status`, whichever process serves the camera."""
    cams = f"ovis/{topics.arena}/cam/*"
    alive: dict[str, set[str]] = {}
    for reply in session.liveliness().get(f"{cams}/alive/*", timeout=timeout):
        if reply.ok is not None:
            key = str(reply.ok.key_expr)
            alive.setdefault(_camera_of(key), set()).add(key.rsplit("/", 1)[-1])
    statuses: dict[str, dict[str, ServiceStatus]] = {}
    for key, st in _status_replies(session, f"{cams}/status/*", timeout):
        mine = statuses.setdefault(_camera_of(key), {})
        seen = mine.get(st.service)
        mine[st.service] = st if seen is None else claimed_once(seen, st)
    reports = []
    for camera in sorted(set(alive) | set(statuses)):
        up, said = alive.get(camera, set()), statuses.get(camera, {})
        reports += [
            ServiceReport(n, n in up, said.get(n) if n in up else None, camera)
            for n in listed(up, said)
        ]
    return reports


def arena_status(
    session: zenoh.Session, topics: Topics, timeout: float = 1.5
) -> list[ServiceReport]:
    """`ovis status`: the arena's services and every camera's (several cameras: the
    arena's own stages are listed only when one of them runs)."""
    root = collect_status(session, topics, timeout)
    cameras = camera_statuses(session, topics, timeout)
    if cameras and not any(r.alive or r.status for r in root if r.service in STAGES):
        root = [r for r in root if r.service not in STAGES]
    return root + cameras


def format_shm(s: ServiceStatus) -> str:
    """A service's shared memory as table markup: messages written into its pool, and
    those sent as plain bytes because the pool was full ("N pool full"; "-": no pool)."""
    if not s.shm_pool_bytes:
        return "-"
    full = f", [yellow]{s.shm_fallbacks} pool full[/]" if s.shm_fallbacks else ""
    return f"{s.shm_written}{full}"


def status_table(report: list[ServiceReport], topics: Topics):
    columns = ("service", "alive", "state", "fps", "in", "out", "dropped", "errors", "calib")
    shm = any(r.status is not None and r.status.shm_pool_bytes for r in report)
    extra = ("shm",) if shm else ()  # only where shared memory is in use
    cameras = any(r.camera for r in report)
    first = ("camera",) if cameras else ()  # several cameras: whose service each row is
    t = table(
        f"ovis services of arena {topics.arena}",
        (*first, *columns, "pid@host", *extra),
        left={*first, "service", "alive", "state", "errors", "calib", "pid@host", *extra},
    )
    for r in report:
        s = r.status
        name = (r.camera or "-", r.service) if cameras else (r.service,)
        if s is None:
            alive = "yes" if r.alive else "[red]NO[/]"
            t.add_row(*name, alive, *["-"] * (len(columns) - 1 + len(extra)))
            continue
        errors = ", ".join(f"{k} {v}" for k, v in s.errors.items()) or "0"
        state = s.state
        if s.state != "ok":  # any other state is not ok (waiting, source lost, …)
            state = f"[red]{s.state}[/]" + (f": {s.reason}" if s.reason else "")
        t.add_row(
            *name,
            "yes",
            state,
            f"{s.fps:.1f}",
            str(s.frames_in),
            str(s.frames_out),
            str(s.dropped),
            errors,
            f"v{s.calibration_version}",
            f"{s.pid}@{s.host}",
            *([format_shm(s)] if shm else []),
        )
    return t


class LiveView:
    """Subscribes to obstacles (and the simulator's truth) and shows the newest frame;
    the numbers are kept by :class:`~ovis.common.analysis.live.LiveScore`."""

    def __init__(
        self,
        topics: Topics,
        config: Any,
        accept: Callable[[ServiceStatus], bool] | None = None,
    ) -> None:
        self.topics = topics
        self.config = config
        self.score = LiveScore()
        self.accept = accept  # whose statuses count (None: everyone's)
        self.verifier = verifier_for(config, "pose")
        self.unproven = UnprovenCount("the pose stage")

    def attach(self, session: zenoh.Session) -> None:
        session.declare_subscriber(self.topics.obstacles, self._on_obstacles)
        session.declare_subscriber(self.topics.truth, self._on_truth)

    def _on_truth(self, sample: zenoh.Sample) -> None:
        with contextlib.suppress(MessageError):
            self.score.add_truth(decode(sample.payload.to_bytes(), TruthFrame))

    def _on_obstacles(self, sample: zenoh.Sample) -> None:
        now = time.time_ns()
        payload = sample.payload.to_bytes()
        if problem := unproven(self.verifier, sample, payload):
            self.unproven.add(problem)  # never scored, never shown
            return
        try:
            msg = decode(payload, ObstacleFrame)
        except MessageError as exc:  # counted and said in the summary, never scored
            self.score.refuse(str(exc))
            return
        self.score.add_obstacles(msg, now)

    def run(
        self,
        stop: Stopping,
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
            msg, lat = self.score.recent()
            if msg is None:
                return Text("waiting for the first obstacle message …")
            p50 = np.median(lat) if lat else float("nan")
            return Text(
                format_obstacles(msg) + f"\n  {self.score.frames} frames, latency p50 {p50:.1f} ms"
            )

        ctx = Live(render(), console=console, refresh_per_second=4) if live else None
        last_print = 0.0
        with ctx if ctx is not None else contextlib.nullcontext():
            while not stop.is_set():
                if until is not None and time.monotonic() >= until:
                    break
                for event in supervise():
                    console.print(f"[yellow]{event}[/]")
                if line := self.unproven.line():
                    console.print(f"[red]{line}[/]")
                if ctx is not None:
                    ctx.update(render())
                elif not quiet and time.monotonic() - last_print > 5.0 and self.score.latest:
                    last_print = time.monotonic()
                    console.print(render(), highlight=False)
                stop.wait(0.1)  # the supervisor's tick: a dead stage restarts this soon

    def poll_status(self, session: zenoh.Session) -> dict[str, ServiceStatus]:
        reports = collect_status(session, self.topics, accept=self.accept)
        return {r.service: r.status for r in reports if r.status}


def summary_table(s: RunSummary):
    from rich.markup import escape

    t = table("ovis up: summary", ("measure", "value"), left={"measure"})

    def fmt(v: float | None, unit: str, digits: int = 2) -> str:
        return "-" if v is None else f"{v:.{digits}f} {unit}"

    t.add_row("duration", fmt(s.duration_s, "s", 1))
    t.add_row("frames captured / processed", f"{s.frames_captured} / {s.frames_processed}")
    t.add_row(
        "latency capture → obstacles p50 / p99",
        f"{fmt(s.latency_ms_p50, 'ms')} / {fmt(s.latency_ms_p99, 'ms')}",
    )
    if s.fits_pending_s is not None:
        t.add_row(
            "objects waiting for their fits",
            f"until {s.fits_pending_s:.1f} s; latency after: "
            f"{fmt(s.latency_after_fits_ms_p50, 'ms')} / {fmt(s.latency_after_fits_ms_p99, 'ms')}",
        )
    if s.truth_frames:  # no truth lines for data that has no truth
        t.add_row(
            "objects matched to truth",
            f"{s.objects_matched} ({s.objects_missed} missed, {s.objects_spurious} spurious, "
            f"{s.objects_wrong_kind} of the wrong kind)",
        )
        if s.after_fits is not None:
            a = s.after_fits
            t.add_row(
                "after the fits",
                f"{a.frames} frames: {a.objects_matched} matched ({a.objects_missed} missed, "
                f"{a.objects_spurious} spurious, {a.objects_within_stated} within their "
                f"stated uncertainty); position error {fmt(a.position_error_cm_mean, 'cm', 3)}"
                f" / {fmt(a.position_error_cm_max, 'cm', 3)}",
            )
        if s.objects_within_stated:
            t.add_row(
                "positions not measurable",
                f"{s.objects_within_stated} found within the uncertainty they state (up to "
                f"{fmt(s.within_stated_error_cm_max, 'cm')} off, stated 1σ up to "
                f"{fmt(s.within_stated_sigma_cm_max, 'cm')}); not in the position error",
            )
        error = (
            f"{fmt(s.position_error_cm_mean, 'cm', 3)} / {fmt(s.position_error_cm_max, 'cm', 3)}"
        )
        error += f" over {s.objects_matched} matched ({s.objects_missed} missed, "
        error += f"{s.objects_spurious} spurious)"
        if s.position_error_flag:
            error += f"\n[red]UNRELIABLE: {s.position_error_flag}[/]"
        t.add_row("position error mean / max", error)
        height = f"{fmt(s.height_error_cm_mean, 'cm', 3)} / {fmt(s.height_error_cm_max, 'cm', 3)}"
        if s.heights:
            height += f"\nheights {escape(s.heights)}"
        t.add_row("height error mean / max (abs.)", height)
        for name, b in s.by_height.items():
            t.add_row(
                f"  heights {escape(name)}",
                f"{b.objects} objects: position {b.position_error_cm_mean:.3f} / "
                f"{b.position_error_cm_max:.3f} cm, height {b.height_error_cm_mean:.3f} / "
                f"{b.height_error_cm_max:.3f} cm, {b.wrong_kind} of the wrong kind",
            )
    t.add_row("calibration version", str(s.calibration_version))
    t.add_row("dropped frames", ", ".join(f"{k} {v}" for k, v in s.dropped.items()) or "0")
    errs = "; ".join(f"{k}: {v}" for k, v in s.errors.items())
    t.add_row("errors", errs or "0")
    if s.frames_refused:
        t.add_row(
            "obstacle frames refused",
            f"[red]{s.frames_refused} (not decoded: {escape(s.refused_because)})[/]",
        )
    t.add_row("restarts", ", ".join(f"{k} {v}" for k, v in s.restarts.items()) or "0")
    health = "\n".join(f"[red]{k} {v}[/]" for k, v in s.health.items())
    t.add_row("health", health or ("ok" if s.frames_processed else "[red]no frame processed[/]"))
    t.add_row("source lost", format_gaps(s))
    if s.cpu is not None and s.cpu.ms_per_frame is not None:
        t.add_row("CPU per frame (all processes)", format_cpu(s.cpu))
    if s.navigation is not None:
        for r in s.navigation.robots:
            goal = (
                f"goal reached in {r.time_s:.1f} s"
                if r.goal_reached
                else "[red]goal not reached[/]"
            )
            contacts = f"[red]{r.collisions} collision(s)[/]" if r.collisions else "no collision"
            closest = "-" if r.min_clearance_cm is None else f"{r.min_clearance_cm:.1f} cm"
            source = "ROS 2 cmd_vel" if r.follows == "cmd_vel" else "ovis's signed"
            clamped = f" ({r.clamped} clamped to its limits)" if r.clamped else ""
            t.add_row(
                f"robot {r.id} drive",
                f"{goal}, {contacts}, closest approach {closest}; {r.commands} "
                f"{source} commands followed{clamped}, {r.refused} refused",
            )
        if not s.navigation.robots:
            t.add_row("robots driven", "[red]no drive report came[/]")
    if s.exit_code:
        t.add_row("exit code", f"[red]{s.exit_code}: {s.reason}[/]")
    return t


def format_cpu(cpu: CpuUse) -> str:
    """The run's CPU time per frame: all its processes, each, and `ovis up`'s own."""
    each = ", ".join(f"{k} {v:.2f}" for k, v in cpu.by_process_ms.items() if v)
    own = cpu.own_ms_per_frame or 0.0
    return (
        f"{cpu.ms_per_frame:.2f} ms ({each}); ovis up's own {own:.2f} ms; over "
        f"{cpu.frames} frames in {cpu.window_s:.1f} s"
    )


def format_gaps(s: RunSummary, shown: int = 5) -> str:
    """The source's losses of a run: how many, for how long, and why (the latest
    ``shown``), as table markup."""
    from rich.markup import escape

    if not s.source_gaps:
        return "never"
    times = "once" if s.source_gaps == 1 else f"{s.source_gaps} times"
    lines = [f"[red]{times}, {s.source_gap_s:.1f} s in total[/]"]
    if s.source_gaps > shown:
        lines.append(f"… {s.source_gaps - shown} earlier")
    for gap in s.gaps[-shown:]:
        still = " (still lost)" if gap.ongoing else ""
        lines.append(f"{gap.seconds:.1f} s{still}: {escape(gap.reason)}")
    return "\n".join(lines)
