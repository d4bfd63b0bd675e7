"""One process per stage serving every camera of a host (issue 38), as real processes on
loopback Zenoh: ``ovis run capture|preprocess|label|pose`` each serve the three cameras
of ``[[cameras]]`` (north and south on the simulated arena, east on a camera that is
not there). Each camera keeps its own topics, counters, status and calibration, and
what goes wrong with one camera stays with it: a bad frame, a lost source, an
impossible calibration; a calibrator serving two cameras keeps a store per camera."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import msgspec
import numpy as np
import pytest
import zenoh
from pipeline_helpers import errors_of
from zenoh_helpers import client, free_port, ovis_cmd, spawn, stop, wait_for

from ovis.common.calibration.file import calibration_from_config
from ovis.common.config import dump_toml, load_config
from ovis.common.messages import (
    ENCODING,
    CalibrationUpdate,
    Frame,
    ObstacleFrame,
    ServiceStatus,
    StreamHealth,
    Topics,
    TruthFrame,
    decode,
    encode,
)
from ovis.common.trust.keys import load_or_create_private
from ovis.common.trust.proof import Signer
from ovis.services.cli.watching import camera_statuses

CAMERAS = ("north", "south", "east")
SEEING = ("north", "south")  # east's camera is not there: its source is lost
STAGES = ("capture", "preprocess", "label", "pose")
FPS = 15.0
TOPICS = Topics("default")


class Camera:
    """One camera's obstacle frames (with their receipt, monotonic s), truth and health."""

    def __init__(self, session: zenoh.Session, name: str) -> None:
        self.obstacles: list[tuple[ObstacleFrame, float]] = []
        self.truth: dict[int, TruthFrame] = {}
        self.health: list[StreamHealth] = []
        self.lock = threading.Lock()
        cam = TOPICS.of_camera(name)
        session.declare_subscriber(cam.obstacles, self._obstacles)
        session.declare_subscriber(cam.truth, self._truth)
        session.declare_subscriber(cam.health, self._health)

    def _obstacles(self, sample: zenoh.Sample) -> None:
        msg = decode(sample.payload.to_bytes(), ObstacleFrame)
        with self.lock:
            self.obstacles.append((msg, time.monotonic()))

    def _truth(self, sample: zenoh.Sample) -> None:
        msg = decode(sample.payload.to_bytes(), TruthFrame)
        with self.lock:
            self.truth[msg.seq] = msg

    def _health(self, sample: zenoh.Sample) -> None:
        msg = decode(sample.payload.to_bytes(), StreamHealth)
        with self.lock:
            self.health.append(msg)

    def since(self, t: float) -> list[ObstacleFrame]:
        with self.lock:
            return [m for m, rx in self.obstacles if rx > t]


@dataclass
class Host:
    endpoint: str
    session: zenoh.Session
    cameras: dict[str, Camera]
    procs: dict[str, subprocess.Popen[bytes]]
    tmp: Path
    config: Path


def _arena(endpoint: str, tmp: Path) -> Path:
    data = msgspec.to_builtins(load_config())
    data["zenoh"]["connect"] = [endpoint]
    data["service"].update(
        fps=FPS, seed=5, prerender=20, state_dir=str(tmp / "state"), frame_timeout_s=1.0
    )
    sources = {"north": "sim", "south": "sim", "east": "/dev/video-ovis-none"}
    data["cameras"] = [{"name": n, "source": sources[n], "camera": data["camera"]} for n in CAMERAS]
    path = tmp / "arena.toml"
    path.write_text(dump_toml(data))
    return path


def statuses(session: zenoh.Session) -> dict[tuple[str, str], ServiceStatus]:
    """(camera, stage) → its status, as `ovis status` lists them."""
    return {
        (r.camera, r.service): r.status
        for r in camera_statuses(session, TOPICS)
        if r.status and r.camera
    }


@pytest.fixture(scope="module")
def host(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Host]:
    tmp = tmp_path_factory.mktemp("stage-host")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = _arena(endpoint, tmp)
    # the calibrator's key, which the test signs an impossible calibration with
    load_or_create_private(tmp / "state" / "keys" / "calibrator.key")
    procs = {"router": spawn(ovis_cmd("router", "--listen", endpoint), tmp / "router.log")}
    for stage in reversed(STAGES):  # one process per stage, serving every camera
        procs[stage] = spawn(ovis_cmd("run", stage, "--config", str(config)), tmp / f"{stage}.log")
    try:
        with client(endpoint) as session:
            cameras = {n: Camera(session, n) for n in CAMERAS}
            for name in SEEING:
                wait_for(lambda n=name: cameras[n].since(0), 120, f"{name}'s obstacles")
            yield Host(endpoint, session, cameras, procs, tmp, config)
    finally:
        stop([p for n, p in procs.items() if n != "router"])
        stop([procs["router"]])
    for stage in STAGES:
        assert "Traceback" not in (tmp / f"{stage}.log").read_text(), stage


