"""Commands of the running system: router, run, up, watch, recalibrate, status, schema."""

from __future__ import annotations

import os
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import msgspec
import typer

from ovis.services.cli.errors import UserError
from ovis.services.cli.options import (
    CONNECT_S,
    DEFAULT_ENDPOINT,
    STARTUP_S,
    ArenaOpt,
    ConfigOpt,
    ConnectOpt,
    ConnectTimeoutOpt,
    JsonOpt,
    SummaryJsonOpt,
    TrustOpt,
    WorldOpt,
    arena_topics,
    config_with_options,
    stop_on_signals,
    with_trust,
)

__all__ = ["register"]

STAGES = ("capture", "preprocess", "label", "pose", "calibrator", "fusion", "ros2", "planner")
#: What the router prints once it listens (`ovis up` waits for it in the router's log).
LISTENING = "listening on"


def router(
    listen: Annotated[
        list[str] | None, typer.Option(help=f"Endpoint to listen on; default {DEFAULT_ENDPOINT}.")
    ] = None,
    config: ConfigOpt = None,
    connect: Annotated[
        list[str] | None, typer.Option(help="Another router to mesh with (repeatable).")
    ] = None,
) -> None:
    """Run a Zenoh router (from the Python package itself: no separate binary).

    Services connect to it with `--connect`; routers are meshed with --connect, or with
    `--config` (a [zenoh] section naming other routers in `connect`, and/or a Zenoh JSON5
    file in `config_file`). Only what the command line or the [zenoh] section sets
    overrides the JSON5 file.
    """
    from ovis.common.config import router_zenoh
    from ovis.services.bus import open_session
    from ovis.services.memory import keep_freed_memory

    keep_freed_memory(0)  # a router decodes no frame: keep no freed block for one
    cfg = config_with_options(config, mode="router")  # a bad file has been refused here
    zc = router_zenoh(
        cfg, config, listen=listen, connect=connect, default_endpoint=DEFAULT_ENDPOINT
    )
    stop = stop_on_signals()
    with open_session(zc) as session:
        where = ", ".join(zc.listen) or f"the endpoints of {zc.config_file}"
        meshed = f"; meshed with {', '.join(zc.connect)}" if zc.connect else ""
        print(f"zenoh router {session.zid()} {LISTENING} {where}{meshed}", flush=True)
        while not stop.wait(0.5):
            pass


def _cpus(spec: str | None) -> list[int] | None:
    """``--cpus``/``--pin`` as core numbers (None: not given), or a usage error."""
    if spec is None:
        return None
    from ovis.services.placement import pick_cpus

    try:
        return pick_cpus(spec)
    except ValueError as exc:
        raise UserError(str(exc), 2) from None


def run(
    stage: Annotated[str, typer.Argument(help=f"One of: {', '.join(STAGES)}.")],
    connect: ConnectOpt = None,
    config: ConfigOpt = None,
    arena: ArenaOpt = None,
    source: Annotated[
        str | None,
        typer.Option(help="capture: 'sim', a folder, a video file, 'camera:N' or /dev/videoN."),
    ] = None,
    fps: Annotated[float | None, typer.Option(help="capture: frames per second (0: max).")] = None,
    state_dir: Annotated[
        str | None, typer.Option(help="calibrator: folder of versioned calibrations.")
    ] = None,
    points: Annotated[
        str | None, typer.Option(help="calibrator: control points file, or 'simulator'.")
    ] = None,
    cpus: Annotated[
        str | None,
        typer.Option(
            help="Cores to run on: '1', '0,2', 'auto' (the last core) or 'none' "
            "(default: [service] cpus, else any)."
        ),
    ] = None,
    standby: Annotated[
        bool,
        typer.Option(hidden=True, help="Wait, imports done, for `ovis up` to activate it."),
    ] = False,
    cameras: Annotated[
        str | None,
        typer.Option(
            help="Cameras of [[cameras]] this process serves, e.g. cam00,cam01 (default: "
            "[service] cameras, else all of them), each on its own topics; not for fusion "
            "and ros2."
        ),
    ] = None,
) -> None:
    """Run one service in this process until Ctrl-C/SIGTERM.

    Stages can run on different machines: each connects to a Zenoh router
    (`ovis router`) with --connect. With several cameras ([[cameras]]) a stage process
    serves every one of them (or those of --cameras), each on its own topics and with
    its own status, as each camera's own process would (docs/cameras.md).
    """
    import importlib

    from ovis.common.pipeline.hosting import served_cameras
    from ovis.services.service import run as run_service

    if stage not in STAGES:
        raise UserError(f"unknown stage {stage!r}; choose one of {', '.join(STAGES)}")
    if cameras is not None and stage in WHOLE_ARENA:
        raise UserError(f"--cameras is for the stages of each camera, not {stage}")
    cfg = config_with_options(
        config,
        connect=connect,
        arena=arena,
        source=source,
        fps=fps,
        state_dir=state_dir,
        points=points,
        cpus=_cpus(cpus),
        cameras=_camera_names(cameras),
    )
    arena_topics(cfg)
    served = [] if stage in WHOLE_ARENA else served_cameras(cfg)
    if served and source is not None:
        raise UserError("--source is one camera's: with [[cameras]] each camera has its own")
    module = importlib.import_module(f"ovis.services.{stage}")
    if standby:
        os.environ["OVIS_STANDBY"] = "1"
    warm = _warm_rays if stage in WHOLE_FRAME_TABLES else None
    run_service(stage, cfg, module.main, served, warm)


