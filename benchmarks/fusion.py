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

* end to end: ``ovis up --cameras 2x2`` as a real process, all four capture →
  preprocess → label → pose chains (rendered 640×480 frames, each chain pinned to one
  core, the chains dealt round the cores) plus fusion at 30 frames/s per camera:
  capture stamp → world frame received by its summary's subscriber, p50 and p99, and
  the frames captured that never reached the world. The floor is the chains alone:
  capture stamp → a camera's pose published. The cameras' period is prerendered (and
  cached) before the clock starts.
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
from ovis.services.trust import signer_for

__all__ = ["fusion_rows"]

PREFIX = "Fusion"
CELL = (100.0, 75.0)
SEED = 9190
#: Issue 31's target for the CPU of all processes per world frame.
CPU_TARGET_MS = 12.0
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
) -> dict:
    """The JSON summary of one ``ovis up --cameras 2x2`` run of ``duration_s`` seconds,
    with ``cpu_ms_per_frame``: the CPU time all its processes took per frame period
    while every camera ran (from 3 s after the cameras all run to 2 s before the end);
    ``probe(pid of ovis up)`` is called at both ends of that window."""
    args = [sys.executable, "-m", "ovis.services.cli", "up", "--cameras", "2x2", "--json",
            "--duration", str(duration_s), "--seed", str(SEED % 1000), "--fps", str(fps),
            "--pin", pin, "--listen", f"tcp/127.0.0.1:{free_port()}"]  # fmt: skip
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
    cpu: list[tuple[float, float]] = []  # (monotonic s, CPU s of the process tree)
    while not running.wait(0.5) and proc.poll() is None:
        pass
    if duration_s > 6.0 and running.is_set():
        for wait_s in (3.0, duration_s - 5.0):
            time.sleep(wait_s)
            cpu.append((time.monotonic(), tree_cpu_s(proc.pid)))
            if probe is not None:
                probe(proc.pid)
    out = proc.stdout.read()  # the summary, at the end
    proc.wait(60)
    reader.join(5.0)
    if proc.returncode != 0:
        raise RuntimeError(
            f"ovis up --cameras failed (exit {proc.returncode}): {''.join(err)[-2000:]}"
        )
    run = json.loads(out)
    if len(cpu) == 2:
        (t0, c0), (t1, c1) = cpu
        run["cpu_ms_per_frame"] = (c1 - c0) * 1e3 / ((t1 - t0) * fps)
    return run


def tree_cpu_s(root: int) -> float:
    """CPU seconds (user + system, every thread) used so far by ``root`` and all the
    processes under it that are still running."""
    return sum(tree_cpu(root).values())


