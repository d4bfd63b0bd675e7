"""Recording (issue 18): does ``ovis record`` keep up with a camera?

A Zenoh router and ``ovis record`` run as separate processes on 127.0.0.1 (``Fleet``
of :mod:`benchmarks.bus`); this process publishes 640×480 grey frames of the simulated
arena (pre-rendered: its sensor noise is the worst case for compression) at 30
frames/s with congestion control BLOCK, then stops the recorder with SIGTERM and reads
the file back: every frame published must be in it, bit-exact. Separately, the
recorder's own work per frame (decode, pack the pixels, JPEG view, write: ``Recorder.
write_sample``) is timed in this process against the floor of PNG-encoding the same
frame (what the brief proposed for lossless frames).
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import msgspec
import zenoh

from benchmarks.bus import Fleet, free_port
from benchmarks.core import Row, stats, time_call
from ovis.common.capture.sources import SimSource
from ovis.common.config import ZenohConfig, load_config
from ovis.common.messages import ENCODING, Frame, Topics, encode
from ovis.common.recording.pacing import FrameGate
from ovis.common.recording.session import SessionReader, SessionWriter
from ovis.services.bus import zenoh_config
from ovis.services.recorder import Recorder

__all__ = ["recording_rows"]

FPS = 30.0
BUDGET_MS = 1000.0 / FPS


def _frames(n: int) -> list[bytes]:
    source = SimSource(load_config(), 0, prerender=n)
    return [encode(Frame.from_image(source.read()[0], seq=0, stamp_ns=0)) for _ in range(n)]


def _payload(images: list[bytes], seq: int) -> bytes:
    """Frame ``seq`` (one of the pre-rendered images, stamped now)."""
    frame = msgspec.msgpack.decode(images[seq % len(images)], type=Frame)
    return encode(msgspec.structs.replace(frame, seq=seq, stamp_ns=time.time_ns()))


def _write_cost(images: list[bytes], workdir: Path, n: int) -> tuple[list[float], list[float]]:
    """Per-frame time of the recorder's work, and of PNG-encoding the frame (floor)."""
    topics = Topics("bench")
    session = zenoh.open(zenoh_config(ZenohConfig(mode="peer", connect=[], listen=[])))
    try:
        writer = SessionWriter(workdir / "cost.mcap")
        rec = Recorder(
            session, writer, topics, [f"{topics.root}/unused"], frames=FrameGate("every")
        )
        payloads = [_payload(images, s) for s in range(n)]
        work = [
            time_call(lambda p=p: rec.write_sample(topics.frames, p, time.time_ns(), 0))
            for p in payloads
        ]
        rec.close()
    finally:
        session.close()
    image = msgspec.msgpack.decode(images[0], type=Frame).image()
    png = [time_call(lambda: cv2.imencode(".png", image)) for _ in range(n)]
    return work, png


def _work_row(which: str, value_ms: float, png_ms: float) -> Row:
    return Row(
        f"Recording 640×480 recorder work per frame {which} (floor: PNG encode)",
        "ms",
        value_ms,
        floor=png_ms,
        ratio=value_ms / png_ms,
        target=f"≤ {BUDGET_MS:.1f} ms",
        met=value_ms <= BUDGET_MS,
    )


def recording_rows(quick: bool, log: Callable[[str], None]) -> list[Row]:
    seconds = 5.0 if quick else 10.0
    images = _frames(30)
    workdir = Path(tempfile.mkdtemp(prefix="ovis-bench-record-"))
    fleet = Fleet(workdir)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    out = workdir / "session.mcap"
    sent: list[bytes] = []
    try:
        fleet.start("router", ["router", "--listen", endpoint])
        time.sleep(1.0)
        fleet.start("record", ["record", "--connect", endpoint, "--out", str(out)])
        session = zenoh.open(zenoh_config(ZenohConfig(connect=[endpoint])))
        try:
            pub = session.declare_publisher(
                "ovis/default/frames",
                encoding=zenoh.Encoding(ENCODING),
                congestion_control=zenoh.CongestionControl.BLOCK,
            )
            time.sleep(3.0)  # the recorder subscribes
            fleet.check("record")
            log(f"  publishing 640×480 frames at {FPS:g}/s for {seconds:g} s")
            t0 = time.monotonic()
            for seq in range(int(seconds * FPS)):
                payload = _payload(images, seq)
                pub.put(payload)
                sent.append(payload)
                delay = t0 + (seq + 1) / FPS - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            rate = len(sent) / (time.monotonic() - t0)
            time.sleep(1.0)
        finally:
            session.close()
        fleet.stop("record", timeout=60.0)
    finally:
        fleet.stop_all()
    reader = SessionReader(out)
    got = [m.payload() for m in reader.bus_messages() if m.topic.endswith("/frames")]
    lost = len(sent) - len(got)
    exact = got == sent
    log(f"  {len(got)}/{len(sent)} frames recorded (bit-exact: {exact}), {rate:.1f} frames/s")
    work, png = _write_cost(images, workdir, 30 if quick else 90)
    w, f = stats(work), stats(png)
    log(f"  recorder work per frame p50 {w.p50:.2f} ms p99 {w.p99:.2f} ms; PNG {f.p50:.2f} ms")
    size_mb = out.stat().st_size / max(len(got), 1) / 1e6
    return [
        Row(
            f"Recording 640×480 at {FPS:g} frames/s: frames lost of {len(sent)}",
            "frames",
            float(lost),
            target="= 0, all bit-exact",
            met=lost == 0 and exact,
        ),
        _work_row("p50", w.p50, f.p50),
        _work_row("p99", w.p99, f.p99),
        Row("Recording 640×480 file size per frame (frame + image view)", "MB", size_mb),
    ]
