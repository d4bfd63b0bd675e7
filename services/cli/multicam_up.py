"""``ovis up --cameras 2x2``: the simulated camera grid end to end (issue 19,
docs/cameras.md). A router, the capture → preprocess → label → pose stages of every
camera (each camera on its own topics ``ovis/<arena>/cam/<name>/…`` and with its own
camera model) and the fusion service; the supervisor restarts what dies. The
processes are laid out as ``[service] layout`` (``--layout``) says: "per-stage", one
process per stage serving every camera (issue 38), or "per-camera", one process per
stage per camera. The summary scores the world against the simulated truth: only world
frames with the fusion key's proof of origin; the others are counted and said
(docs/trust.md)."""

from __future__ import annotations

import contextlib
import signal
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import msgspec

from ovis.services.cli.errors import UserError
from ovis.services.cpu import READ_EVERY_S, CpuWindow
from ovis.services.stopping import stop_on

__all__ = ["CHAIN", "Process", "chain_cores", "plan", "stage_cores", "up_cameras"]

#: the stages of one camera's chain, started downstream first
CHAIN = ("pose", "label", "preprocess", "capture")
ROBOTS, OBSTACLES = 4, 10  # the scene
#: seconds the cameras may take to prerender their period before the run goes on anyway
PRERENDER_S = 180.0
#: seconds the processes get to stop cleanly, on a loaded host too
STOP_S = 15.0
#: seconds after every camera runs that are the start-up (each chain's first frames,
#: first calls and first messages on each route, come while the last cameras start):
#: its frames are counted apart (``startup`` in the summary) and the world is scored after
STARTUP_SETTLE_S = 1.0


@dataclass(frozen=True)
class Process:
    """One stage process of the run: the supervisor's name for it, its stage, the
    cameras it serves and its cores ([]: any)."""

    name: str
    stage: str
    cameras: tuple[str, ...]
    cores: tuple[int, ...]


def chain_cores(allowed: list[int], cameras: int, pin: str) -> list[list[int]]:
    """Cores of each camera's chain (per-camera layout): ``auto`` puts each chain whole
    on one core, the chains dealt round the cores this process may use (a chain's
    stages hand frames to each other: on one core each wakes where the previous one
    ran; separate chains do not wait on each other, so they share out the cores);
    ``none``: any core; core numbers: every chain on those."""
    spec = pin.strip().lower()
    if spec == "none":
        return [[] for _ in range(cameras)]
    if spec == "auto":
        if len(allowed) < 2:
            return [[] for _ in range(cameras)]
        return [[allowed[k % len(allowed)]] for k in range(cameras)]
    return [_cores(spec) for _ in range(cameras)]


def stage_cores(allowed: list[int], pin: str) -> dict[str, list[int]]:
    """Cores of each stage process (per-stage layout): ``auto`` puts label, the costliest
    stage, alone on the last core and the others (capture, preprocess, pose, fusion) on
    the one before, so that the cameras' frames pipeline across the two (label works on
    one camera's frame while the next camera's is preprocessed and the previous one's
    pose found); ``none``: any core; core numbers: every stage on those."""
    spec = pin.strip().lower()
    stages = [*CHAIN, "fusion"]
    if spec == "none" or (spec == "auto" and len(allowed) < 2):
        return {stage: [] for stage in stages}
    if spec == "auto":
        return {stage: [allowed[-1 if stage == "label" else -2]] for stage in stages}
    return dict.fromkeys(stages, _cores(spec))


def _cores(spec: str) -> list[int]:
    from ovis.services.placement import pick_cpus

    try:
        return pick_cpus(spec)
    except ValueError as exc:
        raise UserError(str(exc), 2) from None