#: Stages that serve the whole arena, never one camera's frames (``--cameras`` refused).
WHOLE_ARENA = ("fusion", "ros2", "planner")
#: Stages that back-project every pixel of their camera's frame at start (plane tables):
#: a spare makes the costly part ahead (``ovis.common.camera.plane_table.warm_rays``).
WHOLE_FRAME_TABLES = ("label", "pose")


def _warm_rays(cfg: Any) -> None:
    from ovis.common.camera.plane_table import warm_rays

    warm_rays(cfg.camera)


def _camera_names(text: str | None) -> list[str] | None:
    """``--cameras a,b`` as names (None: not given), or a usage error."""
    if text is None:
        return None
    names = [part.strip() for part in text.split(",") if part.strip()]
    if not names:
        raise UserError("--cameras: give camera names, e.g. cam00,cam01")
    return names


def up(
    source: Annotated[
        str | None,
        typer.Option(
            help="'sim' (default), a folder, a video, 'camera:N', a stream URL, a SESSION.mcap."
        ),
    ] = None,
    listen: Annotated[
        str,
        typer.Option(
            help="Endpoint of its own router: it must be free (one system per run; taken: "
            "exit code 2)."
        ),
    ] = DEFAULT_ENDPOINT,
    duration: Annotated[
        float | None,
        typer.Option(
            min=0.0,
            help="Stop this many seconds after the capture starts (once the other stages "
            "listen; the physical world: after its first frame; default: Ctrl-C).",
        ),
    ] = None,
    config: ConfigOpt = None,
    arena: ArenaOpt = None,
    fps: Annotated[float | None, typer.Option(help="Capture frames per second.")] = None,
    state_dir: Annotated[
        str | None, typer.Option(help="Calibrator state folder (default ovis-state).")
    ] = None,
    live: Annotated[bool, typer.Option(help="Live view of what is detected.")] = True,
    json: SummaryJsonOpt = False,
    max_restarts: Annotated[
        int, typer.Option(min=0, help="Restarts allowed per process within a minute.")
    ] = 5,
    calibration: Annotated[
        Path | None,
        typer.Option(
            help="Calibration JSON (`ovis calibrate`) for the live services: checked "
            "against the source's frame size (scaled to the same aspect ratio), stored as "
            "the newest version in the state folder before they start.",
            dir_okay=False,
        ),
    ] = None,
    pin: Annotated[
        str,
        typer.Option(
            help="Cores for capture, preprocess, label and pose: 'auto' (one core, the "
            "last, when there are two or more: lowest latency at camera rates; with "
            "--cameras, the chains dealt round the cores and fusion on the last), 'none' "
            "(any core: most frames per second on many cores), or e.g. '1' or '2,3'."
        ),
    ] = "auto",
    view: Annotated[
        bool,
        typer.Option(
            help="Also start the live web view (`ovis view`) and print its URL; it listens "
            "on OVIS_VIEW_LISTEN (default 127.0.0.1:8080) and offers recalibration when "
            "OVIS_OPERATOR_TOKEN is set."
        ),
    ] = False,
    record: Annotated[
        Path | None,
        typer.Option(
            help="Also record everything into this session file from the first frame "
            "(ovis record; the capture starts once it listens).",
            dir_okay=False,
        ),
    ] = None,
    cameras: Annotated[
        str | None,
        typer.Option(
            help="Run the simulated camera grid instead, e.g. 2x2: one chain per camera "
            "and the fusion service, scored against the truth (docs/cameras.md).",
        ),
    ] = None,
    layout: Annotated[
        str | None,
        typer.Option(
            help="With --cameras: 'per-stage' (one process per stage serving every camera, "
            "the default) or 'per-camera' (one process per stage per camera); [service] "
            "layout.",
        ),
    ] = None,
    seed: Annotated[
        int | None, typer.Option(min=0, help="Simulated scene seed ([service] seed).")
    ] = None,
    topic: Annotated[
        str | None,
        typer.Option(
            help="--source X.mcap written by another tool: the topic of its image channel "
            "to read ([service] source_topic); needed when it has several."
        ),
    ] = None,
    ros2: Annotated[
        bool,
        typer.Option(
            "--ros2",
            help="Also publish as a ROS 2 node over rmw_zenoh ([ros2] section): obstacles, "
            "markers, odometry, camera info and image, /tf_static (docs/ros2.md).",
        ),
    ] = False,
    world: WorldOpt = None,
    drive: Annotated[
        bool,
        typer.Option(
            "--drive",
            help="With --world physical: the robots drive to their goals among the "
            "[navigation] case's moving obstacles, commanded by the planner service on "
            "what ovis sees (docs/navigation.md); with --ros2 the commands go to cmd_vel too.",
        ),
    ] = False,
    follow: Annotated[
        str | None,
        typer.Option(
            help="With --drive: what the world's robots follow ([navigation] follow): "
            "'ovis', the planner's signed commands, or 'cmd_vel', the TwistStamped it "
            "publishes on ROS 2 (no proof of origin: docs/navigation.md)."
        ),
    ] = None,
) -> None:
    """Start a router and all five services as separate processes, show what is
    detected live, and print a summary at the end.

    First, with nothing started yet, it checks that the router's endpoint (--listen) is
    free (else another system runs there), that the source delivers a frame, and that
    there is a calibration for it: a real source (anything but 'sim') needs its own,
    from --calibration, the session file, or the state folder's newest if it is not the
    simulator's; its size must be the frames' (same aspect ratio: scaled, and said so).
    A failed check is one line and exit code 2.

    A process that dies is restarted (at once, then after a back-off of 1 s doubling to
    10 s, at most --max-restarts a minute) and the reason logged. Ctrl-C or SIGTERM (or
    --duration) stops everything cleanly; logs of each process are in a temporary folder
    named at the start. Exit code 0: frames were processed with a calibration; 3: none
    was (also when a process failed: no frame wins), or the source was lost at the end
    (the summary's "reason" says why); 1: a process failed while frames were processed.
    """
    if cameras is not None:
        given = [f"--{n}" for n, v in (("source", source), ("calibration", calibration),
                 ("record", record), ("view", view or None), ("arena", arena),
                 ("topic", topic), ("ros2", ros2 or None)) if v]  # fmt: skip
        if given:
            raise UserError(f"--cameras runs the simulated grid: not with {', '.join(given)}")
        from ovis.services.cli.multicam_up import up_cameras
        from ovis.services.cli.startup import check_endpoint

        check_endpoint(listen)  # one system per run
        return up_cameras(cameras, config=config, listen=listen, duration=duration, json=json,
                          seed=seed, fps=fps, max_restarts=max_restarts, pin=pin,
                          world=world, layout=layout)  # fmt: skip
    if layout is not None:
        raise UserError("--layout lays out several cameras: give --cameras too")
    if drive and world != "physical":
        raise UserError("--drive drives the physical world's robots: give --world physical")
    if follow is not None and not drive:
        raise UserError("--follow says what the driven robots follow: give --drive")
    if follow not in (None, "ovis", "cmd_vel"):
        raise UserError(f"--follow {follow!r}: give 'ovis' or 'cmd_vel'")
    from ovis.services.cli.physical import live_physical, world_options

    cfg = config_with_options(
        config,
        connect=[listen],
        arena=arena,
        source=source,
        fps=fps,
        state_dir=state_dir,
        seed=seed,
        source_topic=topic,
        **world_options(config, world),
    )
    if drive:  # before the calibration is made: it carries the robots' goals
        from ovis.common.navigation.scenarios import live_drive_config
        from ovis.services.cli.physical import physical_camera

        if config is None:  # the preset's tripod camera finds the robots' markers too
            cfg = physical_camera("overhead", cfg)  # rarely; straight down it does
        try:
            cfg = live_drive_config(cfg)
        except ValueError as exc:
            raise UserError(str(exc)) from None
        follows = follow or cfg.navigation.follow
        # the world following cmd_vel follows the planner's: it must publish them
        nav = msgspec.structs.replace(
            cfg.navigation, follow=follows, cmd_vel=ros2 or follows == "cmd_vel"
        )
        cfg = msgspec.structs.replace(cfg, navigation=nav)
    physical = live_physical(cfg, calibration)  # exit 2 when it cannot run here
    topics = arena_topics(cfg)
    cpus = _cpus(pin) or []
    if record is not None and record.exists():
        raise UserError(f"{record} exists; give --record another name (nothing was started)")
    if view and (token := os.environ.get("OVIS_OPERATOR_TOKEN")) and token != "auto":
        from ovis.common.view.guard import token_problem

        if problem := token_problem(token):  # the view would refuse it at its start
            raise UserError(f"OVIS_OPERATOR_TOKEN: {problem} (nothing was started)")
    from ovis.services.cli import startup

    # Before anything starts: the endpoint, the source and its frame size, the calibration.
    startup.check_endpoint(listen)
    size = startup.source_size(cfg)
    from ovis.services.cli.recording import prepare_recorded_source

    recorded = prepare_recorded_source(cfg)  # a session file: its calibration, or why not
    calib, said = startup.calibration_for_run(cfg, calibration, size)
    out = sys.stderr if json else sys.stdout
    for line in said:
        print(f"ovis up: {line}", file=out)
    log_dir = Path(tempfile.mkdtemp(prefix="ovis-up-"))
    cfg_path = log_dir / "config.toml"
    from ovis.common.config import dump_toml
    from ovis.services.bus import local_peers
    from ovis.services.placement import cpus_option, off_path_cpus, off_path_option

    if physical:  # the empty floor, for segmenting the frames against it
        from ovis.services.cli.physical import with_empty_floor

        cfg, said = with_empty_floor(cfg, log_dir)
        print(f"ovis up: {said}", file=out)
    # The services share the router's machine: they talk to each other directly.
    services_cfg = startup.with_keys(startup.services_config(cfg, calib))
    services_cfg = msgspec.structs.replace(services_cfg, zenoh=local_peers(cfg.zenoh))

    cfg = msgspec.structs.replace(cfg, trust=services_cfg.trust)  # its live view verifies too
    cfg_path.write_text(dump_toml(services_cfg))
    from ovis.services.supervisor import STANDBY, Supervisor

    fleet = Supervisor(log_dir, max_restarts=max_restarts)
    stop = stop_on_signals()
    renderer = ""
    if physical:
        renderer = (
            f" (the physical world's capture on {','.join(map(str, off_path_cpus(cpus))) or 'any'})"
        )
    print(
        f"ovis up: arena {topics.arena}, router {listen}, frame path on cores "
        f"{','.join(map(str, cpus)) or 'any'}{renderer}, logs in {log_dir}",
        file=out,
    )
    if recorded:
        print(f"ovis up: {recorded}", file=out)
    fleet.start("router", ["router", "--listen", listen])
    try:
        _wait_router(fleet, listen, stop)
    except UserError:
        fleet.stop()
        raise
    if view:
        from ovis.services.cli.view import DEFAULT_LISTEN

        # the configuration `ovis up` runs with (its [navigation] timeouts judge the
        # robots' drives on the page, its Zenoh settings reach the router), as a client
        # of the router: not a peer the capture would send frames to directly
        view_cfg = log_dir / "view.toml"
        view_cfg.write_text(dump_toml(cfg))
        view_args = ["view", "--config", str(view_cfg), "--connect", listen,
                     "--arena", topics.arena, "--trust", cfg.trust.keys_dir]  # fmt: skip
        fleet.start("view", [*view_args, *off_path_option(cpus)])
        where = os.environ.get("OVIS_VIEW_LISTEN", DEFAULT_LISTEN)
        print(f"ovis up: live view on http://{where}/ (log: {log_dir / 'view.log'})", file=out)

    def start(stage: str) -> None:
        where = cpus_option(stage, cpus)
        if physical and stage == "capture":  # the renderer is the camera: off the path
            where = off_path_option(cpus)
        args = ["run", stage, "--config", str(cfg_path), *where]
        fleet.start(stage, args, standby=stage in STANDBY, spare_cpus=off_path_cpus(cpus))

    downstream = ("calibrator", "pose", "label", "preprocess")
    for stage in downstream:
        start(stage)
    if ros2:
        fleet.start("ros2", ["run", "ros2", "--config", str(cfg_path), *off_path_option(cpus)])
        downstream = (*downstream, "ros2")
    if drive:
        fleet.start("planner", ["run", "planner", "--config", str(cfg_path),
                                *off_path_option(cpus)])  # fmt: skip
        downstream = (*downstream, "planner")
    if record is not None:
        fleet.start("recorder", ["record", "--connect", listen, "--arena", topics.arena,
                                 "--out", str(record)])  # fmt: skip
        downstream = (*downstream, "recorder")
    summary = _run(fleet, topics, cfg, listen, downstream, stop, start, log_dir,
                   duration=duration, live=live, json=json, drive=drive,
                   first_frame_s=PHYSICAL_OPEN_S if physical else 0.0)  # fmt: skip
    if json:
        sys.stdout.write(msgspec.json.encode(summary).decode() + "\n")
    else:
        from rich.console import Console

        from ovis.services.cli.watching import summary_table

        Console(highlight=False).print(summary_table(summary))
    if summary.exit_code:
        raise UserError(f"{summary.reason}; see the logs in {log_dir}", summary.exit_code)


