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
import os
import resource
import subprocess
import sys
import time

import numpy as np
import zenoh

from benchmarks.bus import free_port
from benchmarks.core import Row, ratio
from ovis.common.config import ZenohConfig
from ovis.common.messages import ENCODING, Frame, FrameView, decode, encode
from ovis.services.bus import zenoh_config
from ovis.services.shm import ShmWriter

__all__ = ["frame_hop_rows"]

KEY = "bench/frame_hop"
FPS = 30.0
WARM_UP = 30


#: How a hop is made: plain bytes over the network (shared memory off on both sides),
#: plain bytes with Zenoh's shared-memory transport (its default), ovis's way (the
#: message written once into shared memory, decoded as a view), and a tiny message
#: (the floor: what any message costs).
HOWS = ("network", "zenoh", "ovis", "tiny")


def _publish(port: int, keep: bool, n: int, shape: tuple[int, ...], how: str = "zenoh") -> None:
    """The publisher process: prints its CPU ms and minor faults per message as JSON."""
    if keep:
        from ovis.services.memory import keep_freed_memory

        keep_freed_memory()
    zc = ZenohConfig(mode="peer", connect=[f"tcp/127.0.0.1:{port}"], shared_memory=how != "network")
    session = zenoh.open(zenoh_config(zc))
    pub = session.declare_publisher(KEY, encoding=zenoh.Encoding(ENCODING))
    image = np.random.default_rng(0).integers(0, 256, shape, dtype=np.uint8)
    if how == "tiny":
        image = image[:1, :8]
    shm = ShmWriter(8 * image.nbytes + 4096) if how == "ovis" else None
    time.sleep(1.0)  # the subscriber's declaration reaches us
    start = time.monotonic()
    for i in range(n):
        if i == WARM_UP:
            before = resource.getrusage(resource.RUSAGE_SELF)
        data = encode(Frame.from_image(image, seq=i, stamp_ns=time.time_ns(), copy=False))
        pub.put(data if shm is None else shm.payload(data))
        time.sleep(max(0.0, start + (i + 1) / FPS - time.monotonic()))
    after = resource.getrusage(resource.RUSAGE_SELF)
    count = n - WARM_UP
    cpu_s = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    faults = after.ru_minflt - before.ru_minflt
    print(json.dumps({"cpu_ms": cpu_s * 1e3 / count, "faults": faults / count}), flush=True)
    session.close()


def _measure(
    keep: bool, n: int, shape: tuple[int, ...], how: str = "zenoh"
) -> tuple[dict[str, float], int]:
    """One publisher run: its per-message figures (with ``sub_ms``, this subscriber's CPU
    per message: every thread of this otherwise idle process, receiving, copying out and
    decoding as the stages do), and how many messages arrived here."""
    port = free_port()
    zc = ZenohConfig(mode="peer", listen=[f"tcp/127.0.0.1:{port}"], shared_memory=how != "network")
    received = 0
    window: list[tuple[int, float]] = []  # (messages, CPU s) at the warm-up, at the last
    kind = FrameView if how == "ovis" else Frame

    latency: list[float] = []  # ms from the publisher's stamp to the decoded frame here

    def on_sample(sample: zenoh.Sample) -> None:
        nonlocal received
        frame = decode(sample.payload.to_bytes(), kind)
        frame.image()
        latency.append((time.time_ns() - frame.stamp_ns) / 1e6)
        received += 1
        if received >= WARM_UP:
            usage = resource.getrusage(resource.RUSAGE_SELF)
            window[received > WARM_UP :] = [(received, usage.ru_utime + usage.ru_stime)]

    with zenoh.open(zenoh_config(zc)) as session:
        session.declare_subscriber(KEY, on_sample)
        args = [str(port), "keep" if keep else "default", str(n), how, *map(str, shape)]
        out = subprocess.run(
            [sys.executable, "-m", "benchmarks.frame_hop", *args],
            capture_output=True,
            text=True,
            check=True,
            timeout=60 + n / FPS,
        )
        time.sleep(0.5)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    if len(window) == 2 and window[1][0] > window[0][0]:
        result["sub_ms"] = (window[1][1] - window[0][1]) * 1e3 / (window[1][0] - window[0][0])
    result["latency_ms"] = float(np.median(latency[WARM_UP:])) if latency[WARM_UP:] else None
    return result, received


def _pipe_publish(fd: int, n: int) -> None:
    """The publisher process of the OS floor: its clock's ns (8 bytes) into a pipe at 30
    messages/s; prints its CPU ms per message as JSON."""
    start = time.monotonic()
    for i in range(n):
        if i == WARM_UP:
            before = resource.getrusage(resource.RUSAGE_SELF)
        os.write(fd, time.time_ns().to_bytes(8, "little"))
        time.sleep(max(0.0, start + (i + 1) / FPS - time.monotonic()))
    after = resource.getrusage(resource.RUSAGE_SELF)
    cpu_s = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    print(json.dumps({"cpu_ms": cpu_s * 1e3 / (n - WARM_UP)}), flush=True)