def plan(names: list[str], layout: str, pin: str, allowed: list[int]) -> list[Process]:
    """The stage processes of the run, downstream first (the captures last), and where
    each runs; fusion comes first."""
    if layout == "per-stage":
        cores = stage_cores(allowed, pin)
        return [Process("fusion", "fusion", tuple(names), tuple(cores["fusion"]))] + [
            Process(stage, stage, tuple(names), tuple(cores[stage])) for stage in CHAIN
        ]
    from ovis.services.placement import pick_cpus

    fusion = Process("fusion", "fusion", tuple(names), tuple(pick_cpus(pin)))  # auto: last
    chains = chain_cores(allowed, len(names), pin)
    return [fusion] + [
        Process(f"{name}-{stage}", stage, (name,), tuple(where))
        for stage in CHAIN
        for name, where in zip(names, chains, strict=True)
    ]


def _where(processes: list[Process], layout: str) -> str:
    """Where the processes run, said at start."""
    if layout == "per-stage":
        shown = [(p.stage, p.cores) for p in processes]
    else:  # a camera's chain shares its cores
        shown = [(p.cameras[0], p.cores) for p in processes if p.stage == "capture"]
        shown.append(("fusion", processes[0].cores))
    return ", ".join(f"{n} on {','.join(map(str, c)) or 'any'}" for n, c in shown)


def _configs(
    grid: tuple[int, int],
    base: Any,
    log_dir: Path,
    calibrated: dict[str, tuple[Any, str]] | None = None,
) -> tuple[Path, list[str]]:
    """Write the arena's configuration (every camera of the grid in ``[[cameras]]``, its
    source and its known simulated model); its path and the cameras' names. Each stage
    process takes its cameras' part of it (``ovis run STAGE --cameras …``)."""
    from ovis.common.config import CameraSpec, dump_toml
    from ovis.common.sim.gridview import grid_specs
    from ovis.services.bus import local_peers

    nx, ny = grid
    specs = grid_specs(nx, ny, base, base.service.seed)
    shared = msgspec.structs.replace(base, zenoh=local_peers(base.zenoh))
    cameras = []
    for spec in specs:
        # each camera works with its known simulated model, or (the physical world) with
        # the camera ``calibrated`` gives it and that camera's empty floor as background
        camera, background = spec.camera, None
        if calibrated is not None:
            camera, background = calibrated[spec.name]
        source = f"grid:{nx}x{ny}:{spec.name}"
        cameras.append(
            CameraSpec(name=spec.name, source=source, camera=camera, background=background)
        )
    arena = msgspec.structs.replace(shared, cameras=cameras)
    path = log_dir / "arena.toml"
    path.write_text(dump_toml(msgspec.to_builtins(arena)))
    return path, [s.name for s in specs]


