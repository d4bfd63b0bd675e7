"""`ovis up` end to end: router + five processes, an independent subscriber, a summary,
and a clean shutdown with no orphans."""

from __future__ import annotations

import json
import re
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from pipeline_helpers import Recorder, errors_of, start_up, up_log_dir
from zenoh_helpers import client, pids_with, wait_for

from ovis.common.config import load_config
from ovis.common.world.planner import planner_inputs


def test_up_runs_the_pipeline_and_summarises(tmp_path: Path) -> None:
    proc, endpoint, err = start_up(tmp_path, "--duration", "14", "--fps", "15")
    try:
        with client(endpoint) as session:
            rec = Recorder(session)

            # Calibrated messages: on a loaded host the first calibration may take a
            # while, so wait for them rather than for a number of messages.
            def calibrated() -> list:
                return [m for m in rec.since(0) if m.calibration_version >= 1]

            wait_for(lambda: len(calibrated()) >= 25, 40, "25 calibrated obstacle messages")
            msgs = calibrated()
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err.read_text()
    seqs = [m.seq for m in msgs]
    assert len(msgs) >= 20 and max(np.diff(seqs)) <= 2
    errors, missed, spurious = errors_of(msgs, rec.truth)
    assert (missed, spurious) == (0, 0) and len(errors) >= 60 and max(errors) < 1.0
    # The planner inputs are those of `ovis plan` on the published positions.
    m = msgs[-1]
    goal = load_config().pose.goal_cm
    expected = planner_inputs(
        (m.robot.x_cm, m.robot.y_cm),
        [(o.x_cm, o.y_cm, o.radius_cm) for o in m.obstacles],
        goal_xy=goal,
    )
    assert [e.distance_cm for e in m.planner] == pytest.approx(expected.distance_cm.tolist())
    summary = json.loads(out)
    assert summary["frames_processed"] >= 40 and summary["frames_captured"] >= 40
    # The capture starts once every other stage is up: no frame is captured and missed
    # (at most the ones in flight when it stops).
    assert summary["frames_captured"] - summary["frames_processed"] <= 2
    assert summary["objects_missed"] == 0 and summary["position_error_cm_max"] < 1.0
    assert summary["latency_ms_p50"] > 0 and summary["calibration_version"] >= 1
    assert set(summary["exit_codes"]) == {
        "router",
        "capture",
        "preprocess",
        "label",
        "pose",
        "calibrator",
    }
    log_dir = up_log_dir(err)
    assert pids_with(log_dir) == []  # no orphans

    def logged(stage: str, what: str) -> str:
        """When ``stage`` logged ``what`` (its log's timestamp, which sorts as text)."""
        text = (Path(log_dir) / f"{stage}.log").read_text()
        return re.search(rf"^(\S+ \S+) \S+ INFO {what}", text, re.M)[1]

    # The capture starts only once every other stage listens to its inputs.
    capture = logged("capture", "started")
    listening = {s: logged(s, "listening") for s in ("preprocess", "label", "pose", "calibrator")}
    assert all(capture >= t for t in listening.values()), (capture, listening)


def test_up_stops_cleanly_on_sigterm(tmp_path: Path) -> None:
    proc, endpoint, err = start_up(tmp_path, "--fps", "10")
    try:
        with client(endpoint) as session:
            rec = Recorder(session)
            wait_for(lambda: rec.count() >= 5, 40, "obstacle messages")
        log_dir = up_log_dir(err)
        # the five stages (the router has no config), and maybe spares (`--standby`)
        spares = set(pids_with("--standby"))
        assert len(set(pids_with(log_dir)) - spares) == 5
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err.read_text()
    assert time.monotonic() - t0 < 15
    assert json.loads(out)["frames_processed"] >= 5
    assert pids_with(log_dir) == []
    assert "Traceback" not in "".join(p.read_text() for p in Path(log_dir).glob("*.log"))
