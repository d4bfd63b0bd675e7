"""The floor under ``ovis up --cameras 2x2``: the same processes, placement and messages
with every stage empty.

Per camera (the per-camera layout): four chains of a capture and three relays
(preprocess, label, pose), each its own process, a Zenoh peer on loopback and pinned as
``ovis up`` pins the chains (dealt round the cores). Per stage (the per-stage layout):
one capture publishing the four cameras' frames and one relay per stage relaying every
camera's messages on its own keys, the frame path on the last core. Either way a fusion
relay publishes a world message once all four cameras' messages of a frame are in. Every
message has the size of the real stage's message for a 640×480 frame (a grey frame; the
packed binary frame with its 3×3 median; the blobs; the obstacles). The captures publish
together at 30 frames/s; this process subscribes to the world and measures capture stamp
→ world. What the real pipeline adds to this is the stages' work and its cache misses.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable

import zenoh

from benchmarks.bus import free_port
from benchmarks.core import Stats, stats
from ovis.common.config import ZenohConfig
from ovis.services.bus import LOOPBACK_PEER, zenoh_config
from ovis.services.inbox import Inbox

__all__ = ["empty_chains"]

PIXELS = 640 * 480
#: Bytes each stage publishes per frame: the grey frame; its packed binary frame and 3×3
#: median; the blobs and the obstacles of a few robots and obstacles (a few KB each).
SIZES = {"capture": PIXELS, "preprocess": PIXELS // 8 + PIXELS, "label": 1_600, "pose": 2_400}
CHAIN = ("capture", "preprocess", "label", "pose")
CAMERAS = 4
ALIVE = "bench/topology/alive/**"
STAMP = 16  # bytes: capture stamp (ns) and frame number, at the head of every message


def _key(camera: int, stage: str) -> str:
    return f"bench/topology/{camera}/{stage}"


def _stage(port: int, stage: str, cameras: list[int], frames: int, fps: float, layout: str) -> None:
    """One relay process of ``cameras`` (or a capture, or the fusion relay) until
    ``frames`` are done: it says it listens (a liveliness token), then the captures wait
    for the start."""
    from ovis.services.memory import keep_freed_memory

    keep_freed_memory()
    cores = sorted(os.sched_getaffinity(0))
    if layout == "per-stage" and len(cores) >= 2:  # as ovis up --pin auto places them
        os.sched_setaffinity(0, {cores[0] if stage == "fusion" else cores[-1]})
    elif layout == "per-camera" and stage != "fusion":
        os.sched_setaffinity(0, {cores[cameras[0] % len(cores)]})
    zc = ZenohConfig(mode="peer", connect=[f"tcp/127.0.0.1:{port}"], listen=[LOOPBACK_PEER])
    session = zenoh.open(zenoh_config(zc))
    go = Inbox(1)
    session.declare_subscriber("bench/topology/go", lambda s: go.put(s.payload.to_bytes()))
    inbox = _listen(session, stage, cameras)
    token = session.liveliness().declare_token(f"{ALIVE[:-3]}/{stage}/{cameras[0]}")  # noqa: F841
    said = None
    while said is None:
        said = go.get(timeout=1.0)
    start = float(said.decode())
    end = start + frames / fps + 3.0
    if stage == "capture":
        pubs = [session.declare_publisher(_key(c, stage)) for c in cameras]
        pad = bytes(SIZES[stage])
        for k in range(frames):
            time.sleep(max(0.0, start + k / fps - time.time()))
            for pub in pubs:
                pub.put(time.time_ns().to_bytes(8, "little") + k.to_bytes(8, "little") + pad)
    elif inbox is not None:
        pubs = {c: session.declare_publisher(_key(c, stage)) for c in cameras}
        pad = bytes(SIZES[stage])
        while time.time() < end:
            item = inbox.get(timeout=0.2)
            if item is not None:
                camera, payload = item
                pubs[camera].put(payload[:STAMP] + pad)
    time.sleep(max(0.0, end - time.time()))
    os._exit(0)  # no session close: nothing is left to send


def _listen(session: zenoh.Session, stage: str, cameras: list[int]) -> Inbox | None:
    """Subscribe what ``stage`` receives: the fusion relay publishes a world message once
    the four cameras' pose messages of a frame are in; a relay's inputs go to the inbox
    returned as (camera, payload) (the newest two of each camera, as in the services)."""
    if stage == "capture":
        return None
    if stage == "fusion":
        pub = session.declare_publisher("bench/topology/world")
        waiting: dict[int, list[bytes]] = {}
        lock = threading.Lock()

        def on_pose(sample: zenoh.Sample) -> None:
            head = sample.payload.to_bytes()[:STAMP]
            k = int.from_bytes(head[8:], "little")
            with lock:
                waiting.setdefault(k, []).append(head)
                if len(waiting[k]) == CAMERAS:
                    first = min(waiting.pop(k))  # the cameras' common stamp
                    pub.put(first + bytes(SIZES["pose"]))

        for c in range(CAMERAS):
            session.declare_subscriber(_key(c, "pose"), on_pose)
        return None
    inbox = Inbox(2 * len(cameras))
    before = CHAIN[CHAIN.index(stage) - 1]
    for c in cameras:
        session.declare_subscriber(
            _key(c, before), lambda s, c=c: inbox.put((c, s.payload.to_bytes()))
        )
    return inbox


def empty_chains(
    frames: int,
    fps: float = 30.0,
    probe: Callable[[int], object] | None = None,
    layout: str = "per-camera",
) -> tuple[Stats, int]:
    """Capture stamp → world (ms) of the empty topology of ``layout``, and world frames
    received; ``probe(pid of this process)`` is called a fifth and four fifths into the
    frames."""
    port = free_port()
    zc = ZenohConfig(mode="peer", listen=[f"tcp/127.0.0.1:{port}"])
    got: list[float] = []
    seen: list[int] = []
    with zenoh.open(zenoh_config(zc)) as session:

        def on_world(sample: zenoh.Sample) -> None:
            head = sample.payload.to_bytes()[:STAMP]
            got.append((time.time_ns() - int.from_bytes(head[:8], "little")) / 1e6)
            seen.append(int.from_bytes(head[8:], "little"))

        session.declare_subscriber("bench/topology/world", on_world)
        every = list(range(CAMERAS))
        if layout == "per-stage":  # receivers first
            roles = [(stage, every) for stage in reversed(CHAIN)]
        else:
            roles = [(stage, [c]) for c in every for stage in reversed(CHAIN)]
        procs = [
            _spawn(port, stage, cams, frames, fps, layout)
            for stage, cams in [*roles, ("fusion", every)]
        ]
        try:
            start = _start_when_listening(session, len(procs), procs)
            for part in (0.2, 0.8) if probe is not None else ():
                time.sleep(max(0.0, start + part * frames / fps - time.time()))
                probe(os.getpid())
            for p in procs:
                p.wait(timeout=start - time.time() + frames / fps + 30)
        finally:
            for p in procs:
                if p.poll() is None:
                    p.kill()
    return stats(got), len(set(seen))


def _spawn(
    port: int, stage: str, cameras: list[int], frames: int, fps: float, layout: str
) -> subprocess.Popen[bytes]:
    """One empty stage's process (this module's ``__main__``)."""
    args = [str(port), stage, ",".join(map(str, cameras)), str(frames), str(fps), layout]
    return subprocess.Popen([sys.executable, "-m", "benchmarks.topology", *args])


def _start_when_listening(
    session: zenoh.Session, count: int, procs: list[subprocess.Popen[bytes]]
) -> float:
    """Wait until all ``count`` processes listen, then tell the captures when to start
    (a second later: the peers' direct links are made by then)."""
    deadline = time.monotonic() + 120.0
    while (seen := len(list(session.liveliness().get(ALIVE, timeout=1.0)))) < count:
        exited = [p.args[4:6] for p in procs if p.poll() is not None]
        if time.monotonic() > deadline or exited:
            raise RuntimeError(f"{seen} of the {count} empty stages started; exited: {exited}")
        time.sleep(0.2)
    start = time.time() + 1.0
    session.put("bench/topology/go", repr(start))
    return start


if __name__ == "__main__":
    port, stage, cameras, frames, fps, layout = sys.argv[1:7]
    cams = [int(c) for c in cameras.split(",")]
    _stage(int(port), stage, cams, int(frames), float(fps), layout)