#: How long the router may take to say it listens.
ROUTER_START_S = 10.0


def _wait_router(fleet, listen: str, stop) -> None:
    """Wait until the router says it listens; exit 2 when it dies first (its endpoint
    was taken after the check, or cannot be listened on) or has not said so within
    :data:`ROUTER_START_S`."""
    log = fleet.log_dir / "router.log"
    deadline = time.monotonic() + ROUTER_START_S
    while not stop.is_set():
        text = log.read_text(errors="replace") if log.exists() else ""
        if LISTENING in text:
            return
        if time.monotonic() >= deadline:
            raise UserError(
                f"the router did not say it listens on {listen} within {ROUTER_START_S:g} s "
                f"(its log: {log}); try again, or see why it is stuck in that log"
            )
        if fleet.children["router"].proc.poll() is not None:
            last = (text.strip().splitlines()[-1:] or ["(no output)"])[0]
            raise UserError(
                f"the router could not listen on {listen} ({last.removeprefix('error: ')}); "
                "give --listen tcp/127.0.0.1:PORT with a free port"
            )
        stop.wait(0.05)


#: How long the physical world's capture may take to build its world and deliver its
#: first frame before `ovis up --duration` counts anyway.
PHYSICAL_OPEN_S = 60.0


def _wait_first_frame(fleet, score, limit_s: float, stop) -> None:
    """Wait (supervising) until the first frame's truth or obstacles came, at most
    ``limit_s``."""
    deadline = time.monotonic() + limit_s
    while not stop.is_set() and time.monotonic() < deadline:
        if score.truth_frames or score.frames:
            return
        fleet.supervise()
        stop.wait(0.1)