def up_cameras(
    grid_text: str,
    *,
    config: Path | None,
    listen: str,
    duration: float | None,
    json: bool,
    seed: int,
    fps: float | None,
    max_restarts: int,
    pin: str,
    world: str | None = None,
    layout: str | None = None,
) -> None:
    """Run the simulated ``grid_text`` (e.g. "2x2") camera grid end to end (module
    docstring) until ``duration`` s of frames or Ctrl-C, and print the summary; with
    ``world`` "physical", over the physical world, each camera calibrated on the floor
    marks it sees before it starts."""
    import os

    from ovis.common.config import ConfigError, with_options
    from ovis.common.messages import Topics
    from ovis.common.sim.scenes import marked_scene
    from ovis.services.cli.cameras import parse_grid
    from ovis.services.cli.physical import require_physical, world_options
    from ovis.services.cli.startup import with_keys
    from ovis.services.supervisor import Supervisor

    grid = parse_grid(grid_text)
    try:
        base = with_options(
            config,
            connect=[listen],
            seed=seed,
            fps=fps,
            layout=layout,
            **world_options(config, world),
        )
        physical = base.simulator.world == "physical"
        if physical:
            require_physical()
        base = with_keys(marked_scene(base, ROBOTS, OBSTACLES))
        topics = Topics(base.service.arena)
        log_dir = Path(tempfile.mkdtemp(prefix="ovis-up-cameras-"))
        arena_cfg, names = _configs(grid, base, log_dir)
    except (ValueError, ConfigError) as exc:
        raise UserError(str(exc)) from None
    layout = base.service.layout
    processes = plan(names, layout, pin, sorted(os.sched_getaffinity(0)))
    out = sys.stderr if json else sys.stdout
    print(
        f"ovis up: {grid_text} cameras over arena {topics.arena} (seed {base.service.seed}), "
        f"router {listen}; {layout} layout, {len(processes)} stage processes: "
        f"{_where(processes, layout)}; logs in {log_dir}",
        file=out,
        flush=True,
    )
    fleet = Supervisor(log_dir, max_restarts=max_restarts)
    stop = stop_on(signal.SIGTERM, signal.SIGINT)
    workers = max(1, len(os.sched_getaffinity(0)))
    calibrated = _prerender(arena_cfg, names, grid, workers, out, stop)
    if physical and not stop.is_set():
        arena_cfg, names = _configs(grid, base, log_dir, calibrated)
        print(f"ovis up: the physical world (seed {base.service.seed}): each camera "
              "calibrated on the floor marks it sees, segmented against its empty floor",
              file=out)  # fmt: skip
    fleet.start("router", ["router", "--listen", listen])
    time.sleep(0.5)

    from ovis.services.placement import off_path_cpus
    from ovis.services.supervisor import STANDBY

    def start(p: Process) -> None:
        args = ["run", p.stage, "--config", str(arena_cfg)]
        if p.stage != "fusion":
            args += ["--cameras", ",".join(p.cameras)]
        # one process per stage: a spare each for the frame path's is few (per camera,
        # twelve idle interpreters would be kept)
        spare = layout == "per-stage" and p.stage in STANDBY
        fleet.start(p.name, [*args, "--cpus", ",".join(map(str, p.cores)) or "none"],
                    standby=spare, spare_cpus=off_path_cpus(list(p.cores)))  # fmt: skip

    captures = [p for p in processes if p.stage == "capture"]
    for p in processes:
        if p.stage != "capture":
            start(p)
    from ovis.common.config import ZenohConfig
    from ovis.services.bus import local_peers, open_session

    run, started = _Run(names, grid, base, topics, processes), time.monotonic()
    try:
        # a loopback peer, as the services: the summary's messages come straight from
        # their stages, not through the router (which then relays nothing on this host)
        with open_session(local_peers(ZenohConfig(connect=[listen]))) as session:
            run.attach(session)
            # the cameras once every stage and fusion listen: no frame is lost at start
            late = _wait_alive(fleet, session, topics, names, stop)
            for p in captures:
                start(p)
            if late and not stop.is_set():
                print(f"ovis up: started the cameras though {', '.join(sorted(late))} did "
                      f"not listen yet (see {log_dir})", file=sys.stderr)  # fmt: skip
            _wait_prerendered(fleet, session, topics, names, stop, out)
            # the chains' first frames (first calls, first messages on each route, the
            # other cameras still starting) are the start-up: counted apart, not scored
            run.clock_from = time.time_ns() + int(STARTUP_SETTLE_S * 1e9)
            began = time.monotonic() + STARTUP_SETTLE_S
            until = f"for {duration:g} s" if duration is not None else "until Ctrl-C"
            print(f"ovis up: all {len(names)} cameras running; scoring the world {until} "
                  f"after {STARTUP_SETTLE_S:g} s of start-up", file=out, flush=True)  # fmt: skip
            cpu = CpuWindow(fleet.pids)
            while not stop.is_set():
                for news in fleet.supervise():
                    print(f"ovis up: {news}", file=sys.stderr)
                if line := run.unproven.line():
                    print(f"ovis up: {line}", file=sys.stderr, flush=True)
                if cpu.opened is None and time.monotonic() >= began:
                    cpu.open(run.world_frames)
                    run.cpu = cpu
                cpu.read(run.world_frames, every_s=READ_EVERY_S)
                if duration is not None and time.monotonic() - began >= duration:
                    cpu.read(run.world_frames)
                    break
                stop.wait(0.1)  # the supervisor's tick: a dead stage restarts this soon
            # the captures stop first; what is in flight reaches the world before the count
            for p in captures:
                proc = fleet.children[p.name].proc
                if proc is not None and proc.poll() is None:
                    proc.send_signal(signal.SIGTERM)
            time.sleep(1.0)
    finally:
        codes = fleet.stop(timeout=STOP_S)
    summary = run.summary(fleet, time.monotonic() - started)
    if json:
        sys.stdout.write(msgspec.json.encode(summary).decode() + "\n")
    else:
        _print_summary(summary)
    if summary["world"]["frames"] == 0:
        raise UserError(f"no world frame came out; see the logs in {log_dir}", 1)
    failures = fleet.failures(codes)
    if failures:
        raise UserError(f"{'; '.join(failures)}; see the logs in {log_dir}", 1)


