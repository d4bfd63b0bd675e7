"""Several cameras fused into one world (issue 19), on the simulated 2×2 arena (4 robots,
10 obstacles, four 640×480 cameras):

* merge cost: one world frame in-process (each camera's detections as columns, then
  for the world frame: every camera's covariances and border tests in one pass,
  merging, identities), p50/p99; the floor is the frame period;
* live: the fusion service as a real process behind a router, fed each camera's
  detections at 30 frames/s per camera (simulated measurements published on
  ``ovis/<arena>/cam/<name>/obstacles`` as each camera's pose service would), camera
  stamp → world frame received by a subscriber; the floor is the same camera message
  received by that subscriber (one hop through the router, no fusion).

* end to end, an A/B of the two layouts in the same run (issue 38): ``ovis up --cameras
  2x2`` as a real process, one process per stage serving the four cameras (per-stage,
  the default) and one process per stage and camera (per-camera: the floor), three runs
  of each taking turns, the worst of each kept: all the processes' CPU time per world
  frame (from the run's own summary, read from /proc), capture stamp → world frame
  received by its summary's subscriber, p50 and p99, and the frames captured after the
  start-up that never reached the world. The cameras' period is prerendered (and
  cached) before the clock starts; the empty topology (``benchmarks/topology.py``) is
  said beside the latency.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import msgspec
import numpy as np
import zenoh

from benchmarks.bus import ARENA, Fleet, free_port, write_config
from benchmarks.core import Row, ratio, stats
from ovis.common.analysis.multicam import as_detections, detections_frame
from ovis.common.config import FusionConfig, ZenohConfig, load_config
from ovis.common.fusion.accuracy import AccuracyMap, detection_columns
from ovis.common.fusion.world import WorldFuser
from ovis.common.messages import ENCODING, ObstacleFrame, Topics, WorldFrame, decode, encode
from ovis.common.sim.multiview import GridScene, camera_grid, grid_arena, measure
from ovis.services.bus import zenoh_config
from ovis.services.cpu import tree_cpu
from ovis.services.trust import signer_for

__all__ = ["fusion_rows"]

PREFIX = "Fusion"
CELL = (100.0, 75.0)
SEED = 9190
FPS = 30.0


def _grid():
    specs = camera_grid(2, 2, cell_cm=CELL, seed=SEED)
    scene = GridScene(*grid_arena(2, 2, CELL), robots=4, obstacles=10, seed=SEED)
    return specs, scene


def _merge_cost(frames: int) -> tuple[float, float]:
    specs, scene = _grid()
    cfg = FusionConfig()
    rng = np.random.default_rng(SEED)
    maps = {s.name: AccuracyMap(s.camera, cfg.pixel_sigma_px) for s in specs}
    for m in maps.values():
        m.prepare(5.0, 7.0)  # robot and obstacle tops, as the service does at start
    fuser = WorldFuser([s.name for s in specs], cfg, stale_ns=10**9, views=maps,
                       robot_radius_cm=9.0)  # fmt: skip
    samples = []
    for f in range(frames):
        truth = scene.objects(f)
        dets = [as_detections(measure(s.camera, truth, 0.3, rng)) for s in specs]
        stamp = f * 33_333_333
        t0 = time.perf_counter()
        for s, found in zip(specs, dets, strict=True):
            fuser.add(s.name, stamp, detection_columns(s.name, found), stamp)
        samples.append((time.perf_counter() - t0) * 1e3)
    st = stats(samples[5:])
    return st.p50, st.p99


def _live(frames: int, log=print) -> tuple[list[float], list[float], int]:
    specs, scene = _grid()
    with tempfile.TemporaryDirectory(prefix="ovis-bench-fusion-") as tmp:
        work = Path(tmp)
        port = free_port()
        config = msgspec.structs.replace(
            load_config(),
            cameras=specs,
            fusion=msgspec.structs.replace(FusionConfig(), wait_ms=20.0),
        )
        cfg_file = write_config(work / "fusion.toml", config, port)
        # the cameras' pose stages sign what they publish: fusion believes only that
        signer = signer_for(load_config(cfg_file), "pose")
        fleet = Fleet(work)
        fleet.start("router", ["router", "--listen", f"tcp/127.0.0.1:{port}"])
        time.sleep(0.5)
        fleet.start("fusion", ["run", "fusion", "--config", str(cfg_file)])
        zc = zenoh_config(ZenohConfig(connect=[f"tcp/127.0.0.1:{port}"]))
        topics = Topics(ARENA)
        world_ms: list[float] = []
        hop_ms: list[float] = []
        lock = threading.Lock()

        def on_world(sample: zenoh.Sample) -> None:
            now = time.time_ns()
            msg = decode(sample.payload.to_bytes(), WorldFrame)
            with lock:
                world_ms.append((now - msg.stamp_ns) / 1e6)

        def on_hop(sample: zenoh.Sample) -> None:
            now = time.time_ns()
            msg = decode(sample.payload.to_bytes(), ObstacleFrame)
            with lock:
                hop_ms.append((now - msg.stamp_ns) / 1e6)

        try:
            with zenoh.open(zc) as sub, zenoh.open(zc) as pub_session:
                sub.declare_subscriber(topics.world, on_world)
                sub.declare_subscriber(topics.of_camera(specs[0].name).obstacles, on_hop)
                deadline = time.monotonic() + 60
                while not any(
                    r.ok is not None
                    for r in sub.liveliness().get(topics.alive("fusion"), timeout=1.0)
                ):
                    fleet.check("fusion")
                    if time.monotonic() > deadline:
                        raise RuntimeError("fusion not alive after 60 s")
                pubs = {
                    s.name: pub_session.declare_publisher(
                        topics.of_camera(s.name).obstacles, encoding=zenoh.Encoding(ENCODING)
                    )
                    for s in specs
                }
                rng = np.random.default_rng(SEED)
                start = time.monotonic()
                for f in range(frames):
                    truth = scene.objects(f)
                    seen = {s.name: measure(s.camera, truth, 0.3, rng) for s in specs}
                    stamp = time.time_ns()  # the cameras' common capture instant
                    for s in specs:
                        payload = encode(detections_frame(f, stamp, seen[s.name]))
                        key = topics.of_camera(s.name).obstacles
                        pubs[s.name].put(payload, attachment=signer.attachment(key, payload))
                    time.sleep(max(0.0, start + (f + 1) / FPS - time.monotonic()))
                time.sleep(0.5)
        finally:
            fleet.stop_all()
        with lock:
            return list(world_ms), list(hop_ms), frames


def up_cameras(
    duration_s: float,
    *,
    pin: str = "auto",
    fps: float = FPS,
    probe: Callable[[int], object] | None = None,
    layout: str = "per-stage",
) -> dict:
    """The JSON summary of one ``ovis up --cameras 2x2`` run of ``duration_s`` seconds in
    ``layout`` (its ``cpu``: what its processes used per world frame, from /proc);
    ``probe(pid of ovis up)`` is called 3 s after every camera runs and 5 s before the
    end (a window while they all run)."""
    args = [sys.executable, "-m", "ovis.services.cli", "up", "--cameras", "2x2", "--json",
            "--duration", str(duration_s), "--seed", str(SEED % 1000), "--fps", str(fps),
            "--pin", pin, "--layout", layout,
            "--listen", f"tcp/127.0.0.1:{free_port()}"]  # fmt: skip
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    err: list[str] = []
    running = threading.Event()

    def read_stderr() -> None:
        for line in proc.stderr:
            err.append(line)
            if "cameras running" in line:
                running.set()

    reader = threading.Thread(target=read_stderr, daemon=True)
    reader.start()
    while not running.wait(0.5) and proc.poll() is None:
        pass
    if probe is not None and duration_s > 6.0 and running.is_set():
        for wait_s in (3.0, duration_s - 5.0):
            time.sleep(wait_s)
            probe(proc.pid)
    out = proc.stdout.read()  # the summary, at the end
    proc.wait(60)
    reader.join(5.0)
    if proc.returncode != 0:
        raise RuntimeError(
            f"ovis up --cameras failed (exit {proc.returncode}): {''.join(err)[-2000:]}"
        )
    return json.loads(out)


#: The layouts compared, the reference first (issue 38: the default is per-stage).
LAYOUTS = ("per-camera", "per-stage")
#: Issue 38's targets for the default layout, every run within them.
TARGETS = {"cpu": 9.0, "p50": 6.0, "p99": 15.0, "lost": 0}


@dataclass
class LayoutRun:
    """What one ``ovis up --cameras 2x2`` run gave."""

    cpu: float  # ms of all its processes per world frame (ovis up's own apart)
    own: float  # ovis up's own process (its summary's subscriber) per world frame
    p50: float
    p99: float
    lost: int  # captured after the start-up and never in the world
    captured: int
    startup_lost: int
    startup_captured: int
    chain_p50: float

    @classmethod
    def of(cls, run: dict) -> LayoutRun:
        lat, early = run["world"]["latency_ms"], run["startup"]["cameras"].values()
        return cls(
            cpu=run["cpu"]["ms_per_frame"],
            own=run["cpu"]["own_ms_per_frame"],
            p50=lat["p50"],
            p99=lat["p99"],
            lost=sum(c["dropped"] for c in run["cameras"].values()),
            captured=sum(c["captured"] for c in run["cameras"].values()),
            startup_lost=sum(c["dropped"] for c in early),
            startup_captured=sum(c["captured"] for c in early),
            chain_p50=run["stages_ms"]["capture_to_pose"]["p50"],
        )


def empty_topology(frames: int, layout: str, log=print) -> dict[str, float]:
    """The empty topology of ``layout`` (:mod:`benchmarks.topology`): its capture → world
    p50 and p99 (ms) and the CPU time of all its processes per world frame (ms)."""
    from benchmarks.topology import empty_chains

    reads: list[tuple[float, float]] = []

    def probe(pid: int) -> None:
        reads.append((time.monotonic(), sum(tree_cpu(pid).values())))

    lat, received = empty_chains(frames, probe=probe, layout=layout)
    (t0, c0), (t1, c1) = reads
    cpu = (c1 - c0) * 1e3 / ((t1 - t0) * FPS)
    log(f"[fusion] empty topology {layout}: p50 {lat.p50:.2f} ms, p99 {lat.p99:.2f} ms, CPU "
        f"{cpu:.2f} ms per world frame ({received} world frames)")  # fmt: skip
    return {"p50": lat.p50, "p99": lat.p99, "cpu": cpu}


def layout_runs(rounds: int, duration_s: float, log=print) -> dict[str, list[LayoutRun]]:
    """``rounds`` runs of each layout, taking turns (a change of load hits both alike)."""
    runs: dict[str, list[LayoutRun]] = {layout: [] for layout in LAYOUTS}
    for k in range(rounds):
        for layout in LAYOUTS:
            got = LayoutRun.of(up_cameras(duration_s, layout=layout))
            runs[layout].append(got)
            log(f"[fusion] {layout} run {k + 1}: {got}")
    return runs


def _runs_text(values: list[float], unit: str) -> str:
    return "runs " + ", ".join(f"{v:.3g}" for v in values) + f" {unit}".rstrip()


def proofs_ms(cameras: int = 4, size: int = 4_000, reps: int = 200) -> float:
    """Median ms of one world frame's proofs of origin, in one process: each camera's
    obstacles signed (pose) and verified (fusion), and the world frame signed (fusion),
    on payloads of ``size`` bytes (a few robots' and obstacles' messages). The checks
    call the public key as :class:`~ovis.common.trust.proof.Verifier` does, without its
    replay guard, which would refuse the same message repeated."""
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    from ovis.common.trust.proof import Signer, signed_bytes

    key = Ed25519PrivateKey.generate()
    signer, public = Signer(key), key.public_key()
    payload, topic = os.urandom(size), "ovis/default/cam/cam00/obstacles"
    sig = key.sign(signed_bytes(topic, payload))
    samples = []
    for _ in range(reps):
        t0 = time.perf_counter()
        for _ in range(cameras):
            signer.attachment(topic, payload)
            public.verify(sig, signed_bytes(topic, payload))
        signer.attachment("ovis/default/world", payload)
        samples.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(samples))


def compute_floor_ms(merge_ms: float, reps: int, log=print) -> dict[str, float]:
    """The work of one world frame in one process, no bus: every camera's preprocess,
    label and pose (:func:`~benchmarks.stage_work.stage_work_ms`, warm, on that camera's
    frames of the same run's seed), the merge (``merge_ms``) and the proofs
    (:func:`proofs_ms`)."""
    from benchmarks.stage_work import stage_work_ms

    stages = sum(sum(stage_work_ms(SEED % 1000, reps, camera=k).values()) for k in range(4))
    proofs = proofs_ms()
    log(f"[fusion] in-process work per world frame: stages {stages:.2f} ms, merge "
        f"{merge_ms:.2f} ms, proofs {proofs:.2f} ms")  # fmt: skip
    return {"stages": stages, "merge": merge_ms, "proofs": proofs}


def _chain_rows(quick: bool, merge_ms: float, log=print) -> list[Row]:
    up_cameras(2.0)  # prerenders (and caches) every camera's period: not timed
    rounds, duration = (1, 10.0) if quick else (3, 30.0)
    runs = layout_runs(rounds, duration, log)
    empty = {layout: empty_topology(150 if quick else 600, layout, log) for layout in LAYOUTS}
    work = compute_floor_ms(merge_ms, 60 if quick else 300, log)
    ours, ref = runs["per-stage"], runs["per-camera"]
    what = (
        "4 cameras + fusion (ovis up --cameras 2x2, 4 × 640×480 at 30 frames/s), one "
        f"process per stage serving every camera; worst of {rounds} runs taking turns with "
        f"the per-camera layout ({rounds} runs, one process per stage and camera: the floor)"
    )

    def row(key: str, label: str, unit: str, extra: str = "") -> Row:
        mine = [getattr(r, key) for r in ours]
        theirs = [getattr(r, key) for r in ref]
        worst, floor = max(mine), max(theirs)
        target = TARGETS.get(key)
        return Row(
            f"{PREFIX} {what}: {label} ({_runs_text(mine, unit)}; per-camera "
            f"{_runs_text(theirs, unit)}{extra})",
            unit or "frames",
            worst,
            floor,
            ratio(worst, floor),
            None if target is None else (f"≤ {target:g} {unit}".strip() if target else "0"),
            None if target is None else all(v <= target for v in mine),
        )

    cores = len(os.sched_getaffinity(0))
    own = ", ".join(f"{r.own:.2f}" for r in ours)
    lost_text = ", ".join(f"{r.lost} of {r.captured}" for r in ours)
    early = ", ".join(f"{r.startup_lost} of {r.startup_captured}" for r in ours)
    bus = {k: f"empty topology per stage {empty['per-stage'][k]:.2f}, per camera "
              f"{empty['per-camera'][k]:.2f} ms" for k in ("cpu", "p50", "p99")}  # fmt: skip
    return [
        row("cpu", "CPU time of all its processes per world frame, from its summary "
            "(/proc)", "ms", f"; ovis up's own summary subscriber apart: {own} ms; the "
            f"{cores} cores have {cores * 1e3 / FPS:.0f} ms per frame period; {bus['cpu']}"),
        row("p50", "capture → world p50", "ms", f"; {bus['p50']}"),
        row("p99", "capture → world p99", "ms", f"; {bus['p99']}"),
        row("lost", "frames captured after the start-up that never reached the world", "",
            f"; of {lost_text}; in the first second, the start-up, counted apart: {early}"),
        row("chain_p50", "one camera's capture → pose p50", "ms"),
        _design_floor_row(what, [r.cpu for r in ours], empty["per-stage"]["cpu"], work),
    ]  # fmt: skip


def _design_floor_row(what: str, cpu: list[float], bus_ms: float, work: dict[str, float]) -> Row:
    """The per-stage layout's CPU per world frame against what its design cannot go
    under: its empty topology (the same processes and messages, no work) plus the work
    done in one process (:func:`compute_floor_ms`), both measured in this run."""
    floor = bus_ms + sum(work.values())
    return Row(
        f"{PREFIX} {what}: CPU time of all its processes per world frame against the "
        f"design's floor ({_runs_text(cpu, 'ms')}; floor: the empty per-stage topology "
        f"{bus_ms:.2f} ms + the work in one process, warm, {work['stages']:.2f} ms for the "
        f"4 cameras' preprocess, label and pose, {work['merge']:.2f} ms the merge, "
        f"{work['proofs']:.2f} ms the proofs of origin)",
        "ms",
        max(cpu),
        floor,
        ratio(max(cpu), floor),
    )


def fusion_rows(quick: bool, log=print) -> list[Row]:
    frames = 150 if quick else 600
    p50, p99 = _merge_cost(frames)
    period = 1e3 / FPS
    log(f"[fusion] merge p50 {p50:.2f} ms, p99 {p99:.2f} ms")
    world, hop, sent = _live(frames, log)
    w, h = stats(world), stats(hop)
    log(f"[fusion] live p50 {w.p50:.2f} ms p99 {w.p99:.2f} ms ({w.n}/{sent}), hop p50 {h.p50:.2f}")
    label = "2×2 arena, 4 robots, 10 obstacles"
    # No targets here: issue 38's are for the four cameras' stages plus fusion, run by
    # `ovis up --cameras 2x2`: _chain_rows.
    return [
        *_chain_rows(quick, p50, log),
        Row(f"{PREFIX} merge one world frame in-process ({label}) p50 (p99 {p99:.2f} ms; "
            "floor: the frame period)", "ms", p50, period, ratio(p50, period)),
        Row(f"{PREFIX} live, 4 cameras' detections at 30 frames/s: camera stamp → world p50 "
            f"(fusion only, chains not included; {w.n}/{sent} world frames received)", "ms",
            w.p50, h.p50, ratio(w.p50, h.p50)),
        Row(f"{PREFIX} live, 4 cameras' detections at 30 frames/s: camera stamp → world p99 "
            "(fusion only)", "ms", w.p99, h.p99, ratio(w.p99, h.p99)),
    ]  # fmt: skip