def _run(fleet, topics, cfg, listen, downstream, stop, start, log_dir, *, duration, live, json,
         first_frame_s: float = 0.0, drive: bool = False):  # fmt: skip
    """Run the started system until ``stop`` or ``duration``: the capture once the other
    stages listen (``duration`` counted from its first frame when ``first_frame_s``
    says how long that may take), the live view, the supervision; then stop it and sum
    up (only this run's processes and frames; ``drive``: with the driven robots' last
    reports)."""
    from ovis.common.analysis.live import heights_basis, navigation_run, with_verdict
    from ovis.common.config import ZenohConfig
    from ovis.services.bus import open_session
    from ovis.services.cli.watching import LiveView
    from ovis.services.cpu import CpuWindow

    live_view = LiveView(topics, cfg, accept=fleet.owns)
    drives: dict = {}
    started = time.monotonic()
    statuses: dict = {}
    cpu = CpuWindow(fleet.pids)
    try:
        with open_session(ZenohConfig(connect=[listen])) as session:
            live_view.attach(session)
            if drive:
                session.declare_subscriber(topics.drives_all, lambda s: _keep_drive(drives, s))
            # Frames only once every stage listens: none is captured and then missed.
            waiting = _wait_listening(fleet, session, topics, downstream, stop)
            if waiting and not stop.is_set():
                print(
                    f"ovis up: {', '.join(sorted(waiting))} not listening after {STARTUP_S:g} s; "
                    f"starting the capture anyway (see their logs in {log_dir})",
                    file=sys.stderr,
                )
            if not stop.is_set():
                start("capture")
            if first_frame_s:  # a source that takes a while to open: from its first frame
                _wait_first_frame(fleet, live_view.score, first_frame_s, stop)
            # --duration counts from here: a slow start (a loaded machine) takes no frames away.
            stop_polling = _poll_counters(fleet, session, topics)
            live_view.run(
                stop,
                until=(time.monotonic() + duration) if duration is not None else None,
                live=live and not json,
                supervise=lambda: _read_cpu(cpu, live_view.score.frames, fleet.supervise()),
                quiet=json,
            )
            cpu.read(live_view.score.frames)
            stop_polling()
            # the frames processed, then the capture's count: never more processed than captured
            live_view.score.close()
            statuses = live_view.poll_status(session)
            fleet.record(statuses)
    finally:
        codes = fleet.stop(sources=("capture",))  # what it captured is still processed
    summary = live_view.score.summary(
        statuses,
        codes,
        time.monotonic() - started,
        fleet.restarts(),
        fleet.totals(),
        streams=fleet.streams("capture"),
    )
    summary = msgspec.structs.replace(
        summary,
        heights=heights_basis(cfg.pose),
        cpu=cpu.summary() if cpu.opened else None,
        navigation=navigation_run(drives) if drive else None,
    )
    return with_verdict(summary, statuses.get("capture"), fleet.failures(codes))