class _Stamps(msgspec.Struct):
    """A truth or obstacle frame's stamps only (the rest of the message is skipped)."""

    stamp_ns: Annotated[int, msgspec.Meta(ge=0)] | None = None
    published_ns: Annotated[int, msgspec.Meta(ge=0)] | None = None


class _Run:
    """What the summary needs, subscribed: the world frames, the truth, and each
    camera's frames captured (its truth messages, one per frame its capture published)
    and processed (its pose's obstacle frames), whatever restarts meanwhile."""

    def __init__(
        self,
        names: list[str],
        grid: tuple[int, int],
        base: Any,
        topics: Any,
        processes: list[Process],
    ) -> None:
        from ovis.common.analysis.multicam import WorldWatch
        from ovis.common.sim.gridview import grid_specs
        from ovis.services.cli.watching import UnprovenCount
        from ovis.services.trust import verifier_for

        self.names, self.topics, self.base = names, topics, base
        self.processes = processes
        nx, ny = grid
        specs = grid_specs(nx, ny, base, base.service.seed)
        self.grid = f"{nx}x{ny}"
        self.watch = WorldWatch({s.name: s.camera for s in specs})
        # each camera's frames captured and processed: [in the start-up, after it] (the
        # grid's cameras share their stamps, so a frame is the start-up's exactly when
        # its world frame is)
        self.captured = {n: [0, 0] for n in names}
        self.processed = {n: [0, 0] for n in names}
        self.chain_ms: list[float] = []  # capture stamp → a camera's pose published
        # frames stamped before this are the start-up's: not scored, counted apart (set,
        # in the future, once every camera runs)
        self.clock_from = sys.maxsize
        # world frames without the fusion key's proof: never scored, counted and said
        self.verifier = verifier_for(base, "fusion")
        self.unproven = UnprovenCount("the fusion service")
        self.world_frames = 0  # proven world frames received
        self.cpu: CpuWindow | None = None  # the processes' CPU while every camera runs

    def attach(self, session: Any) -> None:
        from ovis.common.messages import (
            MessageError,
            TruthFrame,
            WorldFrame,
            decode,
        )
        from ovis.services.trust import unproven

        def on_world(sample: Any) -> None:
            now = time.time_ns()
            payload = sample.payload.to_bytes()
            if problem := unproven(self.verifier, sample, payload):
                self.unproven.add(problem)
                return
            with contextlib.suppress(MessageError):
                self.watch.add_world(decode(payload, WorldFrame), now)
                self.world_frames += 1

        # Zenoh calls one subscriber's callback at a time: the counts need no lock. Each
        # camera's truth holds the whole floor: it is read whole once per stamp; of the
        # rest, and of the obstacle frames, only the stamps (the summary's subscriber
        # shares the cores with what it measures)
        def on_truth(sample: Any, name: str) -> None:
            with contextlib.suppress(MessageError):
                payload = sample.payload.to_bytes()
                stamp = decode(payload, _Stamps).stamp_ns
                stamp = time.time_ns() if stamp is None else stamp
                self.captured[name][stamp >= self.clock_from] += 1
                if not self.watch.has_truth(stamp):
                    self.watch.add_truth(decode(payload, TruthFrame))

        def on_obstacles(sample: Any, name: str) -> None:
            with contextlib.suppress(MessageError):
                frame = decode(sample.payload.to_bytes(), _Stamps)
                if frame.stamp_ns is None or frame.published_ns is None:
                    return
                self.processed[name][frame.stamp_ns >= self.clock_from] += 1
                if frame.stamp_ns >= self.clock_from:
                    self.chain_ms.append((frame.published_ns - frame.stamp_ns) / 1e6)

        session.declare_subscriber(self.topics.world, on_world)
        for name in self.names:
            cam = self.topics.of_camera(name)
            session.declare_subscriber(cam.truth, lambda s, n=name: on_truth(s, n))
            session.declare_subscriber(cam.obstacles, lambda s, n=name: on_obstacles(s, n))

    def summary(self, fleet: Any, elapsed_s: float) -> dict[str, Any]:
        import numpy as np

        from ovis.common.analysis.live import heights_basis
        from ovis.common.analysis.multicam import CameraRun, percentiles

        score, latency, scored = self.watch.score(self.clock_from)
        fused, late = self.watch.fused(self.clock_from), self.watch.late(self.clock_from)
        fused_ever = self.watch.fused()
        restarts = fleet.restarts()
        cameras, startup = {}, {}
        for name in self.names:
            (early, captured), (_, processed) = self.captured[name], self.processed[name]
            cameras[name] = CameraRun(
                captured=captured,
                processed=processed,
                fused=fused.get(name, 0),
                late=late.get(name, 0),
                dropped=max(0, captured - fused.get(name, 0)),
                # restarts of the processes that serve it (in the per-stage layout, each
                # stage's one process serves every camera)
                restarts=sum(
                    restarts.get(p.name, 0)
                    for p in self.processes
                    if p.stage != "fusion" and name in p.cameras
                ),
            )
            early_fused = fused_ever.get(name, 0) - fused.get(name, 0)
            startup[name] = {"captured": early, "dropped": max(0, early - early_fused)}
        return {
            "grid": self.grid,
            "seed": self.base.service.seed,
            "layout": self.base.service.layout,
            "processes": len(self.processes) + 1,  # the stages, fusion and the router
            "elapsed_s": round(elapsed_s, 2),
            "cameras": msgspec.to_builtins(cameras),
            # the first STARTUP_SETTLE_S after every camera ran (chains warming up)
            "startup": {"seconds": STARTUP_SETTLE_S, "cameras": startup},
            "world": {
                "frames": self.watch.frames(),
                "scored": scored,
                "duplicates": score.duplicates,
                "identity_swaps": score.identity_swaps,
                "missed": score.missed,
                "phantoms": score.phantoms,
                "handovers": score.handovers,
                "handover_jump_cm": score.handover_jump_cm,
                "world_error_cm": {
                    "mean": score.world_error_cm_mean,
                    "max": score.world_error_cm_max,
                },
                # the fused top heights less the true ones, and what they rest on
                "height_error_cm": {
                    "mean": score.height_error_cm_mean,
                    "max": score.height_error_cm_max,
                },
                "heights": heights_basis(self.base.pose),
                # by what each fused height rests on ("cameras": two or more cameras'
                # fits merged): [count, mean, max] cm
                "height_error_by_source_cm": score.height_error_by_source_cm,
                "latency_ms": latency,
                # world frames refused for want of the fusion key's proof, and the last why
                "unproven": self.unproven.n,
                "unproven_why": self.unproven.why,
            },
            # where the time goes: capture → each camera's pose published (its chain),
            # → the world published by fusion (chains, the wait for the slowest, merging)
            "stages_ms": {
                "capture_to_pose": percentiles(np.asarray(self.chain_ms, float)),
                "capture_to_world_published": self.watch.published_ms(self.clock_from),
            },
            "restarts": {"fusion": restarts.get("fusion", 0)},
            "gave_up": fleet.gave_up(),
            # the CPU time of the run's processes per world frame received, from /proc,
            # from the end of the start-up until the cameras stop; ovis up's own apart
            "cpu": msgspec.to_builtins(self.cpu.summary()) if self.cpu is not None else None,
        }


