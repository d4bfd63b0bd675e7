"""deploy/examples/subscribe_obstacles.py against real Zenoh on loopback (no mocks).

A router runs in this test process; the example runs as a subprocess with only zenoh and
msgpack, and receives ObstacleFrames encoded by ovis itself.
"""

from __future__ import annotations

import ast
import json
import math
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

import pytest
import zenoh

from ovis.common.messages import ENCODING, ObstacleFrame, Topics, TruthFrame, encode
from ovis.common.trust.keys import load_or_create_private
from ovis.common.trust.proof import Signer
from ovis.common.world.detection import DetectedObject, PlannerEntry
from ovis.common.world.robots import RobotState

EXAMPLE = Path(__file__).resolve().parents[1] / "deploy" / "examples" / "subscribe_obstacles.py"
TIMEOUT_S = 20.0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def _router() -> Iterator[tuple[zenoh.Session, str]]:
    """A Zenoh router in this process, listening on a free loopback port."""
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    try:
        yield session, endpoint
    finally:
        session.close()


class _Lines:
    """Collects a pipe's lines on a thread (so the test never blocks on a read)."""

    def __init__(self, stream: IO[str]) -> None:
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream: IO[str]) -> None:
        for line in stream:
            self.lines.append(line.rstrip("\n"))

    def join(self, timeout: float = 5.0) -> None:
        self._thread.join(timeout)


