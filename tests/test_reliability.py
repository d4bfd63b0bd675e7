"""Faults survived, bad input refused, nothing lost (issue 5), on real processes.

Supervision by `ovis up`, a router restart, frames that stop, a kill during a save, a
corrupt saved calibration, fuzzed payloads on every input topic and query, and
back-pressure from a flood of frames."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import msgspec
import numpy as np
import pytest
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pipeline_helpers import STAGES, Recorder, errors_of, running_pipeline, start_up, up_log_dir
from zenoh_helpers import alive, client, free_port, ovis_cmd, pids_with, spawn, stop, wait_for

from ovis.common.calibration.file import Calibration, load_calibration
from ovis.common.calibration.store import CalibrationStore
from ovis.common.config import load_config
from ovis.common.messages import (
    ENCODING,
    CalibrateReply,
    Frame,
    ServiceStatus,
    StreamHealth,
    Topics,
    decode,
    encode,
)
from ovis.services.cli.watching import collect_status

# alone: a flood and a restart within seconds
pytestmark = pytest.mark.alone

TOPICS = Topics("default")


def _statuses(session: zenoh.Session) -> dict[str, ServiceStatus]:
    return {r.service: r.status for r in collect_status(session, TOPICS) if r.status}


def _calibration(version: int = 1) -> Calibration:
    cfg = load_config()
    return Calibration(
        version=version,
        dipe_px=0.5,
        dipe_mm=0.13,
        dipe_max_px=0.8,
        dipe_max_mm=0.2,
        camera=cfg.camera,
        image=cfg.image,
        pose=cfg.pose,
    )


# --- saved state ------------------------------------------------------------------------
SAVER = """
import sys
from ovis.common.calibration.store import CalibrationStore
from ovis.common.calibration.file import Calibration
from ovis.common.config import load_config
cfg = load_config()
c = Calibration(dipe_px=0.5, dipe_mm=0.1, dipe_max_px=0.6, dipe_max_mm=0.2,
                camera=cfg.camera, image=cfg.image, pose=cfg.pose)
store = CalibrationStore(sys.argv[1])
store.save(c)  # one whole save first: a kill before any save completes leaves nothing to keep
print("ready", flush=True)
while True:
    store.save(c)
"""


def test_kill_during_save_always_leaves_the_last_good_calibration(tmp_path: Path) -> None:
    store = CalibrationStore(tmp_path)
    rng = random.Random(0)
    last = 0
    for _ in range(12):
        proc = subprocess.Popen(
            [sys.executable, "-c", SAVER, str(tmp_path)], stdout=subprocess.PIPE
        )
        assert proc.stdout.readline().strip() == b"ready"
        time.sleep(rng.uniform(0.005, 0.08))  # somewhere in the middle of some save
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        calib, problems = store.latest()
        assert problems == [] and calib is not None
        assert calib.version >= last
        last = calib.version
        current = load_calibration(tmp_path / "current.json")  # never half-written
        assert current.version in (calib.version, calib.version - 1)
    assert last > 12
    # Temporary files of interrupted saves never shadow a version.
    assert all(
        p.name.startswith((".", "calibration-v", "current", "epoch")) for p in tmp_path.iterdir()
    )


def test_corrupt_or_hand_edited_calibration_is_refused_and_the_previous_kept(
    tmp_path: Path,
) -> None:
    store = CalibrationStore(tmp_path)
    store.save(_calibration())
    store.save(_calibration())
    data = json.loads(store.path(2).read_text())
    data["camera"]["lam_mm"] = -3.0  # a hand edit out of range
    store.path(2).write_text(json.dumps(data))
    store.path(3).write_text('{"format": "ovis-calibration", "version": 3, "dipe')  # truncated
    calib, problems = store.latest()
    assert calib is not None and calib.version == 1
    assert len(problems) == 2
    assert "calibration-v0003.json is not valid JSON" in problems[0]
    assert "at `$.camera.lam_mm`" in problems[1]
    # The calibrator service starts on v1, counts and logs the refusals, and keeps running.
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = spawn(ovis_cmd("router", "--listen", endpoint), tmp_path / "router.log")
    calibrator = spawn(
        ovis_cmd("run", "calibrator", "--connect", endpoint, "--state-dir", str(tmp_path)),
        tmp_path / "calibrator.log",
    )
    try:
        with client(endpoint) as session:
            st = wait_for(lambda: _statuses(session).get("calibrator"), 30, "calibrator status")
            # v1 saved again as the next version: stages that hold v2 take only a newer one
            assert st.calibration_version == 4
            assert st.errors.get("bad_saved_calibration") == 2
    finally:
        stop([calibrator, router])
    log = (tmp_path / "calibrator.log").read_text()
    assert "loaded calibration v1" in log and "lam_mm" in log and "Traceback" not in log
    assert "restored v1@" in log and " as v4@" in log
    assert load_calibration(store.path(4)).camera == load_calibration(store.path(1)).camera


# --- a running pipeline ---------------------------------------------------------------
@pytest.fixture(scope="module")
def pipeline(tmp_path_factory: pytest.TempPathFactory):
    tmp = tmp_path_factory.mktemp("reliability")
    with running_pipeline(tmp, "fps = 12.0\nframe_timeout_s = 1.5\nstatus_period_s = 0.5") as p:
        yield p


def _still_correct(
    rec: Recorder, frames: int = 8, timeout: float = 30, injected_seq: int | None = None
) -> None:
    """The next ``frames`` obstacle messages match the truth; those of frames a test
    injected itself (``injected_seq``: still draining from a flood) are not the capture's."""
    n = rec.count()
    wait_for(lambda: rec.count() - n >= frames, timeout, f"{frames} more obstacle messages")
    real = [m for m in rec.since(n) if m.seq != injected_seq]
    errors, missed, spurious = errors_of(real, rec.truth)
    assert errors and (missed, spurious) == (0, 0) and max(errors) < 1.0