def tree_cpu(root: int) -> dict[int, float]:
    """pid → CPU seconds used so far, of ``root`` and every running process under it."""
    tick = os.sysconf("SC_CLK_TCK")
    parent, used = {}, {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            fields = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue  # ended meanwhile
        parent[int(entry)] = int(fields[1])
        used[int(entry)] = (int(fields[11]) + int(fields[12])) / tick

    def under(pid: int) -> bool:
        while pid > 1:
            if pid == root:
                return True
            pid = parent.get(pid, 0)
        return False

    return {pid: t for pid, t in used.items() if under(pid)}


def _chain_rows(quick: bool, log=print) -> list[Row]:
    from benchmarks.topology import empty_chains

    up_cameras(2.0)  # prerenders (and caches) every camera's period: not timed
    run = up_cameras(10.0 if quick else 30.0)
    empty, received = empty_chains(150 if quick else 600)
    w, chain = run["world"], run["stages_ms"]["capture_to_pose"]
    lat = w["latency_ms"]
    dropped = sum(c["dropped"] for c in run["cameras"].values())
    captured = sum(c["captured"] for c in run["cameras"].values())
    startup = run["startup"]
    early = startup["cameras"].values()
    early_dropped, early_captured = (sum(c[k] for c in early) for k in ("dropped", "captured"))
    cores = len(os.sched_getaffinity(0))
    machine_ms = cores * 1e3 / FPS  # the cores' time per frame period
    cpu = run.get("cpu_ms_per_frame")
    log(f"[fusion] 4 chains + fusion: capture → world p50 {lat['p50']:.2f} ms, p99 "
        f"{lat['p99']:.2f} ms; chains p50 {chain['p50']:.2f} ms, p99 {chain['p99']:.2f} ms; "
        f"world published p50 {run['stages_ms']['capture_to_world_published']['p50']:.2f} ms;"
        f" dropped {dropped}/{captured} (start-up {early_dropped}/{early_captured}); CPU per "
        f"world frame {cpu} ms; empty stages p50 "
        f"{empty.p50:.2f} ms, p99 {empty.p99:.2f} ms ({received} world frames); "
        f"{json.dumps(run['cameras'])}")  # fmt: skip
    what = "4 chains + fusion (ovis up --cameras 2x2, 4 × 640×480 at 30 frames/s)"
    floor = (
        f"floor: the same processes, placement and messages with empty stages, "
        f"benchmarks/topology.py; one chain's capture → pose p50 {chain['p50']:.1f} ms"
    )
    rows = [
        Row(f"{PREFIX} {what}: capture → world p50 ({floor})",
            "ms", lat["p50"], empty.p50, ratio(lat["p50"], empty.p50), "≤ 8 ms",
            lat["p50"] <= 8.0),
        Row(f"{PREFIX} {what}: capture → world p99 (floor: empty stages' p99; one chain's "
            f"capture → pose p99 {chain['p99']:.1f} ms)", "ms",
            lat["p99"], empty.p99, ratio(lat["p99"], empty.p99), "≤ 20 ms",
            lat["p99"] <= 20.0),
        Row(f"{PREFIX} {what}: frames captured that never reached the world (of {captured}; "
            f"in the first {startup['seconds']:g} s after every camera ran, the start-up, "
            f"counted apart: {early_dropped} of {early_captured})",
            "frames", dropped, None, None, "0", dropped == 0),
    ]  # fmt: skip
    if cpu is not None:
        rows.append(
            Row(f"{PREFIX} {what}: CPU time of all its processes per world frame (floor: "
                f"the {cores} cores' time per frame period; the four cameras' frames come "
                f"together, so the world waits for about this spread over the cores)",
                "ms", cpu, machine_ms, ratio(cpu, machine_ms), f"≤ {CPU_TARGET_MS:g} ms",
                cpu <= CPU_TARGET_MS)
        )  # fmt: skip
    return rows


def fusion_rows(quick: bool, log=print) -> list[Row]:
    frames = 150 if quick else 600
    p50, p99 = _merge_cost(frames)
    period = 1e3 / FPS
    log(f"[fusion] merge p50 {p50:.2f} ms, p99 {p99:.2f} ms")
    world, hop, sent = _live(frames, log)
    w, h = stats(world), stats(hop)
    log(f"[fusion] live p50 {w.p50:.2f} ms p99 {w.p99:.2f} ms ({w.n}/{sent}), hop p50 {h.p50:.2f}")
    label = "2×2 arena, 4 robots, 10 obstacles"
    # No targets here: the (capture → world p50 ≤ 8 ms, p99 ≤ 20 ms, no frame
    # lost) are for the four chains plus fusion: _chain_rows.
    return [
        *_chain_rows(quick, log),
        Row(f"{PREFIX} merge one world frame in-process ({label}) p50 (p99 {p99:.2f} ms; "
            "floor: the frame period)", "ms", p50, period, ratio(p50, period)),
        Row(f"{PREFIX} live, 4 cameras' detections at 30 frames/s: camera stamp → world p50 "
            f"(fusion only, chains not included; {w.n}/{sent} world frames received)", "ms",
            w.p50, h.p50, ratio(w.p50, h.p50)),
        Row(f"{PREFIX} live, 4 cameras' detections at 30 frames/s: camera stamp → world p99 "
            "(fusion only)", "ms", w.p99, h.p99, ratio(w.p99, h.p99)),
    ]  # fmt: skip
