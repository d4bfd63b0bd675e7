"""Where the frame pipeline's time goes: ``python -m benchmarks.profiling [--size 1920x1080]
[--objects N] [--frames N] [--top N]`` runs ``Detector.detect`` under cProfile on
simulated frames (or, with ``--objects``, on the scaling benchmark's disk scene at
640×480) and prints the functions with the largest own time."""

from __future__ import annotations

import argparse
import cProfile
import pstats

import msgspec

from benchmarks.core import scaled_config
from benchmarks.pipeline import SCALING_SIZE_FILTER_CM2, disk_centres, scene_with_disks
from ovis.common.sim.arena import Arena
from ovis.common.world.detection import Detector


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.profiling")
    parser.add_argument("--size", default="1920x1080", help="COLSxROWS (default 1920x1080)")
    parser.add_argument("--objects", type=int, help="disk scene with N objects at 640x480")
    parser.add_argument("--frames", type=int, default=300, help="detections to profile")
    parser.add_argument("--top", type=int, default=12)
    parser.add_argument("--sort", default="tottime", help="pstats sort key (tottime, cumtime)")
    args = parser.parse_args(argv)
    if args.objects:
        config = scaled_config(480, 640)
        config = msgspec.structs.replace(
            config,
            image=msgspec.structs.replace(config.image, size_filter_cm2=SCALING_SIZE_FILTER_CM2),
        )
        frames = [scene_with_disks(config, disk_centres(args.objects, 480, 640))]
    else:
        cols, rows = (int(v) for v in args.size.lower().split("x"))
        config = scaled_config(rows, cols)
        frames = [image for image, _ in Arena(config, 0).frames(8)]
    detector = Detector(config.camera, config.image, config.pose)
    for f in frames:
        detector.detect(f)
    profiler = cProfile.Profile()
    profiler.enable()
    for i in range(args.frames):
        detector.detect(frames[i % len(frames)])
    profiler.disable()
    pstats.Stats(profiler).sort_stats(args.sort).print_stats(args.top)


if __name__ == "__main__":
    main()