msgpack_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**63), 2**64 - 1)
    | st.floats()
    | st.text(max_size=8)
    | st.binary(max_size=64),
    lambda children: (
        st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4)
    ),
    max_leaves=12,
)
typed_maps = st.builds(
    lambda tag, fields: {"type": tag, **fields},
    st.sampled_from(["frame", "binary", "blobs", "calibration", "calibrate", "obstacles"]),
    st.dictionaries(
        st.sampled_from(
            [
                "seq",
                "stamp_ns",
                "rows",
                "cols",
                "channels",
                "data",
                "bits",
                "blobs",
                "threshold",
                "calibration_version",
                "calibration",
                "x",
            ]
        ),
        msgpack_values,
        max_size=8,
    ),
)
payloads = (
    st.binary(max_size=2048)
    | msgpack_values.map(lambda v: msgspec.msgpack.encode(v))
    | typed_maps.map(lambda v: msgspec.msgpack.encode(v))
)


def test_fuzzed_payloads_on_every_input_are_refused_and_counted(pipeline) -> None:
    session: zenoh.Session = pipeline.session
    enc = zenoh.Encoding(ENCODING)
    before = _statuses(session)
    sent = {"n": 0}

    @settings(
        max_examples=60,
        deadline=None,
        database=None,
        suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    )
    @given(
        payload=payloads,
        key=st.sampled_from(
            [TOPICS.frames, TOPICS.binary, TOPICS.blobs, TOPICS.calibration, TOPICS.calibrate]
        ),
    )
    def feed(payload: bytes, key: str) -> None:
        if key == TOPICS.calibrate:
            replies = list(session.get(key, payload=payload, timeout=20))
            assert replies and replies[0].ok is not None  # always an answer
            answer = decode(replies[0].ok.payload.to_bytes(), CalibrateReply)
            if payload:  # an empty payload is a valid "calibrate the latest frame"
                assert not answer.ok or answer.version >= 1
        else:
            session.put(key, payload, encoding=enc)
            time.sleep(0.02)
        sent["n"] += 1

    feed()
    assert sent["n"] >= 60
    after = wait_for(
        lambda: (s := _statuses(session)) and all(k in s for k in STAGES) and s, 10, "statuses"
    )
    refused = sum(
        sum(after[s].errors.values()) - sum(before[s].errors.values())
        for s in ("preprocess", "label", "pose", "calibrator")
    )
    assert refused > 0
    assert alive(session) >= set(STAGES)
    _still_correct(pipeline.rec)