def _keep_drive(drives: dict, sample: Any) -> None:
    """Keep each robot's newest drive report (the world's, unsigned: what it says about
    the run is shown, never acted on)."""
    from ovis.common.messages import MessageError, RobotDrive, decode

    try:
        report = decode(sample.payload.to_bytes(), RobotDrive)
    except MessageError:
        return
    drives[report.robot_id] = report


#: The processes' CPU time is counted from this long after the first obstacle frame (the
#: stages' first frames, first calls and first messages, are the start-up's).
CPU_AFTER_S = 1.0


def _read_cpu(cpu, frames: int, news: list[str]) -> list[str]:
    """At each tick of the live view, the CPU window's (:data:`CPU_AFTER_S` after the
    first frame); ``news`` passed through."""
    cpu.tick(frames, after_s=CPU_AFTER_S)
    return news


def _poll_counters(fleet, session, topics, period_s: float = 1.0) -> Callable[[], None]:
    """Every ``period_s`` until the function returned is called, give the supervisor the
    stages' statuses (a thread): their counters then survive a restart in its totals.
    The function returns once the thread recorded its last statuses (an older one
    recorded after the final count would lower it)."""
    import zenoh

    from ovis.services.cli.watching import query_statuses

    done = threading.Event()

    def poll() -> None:
        while not done.wait(period_s):
            try:
                fleet.record(query_statuses(session, topics, timeout=period_s, accept=fleet.owns))
            except zenoh.ZError:  # the session is closing
                return

    thread = threading.Thread(target=poll, name="status-poll", daemon=True)
    thread.start()

    def stop() -> None:
        done.set()
        thread.join()

    return stop


