"""What one frame message costs the process that publishes it, with glibc's default
``malloc`` thresholds (the floor) and with :func:`ovis.services.memory.keep_freed_memory`
(what every ``ovis`` process uses).

A publisher process (a Zenoh peer, like the stages under ``ovis up``) encodes and
publishes ``N`` frames (grey 640×480, BGR 1920×1080) as :class:`Frame` messages at
30 frames/s to this process, which subscribes; the publisher reports its own CPU time
(every thread: Python and Zenoh's) and minor page faults per message, after a warm-up.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import time

import numpy as np
import zenoh

from benchmarks.bus import free_port
from benchmarks.core import Row, ratio
from ovis.common.config import ZenohConfig
from ovis.common.messages import ENCODING, Frame, encode
from ovis.services.bus import zenoh_config

__all__ = ["frame_hop_rows"]

KEY = "bench/frame_hop"
FPS = 30.0
WARM_UP = 30


def _publish(port: int, keep: bool, n: int, shape: tuple[int, ...]) -> None:
    """The publisher process: prints its CPU ms and minor faults per message as JSON."""
    if keep:
        from ovis.services.memory import keep_freed_memory

        keep_freed_memory()
    zc = ZenohConfig(mode="peer", connect=[f"tcp/127.0.0.1:{port}"])
    session = zenoh.open(zenoh_config(zc))
    pub = session.declare_publisher(KEY, encoding=zenoh.Encoding(ENCODING))
    image = np.random.default_rng(0).integers(0, 256, shape, dtype=np.uint8)
    time.sleep(1.0)  # the subscriber's declaration reaches us
    start = time.monotonic()
    for i in range(n):
        if i == WARM_UP:
            before = resource.getrusage(resource.RUSAGE_SELF)
        pub.put(encode(Frame.from_image(image, seq=i, stamp_ns=time.time_ns())))
        time.sleep(max(0.0, start + (i + 1) / FPS - time.monotonic()))
    after = resource.getrusage(resource.RUSAGE_SELF)
    count = n - WARM_UP
    cpu_s = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    faults = after.ru_minflt - before.ru_minflt
    print(json.dumps({"cpu_ms": cpu_s * 1e3 / count, "faults": faults / count}), flush=True)
    session.close()


def _measure(keep: bool, n: int, shape: tuple[int, ...]) -> tuple[dict[str, float], int]:
    """One publisher run: its per-message figures, and how many messages arrived here."""
    port = free_port()
    zc = ZenohConfig(mode="peer", listen=[f"tcp/127.0.0.1:{port}"])
    received = 0

    def on_sample(_sample: zenoh.Sample) -> None:
        nonlocal received
        received += 1

    with zenoh.open(zenoh_config(zc)) as session:
        session.declare_subscriber(KEY, on_sample)
        args = [str(port), "keep" if keep else "default", str(n), *map(str, shape)]
        out = subprocess.run(
            [sys.executable, "-m", "benchmarks.frame_hop", *args],
            capture_output=True,
            text=True,
            check=True,
            timeout=60 + n / FPS,
        )
        time.sleep(0.5)
    return json.loads(out.stdout.strip().splitlines()[-1]), received


def frame_hop_rows(quick: bool, log=print) -> list[Row]:
    n = 120 if quick else 450
    rows: list[Row] = []
    for shape in ((480, 640), (1080, 1920, 3)):
        size = f"{shape[1]}×{shape[0]} {'BGR' if len(shape) == 3 else 'grey'}"
        default, got_d = _measure(False, n, shape)
        kept, got_k = _measure(True, n, shape)
        log(f"  {size}: default {default}, kept {kept}; received {got_d}, {got_k} of {n}")
        rows.append(
            Row(
                f"End to end, one hop: publisher CPU per {size} frame message at 30 frames/s, "
                f"freed memory kept (floor: glibc's defaults; page faults per message "
                f"{kept['faults']:.0f} against {default['faults']:.0f}; received "
                f"{got_k} and {got_d} of {n})",
                "ms",
                kept["cpu_ms"],
                default["cpu_ms"],
                ratio(kept["cpu_ms"], default["cpu_ms"]),
            )
        )
    return rows


if __name__ == "__main__":
    port, mode, count, *dims = sys.argv[1:]
    _publish(int(port), mode == "keep", int(count), tuple(map(int, dims)))