def _pipe_hop(n: int) -> tuple[float, float]:
    """Publisher + subscriber CPU ms of one 8-byte message through a pipe between two
    Python processes at 30/s, paced as the Zenoh hops are, and its median latency (ms):
    what any message between processes costs this machine (the OS's floor, no Zenoh)."""
    read_fd, write_fd = os.pipe()
    args = [sys.executable, "-m", "benchmarks.frame_hop", "pipe", str(write_fd), str(n)]
    child = subprocess.Popen(args, pass_fds=(write_fd,), stdout=subprocess.PIPE, text=True)
    os.close(write_fd)
    latency: list[float] = []
    for i in range(n):
        if i == WARM_UP:
            before = resource.getrusage(resource.RUSAGE_SELF)
        sent_ns = int.from_bytes(os.read(read_fd, 8), "little")
        latency.append((time.time_ns() - sent_ns) / 1e6)
    after = resource.getrusage(resource.RUSAGE_SELF)
    os.close(read_fd)
    out, _ = child.communicate(timeout=60)
    sub_s = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    cpu_ms = json.loads(out.strip().splitlines()[-1])["cpu_ms"] + sub_s * 1e3 / (n - WARM_UP)
    return cpu_ms, float(np.median(latency[WARM_UP:]))


#: Issue 38: a frame's hop (ovis's way) costs at most this multiple of a tiny message's
#: hop, measured in the same run (what any Zenoh message costs here is the floor).
HOP_RATIO_TARGET = 1.2


def hop_rows(quick: bool, log=print) -> tuple[list[Row], float]:
    """One 640×480 grey frame hop, publisher + subscriber CPU, each way of :data:`HOWS`
    (runs taking turns, the median of each), against a tiny message's hop; and the tiny
    message's hop latency p50 (ms)."""
    n, rounds = (150, 2) if quick else (450, 3)
    cost: dict[str, list[float]] = {how: [] for how in HOWS}
    lost: dict[str, int] = dict.fromkeys(HOWS, 0)
    latency: dict[str, list[float]] = {how: [] for how in (*HOWS, "pipe")}
    pipe: list[float] = []
    for _ in range(rounds):
        for how in HOWS:
            got, received = _measure(True, n, (480, 640), how)
            cost[how].append(got["cpu_ms"] + got.get("sub_ms", float("nan")))
            latency[how].append(got["latency_ms"] if got["latency_ms"] is not None else np.nan)
            lost[how] += n - received
        cpu_ms, latency_ms = _pipe_hop(n)
        pipe.append(cpu_ms)
        latency["pipe"].append(latency_ms)
    hop = {how: float(np.median(v)) for how, v in cost.items()}
    os_floor = float(np.median(pipe))
    wall = {how: float(np.median(v)) for how, v in latency.items()}
    log(f"  one hop, publisher + subscriber CPU ms: {hop} (runs {cost}); lost {lost}")
    log(f"  an 8-byte pipe message between two processes: {os_floor:.3f} ms (runs {pipe})")
    log(f"  one hop's latency p50 ms: {wall}")
    floor = hop["tiny"]
    what = {
        "network": "over the network (shared memory off)",
        "zenoh": "plain bytes, Zenoh's shared-memory transport (its default)",
        "ovis": "written once into shared memory, decoded as a view (ovis's way)",
    }
    tiny = Row(
        f"End to end, one hop of an 8-pixel frame (any Zenoh message) at 30 frames/s: "
        f"publisher + subscriber CPU (floor: 8 bytes through a pipe between two Python "
        f"processes at the same pace, no Zenoh; median of {rounds} runs of {n})",
        "ms",
        floor,
        os_floor,
        ratio(floor, os_floor),
    )
    tiny_latency = Row(
        f"End to end, one hop of an 8-pixel frame (any Zenoh message) at 30 frames/s: "
        f"latency p50, publisher's stamp to the decoded frame (floor: the pipe's; median "
        f"of {rounds} runs of {n}; a frame's own hop, ovis's way: {wall['ovis']:.2f} ms)",
        "ms",
        wall["tiny"],
        wall["pipe"],
        ratio(wall["tiny"], wall["pipe"]),
    )
    met = ratio(hop["ovis"], floor)
    target = (f"ratio ≤ {HOP_RATIO_TARGET:g}", met is not None and met <= HOP_RATIO_TARGET)
    return [tiny, tiny_latency] + [
        Row(
            f"End to end, one hop of a 640×480 grey frame at 30 frames/s: publisher + "
            f"subscriber CPU, {label} (floor: a {8}-pixel frame's hop, any Zenoh "
            f"message's cost here; median of {rounds} runs of {n}, lost {lost[how]})",
            "ms",
            hop[how],
            floor,
            ratio(hop[how], floor),
            *(target if how == "ovis" else (None, None)),
        )
        for how, label in what.items()
    ], wall["tiny"]


def frame_hop_rows(quick: bool, log=print) -> tuple[list[Row], float]:
    """The rows of what one frame message costs, and a tiny message's hop latency p50
    (ms, :func:`hop_rows`)."""
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
    hops, tiny_ms = hop_rows(quick, log)
    return rows + hops, tiny_ms


if __name__ == "__main__":
    if sys.argv[1] == "pipe":
        _pipe_publish(int(sys.argv[2]), int(sys.argv[3]))
        sys.exit()
    port, mode, count, how, *dims = sys.argv[1:]
    _publish(int(port), mode == "keep", int(count), tuple(map(int, dims)), how)