def _wait_listening(fleet, session, topics, stages: tuple[str, ...], stop) -> set[str]:
    """Wait until every stage's liveliness token is up (or ``STARTUP_S``, or ``stop``),
    restarting what dies meanwhile; the stages still not listening."""
    from ovis.services.cli.watching import alive_services

    deadline = time.monotonic() + STARTUP_S
    waiting = set(stages)
    while not stop.is_set() and time.monotonic() < deadline:
        fleet.supervise()
        waiting = set(stages) - alive_services(session, topics, timeout=0.5)
        if not waiting:
            break
        stop.wait(0.1)
    return waiting


def watch(
    connect: ConnectOpt = None,
    config: ConfigOpt = None,
    arena: ArenaOpt = None,
    json: JsonOpt = False,
    count: Annotated[int | None, typer.Option(min=1, help="Stop after N frames.")] = None,
    duration: Annotated[float | None, typer.Option(min=0.0, help="Stop after S seconds.")] = None,
    timeout: ConnectTimeoutOpt = CONNECT_S,
    trust: TrustOpt = None,
) -> None:
    """Subscribe to the obstacle topic and print each frame's objects and planner inputs.

    Only messages signed by the pose stage's key (--trust) are shown: the others are
    dropped and counted, and a line on stderr says how many and why (docs/trust.md).

    Also follows the pose service's health topic: when frames stop, it says "no data"
    (instead of going quiet). With --json, one JSON object per line, as published:
    "type" is "obstacles" for a frame, "health" for the stream's state. With no router
    answering within --timeout: exit code 4 and why. Ctrl-C or SIGTERM ends it at any
    moment, also while it waits for the router.
    """
    stop = stop_on_signals()  # first: nothing below may block before it is in place
    from ovis.common.messages import ObstacleFrame, StreamHealth, decode
    from ovis.services.bus import client_session
    from ovis.services.cli.watching import UnprovenCount, format_health, format_obstacles
    from ovis.services.inbox import Inbox
    from ovis.services.trust import unproven, verifier_for

    cfg = with_trust(config_with_options(config, connect=connect, arena=arena), trust)
    topics = arena_topics(cfg)
    verifier = verifier_for(cfg, "pose")
    dropped = UnprovenCount("the pose stage")
    box = Inbox(depth=64)
    seen = 0
    deadline = time.monotonic() + duration if duration is not None else None

    def on_sample(sample: Any) -> None:
        payload = sample.payload.to_bytes()
        problem = unproven(verifier, sample, payload)
        if problem is None:
            box.put(payload)
        else:
            dropped.add(problem)

    with client_session(cfg.zenoh, timeout, stop) as session:
        if session is None:  # stopped while waiting for the router
            return
        session.declare_subscriber(topics.obstacles, on_sample)
        session.declare_subscriber(topics.health, on_sample)
        while not stop.is_set() and (count is None or seen < count):
            if deadline is not None and time.monotonic() > deadline:
                break
            if line := dropped.line():
                print(f"ovis watch: {line}", file=sys.stderr, flush=True)
            payload = box.get(0.2)
            if payload is None:
                continue
            try:
                msg = decode(payload, ObstacleFrame | StreamHealth)
            except ValueError as exc:
                print(f"skipped a bad message: {exc}", file=sys.stderr)
                continue
            if json:
                sys.stdout.write(msgspec.json.encode(msg).decode() + "\n")
            elif isinstance(msg, ObstacleFrame):
                sys.stdout.write(format_obstacles(msg) + "\n")
            elif msg.state != "ok":
                sys.stdout.write(format_health(msg) + "\n")
            seen += isinstance(msg, ObstacleFrame)
            sys.stdout.flush()
    if line := dropped.line(final=True):
        print(f"ovis watch: {line}", file=sys.stderr, flush=True)


