"""The physical world (issue 36, docs/physical.md): what a frame costs to render, and the
frame rate ``ovis up --world physical`` sustains.

* render: ``PhysicalWorld.render`` of the ``physical`` preset's world (the oblique rig,
  640×480, six obstacles and a robot, two lamps, 4 anti-aliasing samples) at successive
  instants, median wall time per frame, with the lamps' shadows and without; and the
  empty floor's render (the renderer's cost with no solid). The floor: the light
  simulator's frame of the same size (``SimSource``, rendered live), taking turns with
  them frame by frame;
* live: ``ovis up --world physical`` as a real process, its obstacle frames counted by a
  subscriber over the middle of the run: the frames per second it sustains at the
  preset's rate (floor: that rate) and as fast as it renders (``--fps 0``; floor: the
  renderer alone, one frame per median render above).
"""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import tempfile
import threading
import time

import msgspec
import zenoh

from benchmarks.bus import free_port
from benchmarks.core import Row, ratio, stats
from ovis.common.capture.sources import SimSource
from ovis.common.config import OvisConfig, ZenohConfig, load_config
from ovis.common.messages import ObstacleFrame, Topics, decode
from ovis.services.bus import open_session

__all__ = ["physical_rows"]

PREFIX = "Physical world"
SEED = 3601
#: seconds of each ``ovis up`` run, and of its start and end left out of the count
RUN_S, MARGIN_S = 30.0, 5.0


def _world(cfg: OvisConfig, shadows: bool):
    from ovis.common.physical.scene import random_scene
    from ovis.common.physical.world import PhysicalWorld

    phys = msgspec.structs.replace(cfg.physical, shadows=shadows)
    cfg = msgspec.structs.replace(cfg, physical=phys)
    return PhysicalWorld(random_scene(cfg, SEED, [cfg.camera]), cfg, [cfg.camera])


def _render_ms(frames: int) -> dict[str, float]:
    """Median ms per frame: shadows on, off, the empty floor, and the light frame."""
    cfg = load_config(preset="physical")
    light = SimSource(load_config(), SEED, prerender=0)
    shadowed, plain = _world(cfg, True), _world(cfg, False)
    samples: dict[str, list[float]] = {"on": [], "off": [], "floor": [], "light": []}

    def timed(name: str, k: int, call) -> None:
        t0 = time.perf_counter()
        call()
        if k >= 2:  # the first renders build the GL state
            samples[name].append((time.perf_counter() - t0) * 1e3)

    try:
        for k in range(frames + 2):
            t = k / cfg.simulator.fps
            shadowed.set_time(t)
            plain.set_time(t)
            timed("on", k, lambda k=k: shadowed.render(k))
            timed("off", k, lambda k=k: plain.render(k))
            timed("floor", k, lambda: shadowed.clean(solids=False))
            timed("light", k, light.read)
    finally:
        shadowed.close()
        plain.close()
    return {name: stats(s).p50 for name, s in samples.items()}


def _sustained_fps(fps: float, log=print) -> tuple[float, int]:
    """Obstacle frames per second of one ``ovis up --world physical`` run at ``fps``,
    counted by their capture stamps between ``MARGIN_S`` after the first and before the
    end; and how many were counted."""
    port = free_port()
    state = tempfile.mkdtemp(prefix="ovis-bench-physical-")
    args = [sys.executable, "-m", "ovis.services.cli", "up", "--world", "physical", "--json",
            "--duration", str(RUN_S), "--fps", str(fps), "--seed", str(SEED),
            "--listen", f"tcp/127.0.0.1:{port}", "--state-dir", state]  # fmt: skip
    stamps: list[int] = []
    lock = threading.Lock()

    def on_obstacles(sample: zenoh.Sample) -> None:
        with lock:
            stamps.append(decode(sample.payload.to_bytes(), ObstacleFrame).stamp_ns)

    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        with contextlib.ExitStack() as stack:
            deadline = time.monotonic() + 120
            while proc.poll() is None and time.monotonic() < deadline:
                try:  # its router, once it listens
                    connect = ZenohConfig(connect=[f"tcp/127.0.0.1:{port}"])
                    session = stack.enter_context(open_session(connect))
                    break
                except Exception:
                    time.sleep(0.5)
            else:
                raise RuntimeError("ovis up --world physical: no router to subscribe to")
            session.declare_subscriber(Topics("default").obstacles, on_obstacles)
            out, err = proc.communicate(timeout=RUN_S + 180)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    if proc.returncode != 0:
        raise RuntimeError(f"ovis up --world physical failed: {err[-2000:]}")
    summary = json.loads(out)
    log(f"  fps {fps:g}: {summary['frames_processed']} frames, latency p50 "
        f"{summary['latency_ms_p50']} ms")  # fmt: skip
    with lock:
        t = sorted(stamps)
    if len(t) < 3:
        return 0.0, len(t)
    lo, hi = t[0] + MARGIN_S * 1e9, t[-1] - MARGIN_S * 1e9
    kept = [s for s in t if lo <= s <= hi]
    if len(kept) < 2:
        return 0.0, len(kept)
    return (len(kept) - 1) / ((kept[-1] - kept[0]) / 1e9), len(kept)


def physical_rows(quick: bool, log=print) -> list[Row]:
    frames = 20 if quick else 60
    ms = _render_ms(frames)
    log(f"  render p50 ms: {ms}")
    what = "640×480, oblique rig, 6 obstacles + robot, 2 lamps, 4 samples"
    floor = "(floor: the light simulator's frame, same size)"
    rows = [
        Row(f"{PREFIX}: {name} {floor}", "ms", ms[key], ms["light"], ratio(ms[key], ms["light"]))
        for key, name in (
            ("on", f"frame rendered with shadows ({what})"),
            ("off", f"frame rendered without shadows ({what})"),
            ("floor", "the empty floor rendered with shadows (no solid)"),
        )
    ]
    preset = load_config(preset="physical").service.fps
    kept, n = _sustained_fps(preset, log)
    name = (
        f"{PREFIX}: ovis up --world physical at the preset's rate, frames/s sustained "
        f"({n} frames; floor: the rate asked)"
    )
    rows.append(
        Row(
            name,
            "frames/s",
            kept,
            preset,
            ratio(kept, preset),
            "ratio ≥ 0.95",
            kept >= 0.95 * preset,
        )
    )
    alone = 1e3 / ms["on"]
    fastest, n = _sustained_fps(0.0, log)
    name = (
        f"{PREFIX}: ovis up --world physical as fast as it renders (--fps 0, shadows on), "
        f"frames/s sustained ({n} frames; floor: the renderer alone, one frame per median "
        "render)"
    )
    rows.append(Row(name, "frames/s", fastest, alone, ratio(fastest, alone)))
    return rows
