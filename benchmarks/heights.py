"""Measured heights (issue 36): the per-frame cost of detection with heights measured
against without, on physical frames.

Physical scenes (:mod:`ovis.common.physical`, issue 36's arena, seeds :data:`SEEDS`)
seen by each rig, :data:`FRAMES` consecutive frames at 30 frames/s (the obstacles move).
``Detector.detect`` with heights measured and with configured heights, on the same
frames and the same segmentation (the empty floor subtracted), taking turns at 30
frames/s, each after a pause of its own (half a frame period apart): as in a live stage,
each detection starts after other work had the caches (run back to back, the second
would find them warm from the first); they take turns at seeing a frame first. The
measured one runs as the live pose stage does: its solids fitted on the first frame,
then new blobs and the periodic refits on a thread of their own (``background_fits``),
the frames never waiting for them. Rows, per rig:
the frame path's CPU per frame after the first (the detecting thread's CPU time; the
floor: the detection with configured heights), the fitting thread's CPU per frame beside
it (what measuring heights costs in all), and the first frame's cost (every blob fitted
at once, before the first obstacles).
"""

from __future__ import annotations

import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np

from benchmarks.core import Row, ratio
from ovis.common.analysis.footprints import physical_config
from ovis.common.config import load_config
from ovis.common.physical.rigs import rig
from ovis.common.physical.scene import random_scene
from ovis.common.physical.world import PhysicalWorld
from ovis.common.world.detection import Detector

__all__ = ["heights_rows"]

PREFIX = "Measured heights"
SEEDS = (9361, 9362)
FRAMES = 90
TARGET = 1.3


def _frames(rig_name: str, seed: int, frames: int, folder: Path):
    """The scene's frames at 30 frames/s, its empty floor's file and its camera."""
    cfg = physical_config(load_config(), seed)
    camera = rig(rig_name, cfg)
    world = PhysicalWorld(random_scene(cfg, seed, [camera]), cfg, [camera])
    try:
        out = []
        for k in range(frames):
            world.set_time(k / 30.0)
            out.append(world.render(k))
        floor = world.clean(solids=False)
    finally:
        world.close()
    path = folder / f"floor_{rig_name}_{seed}.png"
    cv2.imwrite(str(path), floor)
    return cfg, camera, out, path


def _detectors(cfg, camera, background: Path) -> tuple[Detector, Detector]:
    import msgspec

    image = msgspec.structs.replace(
        cfg.image,
        background=str(background),
        threshold=131,
        threshold_mode="fixed",
        median="ordinary",
        size_filter_cm2=20.0,
    )
    measured = msgspec.structs.replace(cfg.pose, heights="measured")
    return (
        Detector(camera, image, measured, background_fits=True),
        Detector(camera, image, cfg.pose),
    )


def _fit_thread_cpu_s() -> float:
    """CPU time of the solid tracker's fitting threads so far (s)."""
    return sum(
        time.clock_gettime(time.pthread_getcpuclockid(t.ident))
        for t in threading.enumerate()
        if t.name.startswith("solid-fit") and t.ident is not None
    )


def _paced(images, measured: Detector, configured: Detector) -> tuple[list, list, float]:
    """Frames after the first through both detectors at 30 frames/s, each detection half
    a frame period after the other's, taking turns at going first (the second finds the
    frame in the caches): each one's frame path CPU (ms) per frame, and the fitting
    thread's CPU meanwhile (ms)."""
    path: dict[str, list[float]] = {"measured": [], "configured": []}
    fits0, start = _fit_thread_cpu_s(), time.perf_counter()
    both = (("measured", measured), ("configured", configured))
    for k, image in enumerate(images[1:], start=1):
        for half, (name, det) in enumerate(both if k % 2 else both[::-1]):
            time.sleep(max(0.0, start + (k + 0.5 * half) / 30.0 - time.perf_counter()))
            t0 = time.thread_time()
            det.detect(image, stamp_s=k / 30.0)
            path[name].append((time.thread_time() - t0) * 1e3)
    fits_ms = (_fit_thread_cpu_s() - fits0) * 1e3
    return path["measured"], path["configured"], fits_ms


def heights_rows(quick: bool, log=print) -> list[Row]:
    rows: list[Row] = []
    frames = 45 if quick else FRAMES
    with tempfile.TemporaryDirectory(prefix="ovis-bench-heights-") as tmp:
        for rig_name in ("oblique", "overhead"):
            steady: dict[str, list[float]] = {"measured": [], "configured": []}
            first: list[float] = []
            fits_ms = 0.0
            for seed in SEEDS[:1] if quick else SEEDS:
                cfg, camera, images, floor = _frames(rig_name, seed, frames, Path(tmp))
                measured, configured = _detectors(cfg, camera, floor)
                try:
                    t0 = time.perf_counter()
                    measured.detect(images[0], stamp_s=0.0, fit_all=True)
                    first.append((time.perf_counter() - t0) * 1e3)
                    configured.detect(images[0], stamp_s=0.0)
                    m_path, c_path, fits = _paced(images, measured, configured)
                finally:
                    measured.close()
                steady["measured"] += m_path
                steady["configured"] += c_path
                fits_ms += fits
                log(f"  {rig_name} seed {seed}: {len(images)} frames")
            n = len(steady["measured"])
            m, c = float(np.mean(steady["measured"])), float(np.mean(steady["configured"]))
            r = ratio(m, c)
            rows.append(
                Row(
                    f"{PREFIX}: {rig_name} rig, frame path CPU per frame with heights measured, "
                    f"fits on their own thread as in the live pose stage (floor: configured "
                    f"heights, same physical frames, {n} frames of moving solids at 30 "
                    "frames/s)",
                    "ms",
                    m,
                    c,
                    r,
                    f"ratio ≤ {TARGET}",
                    r is not None and r <= TARGET,
                )
            )
            rows.append(
                Row(
                    f"{PREFIX}: {rig_name} rig, the fitting thread's CPU per frame beside it "
                    "(new blobs and the periodic refits; floor: configured heights' frame path)",
                    "ms",
                    fits_ms / n,
                    c,
                    ratio(fits_ms / n, c),
                )
            )
            rows.append(
                Row(
                    f"{PREFIX}: {rig_name} rig, first frame, every solid fitted at once "
                    "(floor: configured heights' frame)",
                    "ms",
                    float(np.mean(first)),
                    c,
                    ratio(float(np.mean(first)), c),
                )
            )
    return rows
