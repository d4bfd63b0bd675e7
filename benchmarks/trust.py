"""What the proof of origin costs (issue 28, docs/trust.md): per frame, the pose stage
signs its ObstacleFrame and each consumer verifies it (Ed25519 over the key expression
and the payload, :mod:`ovis.common.trust`); per calibration, the calibrator signs it and
every stage verifies each answer. Each as a ratio to one frame's processing (the four
stages' work in one process, :func:`benchmarks.bus.in_process`) measured in the same run.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec

from benchmarks.bus import PRERENDER, in_process
from benchmarks.core import Row, Stats, ratio, scaled_config, stats
from ovis.common.calibration.file import calibration_from_config
from ovis.common.capture.sources import SimSource
from ovis.common.messages import CalibrationUpdate, ObstacleFrame, Topics, encode
from ovis.common.trust.keys import PublicKeyFile, load_or_create_private
from ovis.common.trust.proof import Signer, Verifier
from ovis.common.world.detection import Detector

__all__ = ["trust_rows"]


#: Calls before the timed ones (caches, the first key load).
WARMUP = 20


def _timed(fn: Callable[[], Any], reps: int) -> Stats:
    for _ in range(WARMUP):
        fn()
    samples = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        samples.append((time.perf_counter() - t0) * 1e3)
    return stats(samples)


def _obstacle_payload(config: Any) -> bytes:
    """A simulated frame's ObstacleFrame, as the pose stage publishes it."""
    frame = SimSource(config, config.service.seed).read()[0]
    det = Detector(config.camera, config.image, config.pose).detect(frame, stamp_s=0.0)
    return encode(
        ObstacleFrame(
            seq=1,
            stamp_ns=time.time_ns(),
            published_ns=time.time_ns(),
            frame_age_ms=1.0,
            calibration_version=1,
            robot=next((o for o in det.objects if o.kind == "robot"), None),
            obstacles=[o for o in det.objects if o.kind == "obstacle"],
            planner=det.planner,
            arena="default",
            robots=det.robots,
        )
    )


def _run_of(payload: bytes, n: int) -> list[bytes]:
    """``n`` messages like ``payload``, each the next ``seq`` of one run when it has one
    (so that a verifier takes each: none is a replay, :mod:`ovis.common.trust.order`)."""
    fields = msgspec.msgpack.decode(payload)
    if "seq" not in fields:
        return [payload] * n
    return [msgspec.msgpack.encode({**fields, "seq": fields["seq"] + i}) for i in range(n)]


def trust_rows(quick: bool, log=print) -> list[Row]:
    reps = 300 if quick else 2000
    config = scaled_config(480, 640)
    frame = in_process(config, PRERENDER[480], 100 if quick else 300)
    log(f"  a frame's processing in one process: p50 {frame.p50:.3f} ms")
    topics = Topics("default")
    calib = msgspec.structs.replace(calibration_from_config(config), version=1, epoch="e" * 16)
    payloads = {
        "ObstacleFrame": (topics.obstacles, _obstacle_payload(config)),
        "CalibrationUpdate": (topics.calibration, encode(CalibrationUpdate(calibration=calib))),
    }
    rows: list[Row] = []
    with tempfile.TemporaryDirectory(prefix="ovis-bench-keys-") as tmp:
        key = Path(tmp) / "pose.key"
        signer = Signer(load_or_create_private(key))
        verifier = Verifier(PublicKeyFile(key.with_suffix(".pub")))
        for what, (key_expr, payload) in payloads.items():
            sign = _timed(lambda k=key_expr, p=payload: signer.attachment(k, p), reps)
            run = [(p, signer.attachment(key_expr, p)) for p in _run_of(payload, reps + WARMUP)]
            received, problems = iter(run), []
            check = _timed(
                lambda k=key_expr, got=received, out=problems: out.append(
                    verifier.problem(k, *next(got))
                ),
                reps,
            )
            assert problems == [None] * len(run), set(problems)  # each taken, as a stage would
            both = sign.p50 + check.p50
            log(
                f"  {what} ({len(payload)} B): sign p50 {sign.p50 * 1e3:.1f} µs, verify "
                f"p50 {check.p50 * 1e3:.1f} µs, {both / frame.p50:.3f} of a frame"
            )
            r = ratio(both, frame.p50)
            rows.append(
                Row(
                    f"Proof of origin: sign + verify one {what} ({len(payload)} B) vs one "
                    "frame's processing (the four stages' work in one process)",
                    "ms",
                    both,
                    floor=frame.p50,
                    ratio=r,
                )
            )
            rows.append(Row(f"Proof of origin: sign one {what}", "ms", sign.p50))
            rows.append(Row(f"Proof of origin: verify one {what}", "ms", check.p50))
    return rows