def _wait_alive(fleet: Any, session: Any, topics: Any, names: list[str], stop: Any) -> set[str]:
    """Wait until fusion and every camera's downstream stages listen (or 30 s)."""
    from ovis.services.cli.options import STARTUP_S
    from ovis.services.cli.watching import alive_services

    deadline = time.monotonic() + STARTUP_S
    waiting: set[str] = set()
    while not stop.is_set() and time.monotonic() < deadline:
        fleet.supervise()
        waiting = {"fusion"} - alive_services(session, topics, 0.5)
        for name in names:
            alive = alive_services(session, topics.of_camera(name), 0.5)
            waiting |= {f"{name}-{s}" for s in CHAIN[:-1] if s not in alive}
        if not waiting:
            break
        stop.wait(0.2)
    return waiting


def _render_period(
    config_path: str, grid: tuple[int, int], name: str
) -> tuple[dict[str, Any], str] | None:
    """One camera's period rendered into the cache (in a worker process); over the
    physical world, also the camera calibrated on its floor marks and its empty floor,
    written beside its configuration: (the camera, the floor's path)."""
    from ovis.common.capture.sources import grid_cache_dir
    from ovis.common.config import load_config
    from ovis.common.pipeline.hosting import camera_config
    from ovis.common.sim.gridview import GridCamera

    cfg = camera_config(load_config(Path(config_path)), name)
    if cfg.simulator.world != "physical":
        GridCamera(cfg, *grid, name, cfg.service.seed).render_period(None, grid_cache_dir())
        return None
    from ovis.common.analysis.plots import save_png
    from ovis.common.physical.grid import PhysicalGridCamera, calibrate_grid_camera

    camera = PhysicalGridCamera(cfg, *grid, name, cfg.service.seed)
    try:
        camera.render_period(None, grid_cache_dir())
        calib, floor = calibrate_grid_camera(camera)
    finally:
        camera.close()
    background = Path(config_path).with_name(f"{name}-background.png")
    save_png(background, floor)
    return msgspec.to_builtins(calib.camera), str(background)