def recalibrate(
    connect: ConnectOpt = None,
    config: ConfigOpt = None,
    arena: ArenaOpt = None,
    frame: Annotated[int | None, typer.Option(min=0, help="Frame sequence number.")] = None,
    seed: Annotated[int | None, typer.Option(min=0, help="GA seed.")] = None,
    timeout: Annotated[
        float, typer.Option(min=0.1, help="Seconds to wait for the calibration.")
    ] = 60.0,
    json: JsonOpt = False,
    cancel: Annotated[
        bool, typer.Option("--cancel", help="Cancel the calibration that runs instead.")
    ] = False,
    connect_timeout: Annotated[
        float,
        typer.Option(
            "--connect-timeout",
            min=0.1,
            help="Seconds to wait for a router to answer; then exit code 4 with the reason.",
        ),
    ] = CONNECT_S,
    force: Annotated[
        bool,
        typer.Option(
            "--force",
            help="Publish even if unlike the current calibration (the camera moved); "
            "a DIPE above 3 px or a calibration that sees nothing is still refused.",
        ),
    ] = False,
    camera: Annotated[
        str | None,
        typer.Option(help="One camera of several ([[cameras]]): its calibrator is asked."),
    ] = None,
) -> None:
    """Ask the calibrator (a Zenoh query) to recalibrate on the latest frame, or --frame.

    Shows the new calibration's DIPE, parameters and version. A new calibration much
    worse than the current one (DIPE), or that does not see the objects the current one
    sees where it sees them, is refused (exit code 3, the reason) and kept aside in the
    state folder's rejected/; --force publishes it when the camera really moved. While a
    calibration runs, the calibrator answers at once that it is busy (progress and ETA);
    --cancel stops it.
    With no router answering within --connect-timeout: exit code 4. Ctrl-C or SIGTERM ends it at any
    moment (exit code 130).
    """
    stop = stop_on_signals()  # first: nothing below may block before it is in place
    from ovis.common.calibration.file import dipe_text
    from ovis.common.messages import CalibrateReply, CalibrateRequest, decode, encode
    from ovis.services.bus import client_session, interruptible

    cfg = config_with_options(config, connect=connect, arena=arena)
    topics = arena_topics(cfg)
    if camera is not None:
        try:
            topics = topics.of_camera(camera)
        except ValueError as exc:
            raise UserError(f"--camera: {exc}") from None
    request = encode(CalibrateRequest(frame_seq=frame, seed=seed, cancel=cancel, force=force))
    with client_session(cfg.zenoh, connect_timeout, stop) as session:
        replies = (
            None
            if session is None
            else interruptible(
                stop, lambda: list(session.get(topics.calibrate, payload=request, timeout=timeout))
            )
        )
    if replies is None:
        raise UserError("interrupted before the calibrator answered", 130)
    if not replies:
        raise UserError(
            f"no calibrator is alive on {topics.calibrate} (connect: "
            f"{', '.join(cfg.zenoh.connect)}); start one with `ovis run calibrator`"
            + (
                ", or use credentials the router's access control lets query it"
                if cfg.zenoh.config_file
                else ""
            )
        )
    reply = replies[0]
    if reply.ok is None:
        raise UserError(f"the calibrator did not answer: {reply.err.payload.to_bytes().decode()}")
    answer = decode(reply.ok.payload.to_bytes(), CalibrateReply)
    if json:
        sys.stdout.write(msgspec.json.encode(answer).decode() + "\n")
    if cancel:
        print(answer.error, file=sys.stderr)
        return
    if not answer.ok:
        raise UserError(f"recalibration failed: {answer.error}", 3)
    if not json:
        print(
            f"calibration v{answer.version} on frame {answer.frame_seq}: DIPE "
            f"{dipe_text(answer.dipe_px, answer.dipe_mm)} (max {answer.dipe_max_px:.3f} px)"
            f" in {answer.elapsed_s:.2f} s; saved to {answer.saved_to}"
        )
        for name, value in answer.parameters.items():
            print(f"  {name:16s} {value:.6g}")