def test_every_camera_has_its_topics_and_status_from_one_process_per_stage(host: Host) -> None:
    t0 = time.monotonic()
    for name in SEEING:
        cam = host.cameras[name]
        wait_for(lambda c=cam: len(c.since(t0)) >= 20, 30, f"20 obstacle frames of {name}")
        msgs = cam.since(t0)
        seqs = [m.seq for m in msgs]
        assert seqs == sorted(seqs) and max(np.diff(seqs)) <= 2, (name, seqs)
        errors, missed, spurious = errors_of(msgs, cam.truth)
        assert len(errors) >= 3 * 10 and (missed, spurious) == (0, 0), name
        assert max(errors) < 1.0, name
    got = statuses(host.session)
    # east's stages wait for a calibration of its real camera (none: not listening yet)
    assert set(got) == {(c, s) for c in SEEING for s in STAGES} | {("east", "capture")}
    for stage in STAGES:  # one process serves the stage of every camera
        assert {got[(c, stage)].pid for c in SEEING} == {host.procs[stage].pid}
    # each camera counts its own frames: its own capture stream, its own rate
    assert len({got[(c, "capture")].stream for c in SEEING}) == 2
    for name in SEEING:
        assert got[(name, "pose")].fps > 0.6 * FPS, got[(name, "pose")]
    # `ovis status` shows a row per camera and stage
    out = subprocess.run(
        ovis_cmd("status", "--connect", host.endpoint, "--json"),
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    rows = {(r["camera"], r["service"]): r for r in json.loads(out.stdout)}
    assert all(rows[(c, s)]["alive"] for c in SEEING for s in STAGES)
    assert rows[("east", "capture")]["alive"] and not rows[("east", "pose")]["alive"]
    assert ("north", "calibrator") in rows and not rows[("north", "calibrator")]["alive"]
    assert not any(r["camera"] is None and r["service"] in STAGES for r in rows.values())
    table = subprocess.run(
        ovis_cmd("status", "--connect", host.endpoint),
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
        env=dict(os.environ, COLUMNS="200"),
    )
    lines = [line.split("│")[1:4] for line in table.stdout.splitlines() if "│" in line]
    cells = {tuple(c.strip() for c in line) for line in lines}
    assert {("south", "label", "yes"), ("east", "capture", "yes"), ("east", "pose", "NO")} <= cells


def test_a_bad_frame_on_one_camera_is_counted_for_it_alone(host: Host) -> None:
    before = statuses(host.session)
    south = TOPICS.of_camera("south")
    enc = zenoh.Encoding(ENCODING)
    wrong_size = Frame.from_image(np.zeros((100, 120), np.uint8), seq=10**9, stamp_ns=1)
    bad = [b"", b"\x00\xff garbage", b"\xc1", encode(wrong_size), b"x" * 5000]
    t0 = time.monotonic()
    for key in (south.frames, south.binary, south.blobs):
        for payload in bad:
            host.session.put(key, payload, encoding=enc)
            time.sleep(0.03)

    def counted() -> dict[tuple[str, str], ServiceStatus]:
        now = statuses(host.session)
        grew = all(
            sum(now[("south", s)].errors.values()) > sum(before[("south", s)].errors.values())
            for s in ("preprocess", "label", "pose")
        )
        return now if grew else {}

    after = wait_for(counted, 15, "south's stages to count the bad input")
    for stage in ("preprocess", "label", "pose"):
        assert after[("north", stage)].errors == before[("north", stage)].errors, stage
        assert after[("north", stage)].state == "ok", after[("north", stage)]
    # both cameras go on at their rate, right
    wait_for(lambda: len(host.cameras["south"].since(t0)) >= 15, 15, "south after")
    for name in SEEING:
        msgs = host.cameras[name].since(t0)
        assert len(msgs) >= 10, name
        errors, missed, spurious = errors_of(msgs, host.cameras[name].truth)
        assert errors and (missed, spurious) == (0, 0) and max(errors) < 1.0, name


def test_a_lost_source_is_its_cameras_alone(host: Host) -> None:
    got = wait_for(
        lambda: (
            (s := statuses(host.session)).get(("east", "capture"))
            and s[("east", "capture")].errors.get("source", 0) >= 2
            and s
        ),
        20,
        "east's capture retrying",
    )
    east = got[("east", "capture")]
    assert east.state == "source lost" and east.source_gaps == 1 and east.gaps[0].ongoing
    wait_for(
        lambda: any(h.state == "source lost" for h in host.cameras["east"].health),
        10,
        "east's health saying its source is lost",
    )
    for name in SEEING:
        capture, pose = got[(name, "capture")], got[(name, "pose")]
        assert capture.state == "ok" and capture.source_gaps == 0, capture
        assert capture.fps > 0.6 * FPS and pose.fps > 0.6 * FPS, (capture, pose)
        # (south's may still say the bad input of the test before: degraded, not lost)
        assert host.cameras[name].health[-1].state in ("ok", "degraded"), name
    assert host.cameras["north"].health[-1].state == "ok"


def test_sigusr1_reaches_every_camera_of_a_capture_and_does_not_end_it(host: Host) -> None:
    """SIGUSR1 unplugs the physical world's camera (services/capture.py). A capture
    serving several cameras runs each camera's main in a thread, where no handler can be
    set: the process's own handler hands the signal to each camera (these simulated ones
    have nothing to unplug, and say so), and the signal's default, the process's end, is
    not taken."""
    log = host.tmp / "capture.log"
    before = log.read_text().count("SIGUSR1 ignored")
    host.procs["capture"].send_signal(signal.SIGUSR1)
    wait_for(
        lambda: log.read_text().count("SIGUSR1 ignored") >= before + len(CAMERAS),
        10,
        "each camera of the capture saying it has nothing to unplug",
    )
    t = time.monotonic()
    for name in SEEING:
        wait_for(lambda n=name: host.cameras[n].since(t), 10, f"{name}'s obstacles after it")
    assert host.procs["capture"].poll() is None


def test_an_impossible_calibration_is_refused_by_its_cameras_stages_alone(host: Host) -> None:
    """The calibration the calibrator's key signs for south puts its camera 5 m under
    the floor: south's stages refuse it (counted, said), north's never see it."""
    cfg = load_config(host.config)
    below = msgspec.structs.replace(cfg.camera, Z0_cm=-500.0)
    impossible = msgspec.structs.replace(
        calibration_from_config(cfg), camera=below, version=7, epoch="e" * 16
    )
    signer = Signer(load_or_create_private(host.tmp / "state" / "keys" / "calibrator.key"))
    key = TOPICS.of_camera("south").calibration
    payload = encode(CalibrationUpdate(calibration=impossible))
    proof = signer.attachment(key, payload)

    def answer(query: zenoh.Query) -> None:
        query.reply(key, payload, encoding=zenoh.Encoding(ENCODING), attachment=proof)

    before = statuses(host.session)
    queryable = host.session.declare_queryable(key, answer)
    try:
        host.session.put(key, payload, encoding=zenoh.Encoding(ENCODING), attachment=proof)
        after = wait_for(
            lambda: (
                all(
                    (s := statuses(host.session))[("south", stage)].errors.get("bad_calibration")
                    for stage in ("preprocess", "label", "pose")
                )
                and s
            ),
            15,
            "south's stages refusing the calibration",
        )
    finally:
        queryable.undeclare()
    for stage in ("preprocess", "label", "pose"):
        south, north = after[("south", stage)], after[("north", stage)]
        assert "not above the floor" in south.last_error, south
        assert south.calibration_version == 0  # it kept the one it had
        assert north.errors == before[("north", stage)].errors and north.state == "ok", north
    t0 = time.monotonic()
    for name in SEEING:
        wait_for(lambda n=name: len(host.cameras[n].since(t0)) >= 10, 15, f"{name} after")


def test_a_calibrator_serving_two_cameras_calibrates_each_on_its_own(host: Host) -> None:
    proc = spawn(
        ovis_cmd("run", "calibrator", "--config", str(host.config), "--cameras", "north,south"),
        host.tmp / "calibrator.log",
    )
    try:
        t0 = time.monotonic()
        for name in SEEING:
            wait_for(
                lambda n=name: any(m.calibration_version >= 1 for m in host.cameras[n].since(t0)),
                120,
                f"{name}'s obstacles made with its calibration",
            )
        before = statuses(host.session)
        # `ovis recalibrate --camera south` asks south's calibrator alone
        out = subprocess.run(
            ovis_cmd("recalibrate", "--connect", host.endpoint, "--camera", "south", "--json",
                     "--force", "--timeout", "120"),
            capture_output=True, text=True, timeout=180,
        )  # fmt: skip
        assert out.returncode == 0, out.stderr
        assert json.loads(out.stdout.splitlines()[-1])["version"] == 2
        got = wait_for(
            lambda: (s := statuses(host.session))[("south", "pose")].calibration_version == 2 and s,
            30,
            "south's stages on its second calibration",
        )
    finally:
        stop([proc])
    assert "Traceback" not in (host.tmp / "calibrator.log").read_text()
    for name in SEEING:  # each camera's versions in its own store
        assert list((host.tmp / "state" / "cam" / name).glob("calibration-v*.json")), name
        assert got[(name, "calibrator")].pid == proc.pid
    epochs = {got[(n, "pose")].calibration_epoch for n in SEEING}
    assert len(epochs) == 2 and "" not in epochs  # two stores, one per camera
    assert before[("north", "pose")].calibration_version == 1
    assert got[("north", "pose")].calibration_version == 1  # north's untouched
    assert ("east", "calibrator") not in got  # it was not asked to serve east
