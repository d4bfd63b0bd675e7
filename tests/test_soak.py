"""Soak: the whole pipeline for a bounded time at a high frame rate — no leaks, no
unbounded queues, and no sequence number lost except those counted as dropped.

Duration and rate come from OVIS_SOAK_S (default 20) and OVIS_SOAK_FPS (default 60);
the benchmark (benchmarks/) measures the highest rate sustained without drops."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest
from pipeline_helpers import STAGES, running_pipeline

from ovis.common.messages import Topics
from ovis.services.cli.watching import collect_status

# alone: memory and latency over a minute of frames at their rate
pytestmark = pytest.mark.alone

SOAK_S = float(os.environ.get("OVIS_SOAK_S", "20"))
SOAK_FPS = float(os.environ.get("OVIS_SOAK_FPS", "60"))


def _rss(session) -> dict[str, float]:
    return {
        r.service: r.status.rss_mb
        for r in collect_status(session, Topics("default"))
        if r.status is not None
    }


@pytest.mark.slow
def test_soak(tmp_path: Path) -> None:
    with running_pipeline(tmp_path, f"fps = {SOAK_FPS}\nprerender = 90") as pipe:
        session, rec = pipe.session, pipe.rec
        time.sleep(5)  # warm-up
        start = rec.count()
        samples = []
        t_end = time.monotonic() + SOAK_S
        while time.monotonic() < t_end:
            samples.append(_rss(session))
            time.sleep(min(10.0, max(0.1, t_end - time.monotonic())))
        samples.append(_rss(session))
        msgs = rec.since(start)
        statuses = {r.service: r.status for r in collect_status(session, Topics("default"))}
    seqs = sorted({m.seq for m in msgs})
    expected = seqs[-1] - seqs[0] + 1
    missing = expected - len(seqs)
    pose = statuses["pose"]
    capture = statuses["capture"]
    rate = len(seqs) / SOAK_S
    print(
        f"\nsoak {SOAK_S:.0f} s at {SOAK_FPS:g} fps: {len(seqs)} frames received "
        f"({rate:.1f}/s), {missing} missing, pose counted {pose.dropped} dropped; RSS MB "
        f"first/last: { {k: (round(samples[0][k]), round(samples[-1][k])) for k in samples[0]} }"
    )
    assert rate > 0.5 * SOAK_FPS
    # Every lost sequence number was counted as dropped by the pose service (its own
    # newest-wins drops plus the gaps it saw upstream).
    assert missing <= pose.dropped, (missing, pose.dropped)
    assert capture.frames_out >= len(seqs)
    # Memory is flat: growth from the first to the last sample stays small.
    for name in STAGES:
        growth = samples[-1][name] - samples[0][name]
        assert growth < 20.0, f"{name} grew {growth:.1f} MB over {SOAK_S:.0f} s"
