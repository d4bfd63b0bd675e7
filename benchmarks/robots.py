"""Marked robots (issue 16): accuracy against ground truth per seed, the per-frame cost of
the markers, and the end-to-end latency of the running services with 4 robots.

* accuracy: :func:`ovis.common.analysis.robots.evaluate_marked` on unseen seeds (4 robots,
  6 obstacles, 640×480, 300 frames; ``--quick``: 100 frames, 2 seeds);
* cost: ``Detector.detect`` on the same pre-rendered 4-robot frames with the robots
  configured (marker search, pose, filters, per-robot planner) and without (the paper's
  frame path: compactness rule), taking turns; the floor is the frame path without;
* end to end: ``ovis run`` preprocess, label, pose and capture on a router with the
  4-robot arena, as ``ovis up`` starts them, capture stamp → subscriber.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import msgspec

from benchmarks.bus import LATENCY_FPS, PIPELINE, Bench
from benchmarks.core import Row, ratio, stats
from ovis.common.analysis.robots import evaluate_marked
from ovis.common.capture.sources import SimSource
from ovis.common.config import OvisConfig, load_config
from ovis.common.sim.scenes import marked_scene
from ovis.common.world.detection import Detector

__all__ = ["robots_rows"]

PREFIX = "Marked robots"
SEEDS = (9101, 9102, 9103)
ROBOTS, OBSTACLES = 4, 6
PRERENDER = 60


def _cost(config: OvisConfig, reps: int) -> tuple[float, float]:
    """p50 ms of ``Detector.detect`` per frame with and without the robots configured."""
    source = SimSource(config, 9100, prerender=PRERENDER)
    frames = [source.read()[0] for _ in range(PRERENDER)]
    plain = msgspec.structs.replace(config.pose, robots=[])
    with_markers = Detector(config.camera, config.image, config.pose)
    without = Detector(config.camera, config.image, plain)
    samples: dict[int, list[float]] = {0: [], 1: []}
    for i in range(reps + 5):
        frame, stamp = frames[i % PRERENDER], i / 30.0
        for k, detector in enumerate((with_markers, without)):
            t0 = time.perf_counter()
            detector.detect(frame, stamp_s=stamp)
            if i >= 5:
                samples[k].append((time.perf_counter() - t0) * 1e3)
    return stats(samples[0]).p50, stats(samples[1]).p50


def robots_rows(quick: bool, log=print) -> list[Row]:
    base = load_config()
    config = marked_scene(base, ROBOTS, OBSTACLES)
    rows: list[Row] = []
    frames, seeds = (100, SEEDS[:2]) if quick else (300, SEEDS)
    for seed in seeds:
        acc = evaluate_marked(base, seed=seed, frames=frames, robots=ROBOTS, obstacles=OBSTACLES)
        log(f"  seed {seed}: {msgspec.json.encode(acc).decode()}")
        what = (
            f"{PREFIX} seed {seed} ({ROBOTS} robots, {OBSTACLES} obstacles, 640×480, "
            f"{frames} frames)"
        )
        for name, unit, value, target, ok in (
            ("identity swaps", "robot-frames", acc.swaps, "0", acc.swaps == 0),
            (
                f"position error mean (max {acc.position_max_cm:.3f} cm)",
                "cm",
                acc.position_mean_cm,
                "≤ 0.5 cm (max ≤ 1.5)",
                acc.position_mean_cm <= 0.5 and acc.position_max_cm <= 1.5,
            ),
            (
                f"heading error mean (max {acc.heading_max_deg:.2f}°)",
                "°",
                acc.heading_mean_deg,
                "≤ 1° (max ≤ 3°)",
                acc.heading_mean_deg <= 1.0 and acc.heading_max_deg <= 3.0,
            ),
            (
                f"velocity error mean after settling (max {acc.velocity_max_cm_s:.2f} cm/s)",
                "cm/s",
                acc.velocity_mean_cm_s,
                "≤ 2 cm/s",
                acc.velocity_mean_cm_s <= 2.0,
            ),
            (
                f"robots reported as obstacles (missed robot-frames: {acc.missed})",
                "robot-frames",
                acc.robots_as_obstacles,
                "0",
                acc.robots_as_obstacles == 0,
            ),
        ):
            rows.append(Row(name=f"{what} {name}", unit=unit, value=value, target=target, met=ok))
    with_ms, without_ms = _cost(config, 100 if quick else 300)
    log(f"  per frame: {with_ms:.2f} ms with {ROBOTS} markers, {without_ms:.2f} ms without")
    rows.append(
        Row(
            name=f"{PREFIX} per-frame cost with {ROBOTS} markers, 640×480 (Detector.detect p50; "
            "floor: the same frames without robots configured)",
            unit="ms",
            value=with_ms,
            floor=without_ms,
            ratio=ratio(with_ms, without_ms),
            target="≤ 1.5× the floor",
            met=bool(with_ms <= 1.5 * without_ms),
        )
    )
    latency_s = 8.0 if quick else 20.0
    config = msgspec.structs.replace(
        config, service=msgspec.structs.replace(config.service, prerender=PRERENDER)
    )
    with (
        tempfile.TemporaryDirectory(prefix="ovis-bench-") as tmp,
        Bench(Path(tmp), config, PIPELINE, prerender=PRERENDER) as bench,
    ):
        log(f"  end to end with {ROBOTS} robots at {LATENCY_FPS:g} fps for {latency_s:g} s")
        lat = bench.run_capture(LATENCY_FPS, latency_s, log)
    rows.append(
        Row(
            name=f"{PREFIX} end to end 640×480 with {ROBOTS} robots, latency p50 at "
            f"{LATENCY_FPS:g} frames/s, capture stamp → subscriber (p99 "
            f"{lat.latency.p99:.2f} ms; dropped {lat.dropped} of {lat.published})",
            unit="ms",
            value=lat.latency.p50,
        )
    )
    return rows