def _prerender(
    arena: Path, names: list[str], grid: tuple[int, int], workers: int, out: Any, stop: Any
) -> dict[str, tuple[Any, str]] | None:
    """Render (or find in the cache) every camera's period before any camera runs, on
    ``workers`` processes, saying how far it is: a camera that started while others
    still rendered would lose frames to their rendering, and the cameras would not
    start together. Over the physical world: each camera calibrated on its floor marks
    and its empty floor (:func:`_render_period`), by name; else None."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from ovis.common.config import CameraModel

    began = time.monotonic()
    ctx = multiprocessing.get_context("spawn")  # no fork of this process's threads
    with ProcessPoolExecutor(max_workers=min(workers, len(names)), mp_context=ctx) as pool:
        jobs = [pool.submit(_render_period, str(arena), grid, n) for n in names]
        while not stop.is_set():
            done = sum(j.done() for j in jobs)
            if done == len(jobs):
                break
            took = time.monotonic() - began
            if took > 2.0:
                said = f"{done} of {len(jobs)} cameras done ({took:.0f} s)"
                print(f"ovis up: rendering the cameras' frames: {said}", file=out, flush=True)
            stop.wait(2.0)
        for job in jobs:
            if stop.is_set():
                job.cancel()
            elif job.exception() is not None:
                raise UserError(f"rendering the simulated cameras failed: {job.exception()}")
        if stop.is_set():
            return None
        made = {name: job.result() for name, job in zip(names, jobs, strict=True)}
    if any(v is None for v in made.values()):
        return None
    return {
        name: (msgspec.convert(camera, CameraModel), background)
        for name, (camera, background) in made.items()
    }


def _wait_prerendered(
    fleet: Any, session: Any, topics: Any, names: list[str], stop: Any, out: Any
) -> None:
    """Wait while the cameras prerender their period, saying how far they are."""
    from ovis.services.cli.watching import query_statuses

    deadline = time.monotonic() + PRERENDER_S
    said = ""
    while not stop.is_set() and time.monotonic() < deadline:
        fleet.supervise()
        states = {}
        for name in names:
            st = query_statuses(session, topics.of_camera(name), 1.0).get("capture")
            states[name] = st.state if st is not None else "starting"
        busy = {n: s for n, s in states.items() if s.startswith("prerendering") or s == "starting"}
        if not busy:
            return
        line = "ovis up: cameras " + ", ".join(f"{n} {s}" for n, s in busy.items())
        if line != said:
            print(line, file=out, flush=True)
            said = line
        stop.wait(1.0)


def _print_summary(summary: dict[str, Any]) -> None:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    con = Console(highlight=False)
    t = Table(title=f"cameras ({summary['grid']}, seed {summary['seed']})", title_justify="left")
    for col in ("camera", "captured", "processed", "fused", "late", "dropped", "restarts"):
        t.add_column(col, justify="right")
    for name, c in summary["cameras"].items():
        t.add_row(name, *(str(c[k]) for k in ("captured", "processed", "fused", "late",
                                              "dropped", "restarts")))  # fmt: skip
    con.print(t)
    up = summary["startup"]
    early = list(up["cameras"].values())
    con.print(
        f"start-up (the first {up['seconds']:g} s, not in the table): "
        f"{sum(c['captured'] for c in early)} frames captured, "
        f"{sum(c['dropped'] for c in early)} of them not in the world"
    )
    w = summary["world"]
    con.print(
        f"world: {w['frames']} frames ({w['scored']} scored), {w['duplicates']} duplicates, "
        f"{w['identity_swaps']} identity swaps, {w['missed']} missed, {w['phantoms']} phantoms; "
        f"hand-over jump max {w['handover_jump_cm']:.3f} cm over {w['handovers']} hand-overs; "
        f"error mean {w['world_error_cm']['mean']:.3f} cm, max {w['world_error_cm']['max']:.3f}"
        f" cm; latency capture → world p50 {w['latency_ms']['p50']:.1f} ms, p99 "
        f"{w['latency_ms']['p99']:.1f} ms"
    )
    dz = w["height_error_cm"]
    if dz["mean"] is not None:
        con.print(
            f"height error mean {dz['mean']:.3f} cm, max {dz['max']:.3f} cm (heights "
            f"{escape(w['heights'])})"
        )
        for source, (n, mean, top) in w["height_error_by_source_cm"].items():
            con.print(f"  {escape(source)}: {n:.0f} heights, error mean {mean:.3f} cm, "
                      f"max {top:.3f} cm")  # fmt: skip
    if w["unproven"]:
        con.print(
            f"[red]refused {w['unproven']} world frame(s) without the fusion service's proof "
            f"of origin (last: {escape(w['unproven_why'])})[/]"
        )
    if (cpu := summary["cpu"]) and cpu["ms_per_frame"] is not None:
        from ovis.common.analysis.live import CpuUse
        from ovis.services.cli.watching import format_cpu

        used = format_cpu(msgspec.convert(cpu, CpuUse))
        con.print(f"CPU per world frame, {summary['processes']} processes: {used}")