def test_a_flood_of_frames_is_dropped_not_queued(pipeline) -> None:
    session: zenoh.Session = pipeline.session
    st0 = _statuses(session)["preprocess"]
    frame = encode(
        Frame.from_image(np.full((480, 640), 60, np.uint8), seq=0, stamp_ns=time.time_ns())
    )
    enc = zenoh.Encoding(ENCODING)
    block = zenoh.CongestionControl.BLOCK  # every frame really reaches preprocess
    t0 = time.monotonic()
    for _ in range(400):  # ≈ 120 MB as fast as we can: far more than preprocess can take
        session.put(TOPICS.frames, frame, encoding=enc, congestion_control=block)
    flood_s = time.monotonic() - t0
    st1 = wait_for(lambda: (s := _statuses(session).get("preprocess")) and s, 10, "status")
    assert st1.dropped > st0.dropped  # newest-wins: the backlog was dropped and counted
    assert st1.rss_mb < st0.rss_mb + 60  # memory did not follow the flood
    assert flood_s < 30
    _still_correct(pipeline.rec, injected_seq=0)


@pytest.mark.processes_kept_by_the_module  # the new router replaces the pipeline's
def test_stages_survive_a_router_restart(pipeline) -> None:
    procs, tmp, endpoint = pipeline.procs, pipeline.tmp, pipeline.endpoint
    rec: Recorder = pipeline.rec
    procs["router"].send_signal(signal.SIGKILL)
    procs["router"].wait()
    time.sleep(1.0)
    n = rec.count()
    procs["router"] = spawn(ovis_cmd("router", "--listen", endpoint), tmp / "router2.log")
    wait_for(lambda: rec.count() - n >= 5, 60, "obstacles after the router came back")
    assert all(p.poll() is None for name, p in procs.items() if name != "router")
    _still_correct(rec)


def test_frames_that_stop_are_reported_as_no_data(pipeline) -> None:
    session: zenoh.Session = pipeline.session
    health: list[StreamHealth] = []
    # on the module's session: undeclared at the end (its thread would run on otherwise)
    sub = session.declare_subscriber(
        TOPICS.health, lambda s: health.append(decode(s.payload.to_bytes(), StreamHealth))
    )
    try:
        wait_for(lambda: any(h.state == "ok" for h in health), 10, "health 'ok' while flowing")
        watch = subprocess.Popen(
            ovis_cmd(
                "watch",
                "--connect",
                pipeline.endpoint,
                "--duration",
                "12",
                "--trust",
                str(pipeline.tmp / "state" / "keys"),
            ),
            stdout=subprocess.PIPE,
            text=True,
        )
        time.sleep(3)
        capture = pipeline.procs["capture"]
        capture.send_signal(signal.SIGKILL)  # the camera is gone: no more frames
        capture.wait()
        t0 = time.monotonic()
        stalled = wait_for(
            lambda: next((h for h in health if h.state == "stalled"), None),
            10,
            "a 'stalled' health message",
        )
    finally:
        sub.undeclare()
    assert time.monotonic() - t0 < 1.5 + 0.5 + 3.0  # timeout + period + slack
    assert stalled.seconds_since_frame >= 1.5 and stalled.last_seq >= 0
    out, _ = watch.communicate(timeout=30)
    assert "NO DATA: frames stalled" in out
    assert _statuses(session)["pose"].state == "no frames"


# --- supervision by `ovis up` ---------------------------------------------------------
def test_up_restarts_a_stage_that_dies(tmp_path: Path) -> None:
    up, endpoint, err = start_up(tmp_path, "--fps", "10")
    try:
        with client(endpoint) as session:
            rec = Recorder(session)
            wait_for(lambda: rec.count() >= 5, 60, "obstacles from ovis up")
            log_dir = up_log_dir(err)
            (victim,) = pids_with(f"run label --config {log_dir}")
            os.kill(victim, signal.SIGKILL)
            t_kill = time.monotonic()
            n = rec.count()
            wait_for(lambda: rec.count() - n >= 5, 40, "obstacles again after the restart")
            resumed = time.monotonic() - t_kill
            st = wait_for(
                lambda: (s := _statuses(session).get("label")) and s.restarts and s,
                20,
                "label to report its restart",
            )
            assert st.restarts == 1 and st.pid != victim
        up.send_signal(signal.SIGTERM)
        out, _ = up.communicate(timeout=60)
    finally:
        if up.poll() is None:
            up.kill()
    assert up.returncode == 0, err.read_text()
    summary = json.loads(out)
    assert summary["restarts"] == {"label": 1}
    assert "label died (killed by SIGKILL); restarting in 0 s" in err.read_text()
    assert resumed < 40
    assert pids_with(log_dir) == []