def status(
    connect: ConnectOpt = None,
    config: ConfigOpt = None,
    arena: ArenaOpt = None,
    json: JsonOpt = False,
    timeout: ConnectTimeoutOpt = CONNECT_S,
) -> None:
    """Which services are alive (Zenoh liveliness), their frame rates, drops and errors.

    With no router answering within --timeout: exit code 4 and why. Ctrl-C or SIGTERM
    ends it at any moment (exit code 130)."""
    stop = stop_on_signals()  # first: nothing below may block before it is in place
    from ovis.services.bus import client_session, interruptible
    from ovis.services.cli.watching import arena_status, status_table

    cfg = config_with_options(config, connect=connect, arena=arena)
    topics = arena_topics(cfg)
    with client_session(cfg.zenoh, timeout, stop) as session:
        report = (
            None if session is None else interruptible(stop, lambda: arena_status(session, topics))
        )
    if report is None:
        raise UserError("interrupted before the services answered", 130)
    if json:
        sys.stdout.write(msgspec.json.encode(report).decode() + "\n")
        return
    from rich.console import Console

    Console(highlight=False).print(status_table(report, topics))


def schema() -> None:
    """Print the JSON Schema of every ovis message (MessagePack maps on the wire)."""
    from ovis.common.messages import message_schema

    sys.stdout.write(msgspec.json.format(msgspec.json.encode(message_schema()), indent=2).decode())
    sys.stdout.write("\n")


def register(app: typer.Typer) -> None:
    for command in (router, run, up, watch, recalibrate, status, schema):
        app.command()(command)
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