@pytest.fixture(scope="module", autouse=True)
def _pose_key(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """The pose stage's key pair, as `ovis up` makes it: the test signs with it, the
    example trusts its public half."""
    global SIGNER, TRUST
    key_file = tmp_path_factory.mktemp("keys") / "pose.key"
    SIGNER, TRUST = Signer(load_or_create_private(key_file)), str(key_file.with_suffix(".pub"))
    yield


SIGNER: Signer
TRUST = ""


def _spawn(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, str(EXAMPLE), "--trust", TRUST, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
        text=True,
    )


def _stop(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.wait(5)


def _obj(id: int, kind: str, x: float, y: float, r: float) -> DetectedObject:
    return DetectedObject(
        id=id,
        kind=kind,
        row=100.0 + y,
        col=200.0 + x,
        area_px=321.0,
        perimeter_px=64.5,
        compactness=1.02 if kind == "obstacle" else 1.6,
        x_cm=x,
        y_cm=y,
        z_cm=5.0 if kind == "obstacle" else 12.0,
        radius_cm=r,
        area_cm2=math.pi * r * r,
        heading_deg=30.0 if kind == "robot" else None,
        elongation=1.0,
    )


def _robots(seq: int) -> list[RobotState]:
    return [
        RobotState(
            id=i,
            name=f"bot{i}",
            marker_id=10 + i,
            x_cm=20.0 * i + seq,
            y_cm=30.5,
            z_cm=5.0,
            heading_deg=-135.25 + i,
            vx_cm_s=12.0,
            vy_cm_s=-3.5,
            yaw_rate_deg_s=0.0,
            age_s=0.0 if i == 1 else 0.25,
            radius_cm=9.0,
        )
        for i in (1, 2)
    ]


def _frame(seq: int, *, robot: bool = True, marked: bool = False) -> ObstacleFrame:
    """A frame whose values depend on seq, so a line printed can be matched to its frame."""
    obstacles = [
        _obj(2 + seq % 3, "obstacle", 10.0 + seq, 20.5, 4.25),
        _obj(7, "obstacle", -3.5, 40.0, 6.0),
    ]
    return ObstacleFrame(
        seq=seq,
        stamp_ns=1_700_000_000_000_000_000 + seq,
        published_ns=1_700_000_000_010_000_000 + seq,
        frame_age_ms=10.0,
        calibration_version=4,
        robot=_obj(1, "robot", 50.0, 60.25, 9.0) if robot else None,
        obstacles=obstacles,
        planner=[
            PlannerEntry(obstacle_id=o.id, distance_cm=12.5 + seq + i, angle_deg=-45.25 + 90 * i)
            for i, o in enumerate(obstacles)
        ],
        robots=_robots(seq) if marked else [],
    )


def _publish_until(
    session: zenoh.Session,
    proc: subprocess.Popen[str],
    out: _Lines,
    n_lines: int,
    *,
    robot: bool = True,
    junk: bool = False,
    marked: bool = False,
) -> dict[int, ObstacleFrame]:
    """Publish frames (seq 0, 1, …) every 50 ms until ``n_lines`` lines or the process ends."""
    publisher = session.declare_publisher(
        Topics("default").obstacles, encoding=zenoh.Encoding(ENCODING)
    )
    sent: dict[int, ObstacleFrame] = {}
    deadline = time.monotonic() + TIMEOUT_S
    seq = 0
    key = Topics("default").obstacles

    def put(payload: bytes) -> None:  # as the pose stage publishes: with its proof
        publisher.put(payload, attachment=SIGNER.attachment(key, payload))

    try:
        while len(out.lines) < n_lines and proc.poll() is None:
            assert time.monotonic() < deadline, f"only {out.lines} after {TIMEOUT_S} s"
            if junk:  # each must be skipped, not printed and not fatal
                put(b"\xc1 not msgpack")
                put(encode(TruthFrame(seq=seq, objects=[])))
                put(b"\x93\x01\x02\x03")  # an array, not a map
                # and a frame without the proof (seq beyond any sent): dropped, counted
                publisher.put(encode(_frame(10**6 + seq, robot=robot, marked=marked)))
                if seq:  # and the previous genuine frame again, with its proof: a replay
                    put(encode(sent[seq - 1]))
            sent[seq] = _frame(seq, robot=robot, marked=marked)
            put(encode(sent[seq]))
            seq += 1
            time.sleep(0.05)
    finally:
        publisher.undeclare()
    return sent


def test_json_lines_carry_the_published_frames() -> None:
    with _router() as (session, endpoint):
        proc = _spawn("--connect", endpoint, "--count", "3", "--json")
        try:
            assert proc.stdout is not None and proc.stderr is not None
            out, err = _Lines(proc.stdout), _Lines(proc.stderr)
            sent = _publish_until(session, proc, out, 3, junk=True)
            assert proc.wait(TIMEOUT_S) == 0, "\n".join(err.lines)
        finally:
            _stop(proc)
    out.join()
    err.join()
    got = [json.loads(line) for line in out.lines]
    assert len(got) == 3, out.lines
    seqs = [g["seq"] for g in got]
    assert seqs == list(range(seqs[0], seqs[0] + 3))  # FIFO on loopback: none lost
    for g in got:
        frame = sent[g["seq"]]
        assert set(g) == {"seq", "stamp_ns", "calibration_version", "robot", "obstacles", "planner"}
        assert g["stamp_ns"] == frame.stamp_ns
        assert g["calibration_version"] == 4
        assert g["robot"]["id"] == 1 and g["robot"]["kind"] == "robot"
        assert (g["robot"]["x_cm"], g["robot"]["y_cm"]) == (50.0, 60.25)
        assert [o["id"] for o in g["obstacles"]] == [o.id for o in frame.obstacles]
        assert [o["x_cm"] for o in g["obstacles"]] == [o.x_cm for o in frame.obstacles]
        assert [o["radius_cm"] for o in g["obstacles"]] == [4.25, 6.0]
        assert g["obstacles"][0]["heading_deg"] is None
        assert [(p["obstacle_id"], p["distance_cm"], p["angle_deg"]) for p in g["planner"]] == [
            (p.obstacle_id, p.distance_cm, p.angle_deg) for p in frame.planner
        ]
    skipped = [line for line in err.lines if line.startswith("skipped")]
    assert any("not MessagePack" in line for line in skipped), err.lines
    assert any("expected type 'obstacles', got 'truth'" in line for line in skipped), err.lines
    assert any("expected a map, got list" in line for line in skipped), err.lines
    assert all(g["seq"] < 10**6 for g in got)  # the unproven frames were never printed
    assert any(line.startswith("dropped 1 unproven message(s) (no proof of origin)")
               for line in err.lines), err.lines  # fmt: skip
    assert any("unproven message(s) (replayed: seq" in line for line in err.lines), err.lines
    assert len(seqs) == len(set(seqs))  # the replayed frames were never printed again


def test_text_output_names_robot_and_each_obstacle() -> None:
    with _router() as (session, endpoint):
        proc = _spawn("--connect", endpoint, "--count", "2")
        try:
            assert proc.stdout is not None and proc.stderr is not None
            out, err = _Lines(proc.stdout), _Lines(proc.stderr)
            sent = _publish_until(session, proc, out, 6)  # 3 lines per frame
            assert proc.wait(TIMEOUT_S) == 0, "\n".join(err.lines)
        finally:
            _stop(proc)
    out.join()
    assert len(out.lines) == 6, out.lines
    first = int(out.lines[0].split()[1])
    frame = sent[first]
    assert out.lines[0] == (
        f"frame {first} (calibration v4): robot at (50.0, 60.2) cm heading 30.0 deg, 2 obstacle(s)"
    )
    o, p = frame.obstacles[0], frame.planner[0]
    assert out.lines[1] == (
        f"  obstacle {o.id}: at ({o.x_cm:.1f}, 20.5) cm, radius 4.2 cm, "
        f"distance {p.distance_cm:.1f} cm, angle -45.2 deg"
    )
    assert out.lines[2] == (
        "  obstacle 7: at (-3.5, 40.0) cm, radius 6.0 cm, "
        f"distance {frame.planner[1].distance_cm:.1f} cm, angle 44.8 deg"
    )


def test_marked_robots_are_printed_with_heading_and_velocity() -> None:
    with _router() as (session, endpoint):
        text = _spawn("--connect", endpoint, "--count", "1")
        lines = _spawn("--connect", endpoint, "--count", "1", "--json")
        try:
            assert text.stdout is not None and lines.stdout is not None
            out, js = _Lines(text.stdout), _Lines(lines.stdout)
            sent = _publish_until(session, text, out, 5, marked=True)
            while lines.poll() is None and not js.lines:
                _publish_until(session, lines, js, 1, marked=True)
            assert text.wait(TIMEOUT_S) == 0 and lines.wait(TIMEOUT_S) == 0
        finally:
            _stop(text)
            _stop(lines)
    out.join()
    js.join()
    first = int(out.lines[0].split()[1])
    x = 20.0 + sent[first].robots[0].x_cm - 20.0
    assert out.lines[3] == (
        f"  robot 1 bot1: at ({x:.1f}, 30.5) cm, heading -134.2 deg, velocity (12.0, -3.5) "
        "cm/s, seen 0.00 s ago"
    )
    assert out.lines[4].startswith("  robot 2 bot2:") and out.lines[4].endswith("seen 0.25 s ago")
    got = json.loads(js.lines[0])
    assert [(r["id"], r["marker_id"], r["heading_deg"]) for r in got["robots"]] == [
        (1, 11, -134.25),
        (2, 12, -133.25),
    ]


def test_a_frame_without_robot_is_printed_too() -> None:
    with _router() as (session, endpoint):
        proc = _spawn("--connect", endpoint, "--count", "1", "--json")
        try:
            assert proc.stdout is not None and proc.stderr is not None
            out, err = _Lines(proc.stdout), _Lines(proc.stderr)
            _publish_until(session, proc, out, 1, robot=False)
            assert proc.wait(TIMEOUT_S) == 0, "\n".join(err.lines)
        finally:
            _stop(proc)
    out.join()
    assert json.loads(out.lines[0])["robot"] is None


def test_ctrl_c_closes_the_session_and_exits() -> None:
    with _router() as (_session, endpoint):
        proc = _spawn("--connect", endpoint)
        try:
            assert proc.stderr is not None
            err = _Lines(proc.stderr)
            deadline = time.monotonic() + TIMEOUT_S
            while not any(line.startswith("subscribed to") for line in err.lines):
                assert proc.poll() is None, err.lines
                assert time.monotonic() < deadline, err.lines
                time.sleep(0.05)
            proc.send_signal(signal.SIGINT)
            assert proc.wait(10) == 130
        finally:
            _stop(proc)
    err.join()
    assert err.lines[-1] == "interrupted"


def test_no_router_is_a_one_line_error() -> None:
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    proc = subprocess.run(
        [sys.executable, str(EXAMPLE), "--trust", TRUST, "--connect", endpoint, "--count", "1"],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert proc.returncode == 1
    assert proc.stdout == ""
    assert proc.stderr.startswith("error: ") and endpoint in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize(
    "args,needle",
    [
        (["--arena", "a/b"], "arena name 'a/b' must be 1-64 letters"),
        (["--count", "0"], "must be >= 1, got 0"),
        (["--trust", "/nonexistent/pose.pub"], "cannot read the pose stage's public key"),
    ],
)
def test_bad_arguments_exit_2(args: list[str], needle: str) -> None:
    proc = subprocess.run(
        [sys.executable, str(EXAMPLE), *args], capture_output=True, text=True, timeout=TIMEOUT_S
    )
    assert proc.returncode == 2
    assert needle in proc.stderr


def test_example_needs_only_zenoh_msgpack_and_cryptography() -> None:
    tree = ast.parse(EXAMPLE.read_text())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            imported.add(node.module.split(".")[0])
    third_party = imported - set(sys.stdlib_module_names) - {"__future__"}
    assert third_party == {"zenoh", "msgpack", "cryptography"}  # the last for the proof


def test_ctrl_c_ends_it_even_when_the_suite_was_started_with_sigint_ignored() -> None:
    """The suite started as a shell without job control starts a background command
    (SIGINT ignored, which every child inherits): the Ctrl-C test above still passes,
    since the suite takes SIGINT back at its start (tests/conftest.py). Without that,
    the subscriber never saw the signal and the test timed out in such runs only."""
    here = Path(__file__).resolve()
    test = f"{here}::test_ctrl_c_closes_the_session_and_exits"
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", test],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=here.parents[1],
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    assert proc.returncode == 0, proc.stdout[-2000:]
    assert "1 passed" in proc.stdout
