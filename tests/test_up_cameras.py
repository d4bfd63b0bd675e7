"""`ovis up --cameras 2x2` end to end (issue 19): a real process starting a router, four
real capture → preprocess → label → pose chains rendering the simulated grid, and the
fusion service; its JSON summary scores the fused world against the ground truth, and
counts the world frames it refused for want of the fusion key's proof of origin."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import tempfile
import time
from pathlib import Path

import msgspec
import pytest
from zenoh_helpers import client, free_port, ovis_cmd, wait_for

from ovis.common.messages import ENCODING, Topics, WorldFrame, decode, encode
from ovis.common.trust.keys import PublicKeyFile, load_or_create_private
from ovis.common.trust.proof import Signer, Verifier
from ovis.services.trust import attachment_of

# alone: a killed stage back within 1.5 s, its gap's frames counted at 15 frames/s
pytestmark = pytest.mark.alone

CAMERAS = ("cam00", "cam10", "cam01", "cam11")
STAGES = ("capture", "preprocess", "label", "pose")
WORLD = Topics("default").world
#: forged world frames published by another client: unsigned, then with the pose key
FORGED = 5


def _up(
    tmp_path: Path, duration_s: int, layout: str | None = None
) -> tuple[list[str], dict[str, str]]:
    """The `ovis up --cameras 2x2` command and its environment: on a loaded, shared 2-core
    host the world waits longer for a late camera and the cameras run at 15 frames/s (the
    30 frames/s budget is the benchmark's); the prerendered periods are kept between
    runs in the system's temporary folder; the keys in ``tmp_path/state/keys``."""
    cfg = tmp_path / "wait.toml"
    cfg.write_text(f"[fusion]\nwait_ms = 250.0\n[service]\nstate_dir = '{tmp_path / 'state'}'\n")
    env = dict(os.environ, OVIS_CACHE=str(Path(tempfile.gettempdir()) / "ovis-test-cache"))
    args = ["up", "--cameras", "2x2", "--duration", str(duration_s), "--json", "--seed", "7"]
    args += ["--fps", "15", "--listen", f"tcp/127.0.0.1:{free_port()}", "--config", str(cfg)]
    args += ["--layout", layout] if layout else []
    return ovis_cmd(*args), env


def _forge_world(endpoint: str, keys: Path, err: Path) -> None:
    """Once every camera runs: check a genuine world frame's proof with the fusion
    public key, then publish from another client ``FORGED`` copies of it moved 40 cm,
    unsigned, and (once `ovis up` said it refused them) ``FORGED`` signed with the pose
    key (trusted for obstacles, not for the world), then the genuine frame ``FORGED``
    times again (a replay)."""
    wait_for(lambda: "scoring the world" in err.read_text(), 200, "every camera running")
    with client(endpoint) as session:
        got: list[tuple[bytes, bytes | None]] = []
        session.declare_subscriber(
            WORLD, lambda s: got.append((s.payload.to_bytes(), attachment_of(s)))
        )
        wait_for(lambda: got, 20, "a genuine world frame")
        payload, proof = got[0]
        fusion = Verifier(PublicKeyFile(keys / "fusion.pub"))
        assert fusion.problem(WORLD, payload, proof) is None
        genuine = decode(payload, WorldFrame)
        moved = [msgspec.structs.replace(o, x_cm=o.x_cm + 40.0) for o in genuine.objects]
        fake = encode(msgspec.structs.replace(genuine, seq=10**6, objects=moved))
        pub = session.declare_publisher(WORLD, encoding=ENCODING)
        for _ in range(FORGED):
            pub.put(fake)
        said = "proof of origin from the fusion service (last: no proof of origin)"
        wait_for(lambda: said in err.read_text(), 20, "ovis up saying it refused them")
        pose = Signer(load_or_create_private(keys / "pose.key"))
        for _ in range(FORGED):
            pub.put(fake, attachment=pose.attachment(WORLD, fake))
        said = f"(last: signed by key {pose.kid.hex()}, not the trusted"
        wait_for(lambda: said in err.read_text(), 20, "ovis up saying it refused those")
        for _ in range(FORGED):  # the genuine first one again, its proof genuine: a replay
            pub.put(payload, attachment=proof)


def test_up_cameras_2x2_gives_one_clean_world(tmp_path: Path) -> None:
    cmd, env = _up(tmp_path, 14)
    err = tmp_path / "up.err"
    with err.open("w") as log:
        up = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, text=True, env=env)
    try:
        endpoint = cmd[cmd.index("--listen") + 1]
        _forge_world(endpoint, tmp_path / "state" / "keys", err)
        out, _ = up.communicate(timeout=240)
    finally:
        if up.poll() is None:
            up.kill()
    stderr = err.read_text()
    assert up.returncode == 0, stderr[-3000:]
    summary = json.loads(out)
    # the default layout: one process per stage serving every camera; it said where each
    # runs (label alone on the last core, the others on the one before; any core on a
    # 1-core host) and where the logs are
    assert summary["layout"] == "per-stage" and summary["processes"] == 6
    allowed = sorted(os.sched_getaffinity(0))
    last, other = (allowed[-1], allowed[-2]) if len(allowed) >= 2 else ("any", "any")
    assert f"label on {last}," in stderr and "logs in" in stderr
    assert all(f"{name} on {other}" in stderr for name in ("capture", "preprocess", "pose"))
    assert f"fusion on {other}" in stderr
    assert summary["grid"] == "2x2" and summary["seed"] == 7
    # what the processes cost per world frame, from /proc, over the scored window
    cpu = summary["cpu"]
    assert cpu["frames"] >= 0.8 * world_frames(summary) and cpu["window_s"] > 10
    assert set(cpu["by_process_ms"]) >= {"router", "fusion", *STAGES}
    assert cpu["ms_per_frame"] == pytest.approx(sum(cpu["by_process_ms"].values()), abs=0.01)
    assert 0 < cpu["ms_per_frame"] < 2e3 / 15  # less than the two cores' frame period
    cams = summary["cameras"]
    assert sorted(cams) == sorted(CAMERAS)
    world = summary["world"]
    for name, c in cams.items():
        assert c["processed"] > 100, (name, c)
        # every count is consistent: nothing fused that was not processed, not captured
        assert c["fused"] <= c["processed"] + 1 and c["processed"] <= c["captured"] + 1, c
        assert c["dropped"] == max(0, c["captured"] - c["fused"])
        assert c["fused"] <= world["frames"]
        assert c["restarts"] == 0
    # the first second after every camera ran is the start-up: its frames counted apart
    startup = summary["startup"]
    assert startup["seconds"] == 1.0 and sorted(startup["cameras"]) == sorted(CAMERAS)
    for c in startup["cameras"].values():
        assert 0 <= c["dropped"] <= c["captured"]
    assert world["scored"] >= 0.8 * world["frames"] > 0
    # the forged world frames were refused, counted, and the summary says the last why
    assert world["unproven"] == 3 * FORGED, world
    assert world["unproven_why"].startswith("replayed or out of order: seq "), world
    assert world["duplicates"] == 0
    assert world["identity_swaps"] == 0
    assert world["phantoms"] == 0
    assert world["handovers"] > 0  # robots did cross from one view to the next
    assert world["handover_jump_cm"] <= 1.0
    assert world["world_error_cm"]["mean"] <= 0.5
    assert 0 < world["latency_ms"]["p50"] <= world["latency_ms"]["p99"]


def world_frames(summary: dict) -> int:
    return summary["world"]["frames"]


def test_up_cameras_refuses_what_cannot_go_with_the_grid() -> None:
    bad = subprocess.run(
        ovis_cmd("up", "--cameras", "2x2", "--source", "camera:0"), capture_output=True, text=True
    )
    assert bad.returncode == 2
    assert "--cameras runs the simulated grid: not with --source" in bad.stderr
    bad = subprocess.run(ovis_cmd("up", "--cameras", "9x9"), capture_output=True, text=True)
    assert bad.returncode == 2 and "give columns x rows, e.g. 2x2" in bad.stderr
    bad = subprocess.run(
        ovis_cmd("up", "--cameras", "2x2", "--layout", "per-host"), capture_output=True, text=True
    )
    assert bad.returncode == 2 and "Invalid enum value 'per-host'" in bad.stderr
    bad = subprocess.run(ovis_cmd("up", "--layout", "per-stage"), capture_output=True, text=True)
    assert bad.returncode == 2 and "--layout lays out several cameras" in bad.stderr


def _child(parent: int, *words: str) -> int | None:
    """The pid of a child of ``parent`` whose command line holds every word."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if int(stat[1]) == parent and all(w in cmd for w in words):
            return int(entry.name)
    return None


def _kill_and_sum_up(up: subprocess.Popen[bytes], victim: int | None, err: Path) -> dict:
    """Kill ``victim`` (a child of the running ``up``: None fails), wait for `ovis up` to
    end by itself and give its summary (it exits 0)."""
    try:
        assert victim is not None, err.read_text()[-2000:]
        os.kill(victim, signal.SIGKILL)
        out, _ = up.communicate(timeout=200)
    finally:
        if up.poll() is None:
            up.kill()
    assert up.returncode == 0, err.read_text()[-3000:]
    return json.loads(out)


def test_up_cameras_restarts_a_killed_chain_stage_and_the_others_go_on(tmp_path: Path) -> None:
    """The per-camera layout: a camera's chain of its own processes; one of them killed
    costs that camera alone."""
    cmd, env = _up(tmp_path, 18, "per-camera")
    err = tmp_path / "up.err"
    with err.open("w") as log:
        up = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, env=env)
    deadline = time.monotonic() + 150
    victim = None
    try:
        while victim is None and time.monotonic() < deadline:
            capture = _child(up.pid, "run capture", "--cameras cam11")
            victim = _child(up.pid, "run pose", "--cameras cam01") if capture else None
            time.sleep(0.5)
        time.sleep(6)  # the cameras read their period (cached by the test above) and run
    except BaseException:
        up.kill()
        up.wait()
        raise
    summary = _kill_and_sum_up(up, victim, err)
    cams, world = summary["cameras"], summary["world"]
    assert summary["layout"] == "per-camera" and summary["processes"] == 18
    assert cams["cam01"]["restarts"] >= 1
    assert "cam01-pose died (killed by SIGKILL)" in err.read_text()
    # the other chains run on, not restarted and still fusing most of their frames: the
    # restarted process's start (interpreter and imports, before it pins itself) takes
    # CPU from every chain of a 2-core machine for a moment, so some frames come late
    for name in ("cam00", "cam10", "cam11"):
        c = cams[name]
        assert c["restarts"] == 0 and c["dropped"] <= 0.25 * c["captured"], (name, c)
    # cam01 is back in the world: killed about a third of the way in and never back, it
    # would have fused about a third of what cam00 did
    assert cams["cam01"]["fused"] > 0.7 * cams["cam00"]["fused"], cams
    # around the restart an object has been reported twice a few times (3 in one
    # of four runs on a loaded host; docs/cameras.md, not done): bounded, not zero
    assert world["duplicates"] <= 5 and world["phantoms"] == 0, world


def test_up_cameras_a_killed_stage_process_is_back_within_1_5_s_for_every_camera(
    tmp_path: Path,
) -> None:
    """The per-stage layout: the label process serves every camera; killed, a spare
    takes over and every camera's obstacles are back within 1.5 s, each camera's gap
    counted (its frames captured and never in the world), the world clean after."""
    cmd, env = _up(tmp_path, 18)
    endpoint = cmd[cmd.index("--listen") + 1]
    err = tmp_path / "up.err"
    with err.open("w") as log:
        up = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, env=env)
    received: dict[str, list[float]] = {name: [] for name in CAMERAS}
    try:
        wait_for(lambda: "scoring the world" in err.read_text(), 200, "every camera running")
        with client(endpoint) as session:
            session.declare_subscriber(
                "ovis/default/cam/*/obstacles",
                lambda s: received[str(s.key_expr).split("/")[3]].append(time.monotonic()),
            )
            # the spare is started a few seconds after its stage: it has done its imports
            wait_for(lambda: _child(up.pid, "run --standby label"), 30, "label's spare")
            time.sleep(4)
            victim = _child(up.pid, "run label")
            killed = time.monotonic()
            summary = _kill_and_sum_up(up, victim, err)
    finally:
        if up.poll() is None:
            up.kill()
    assert "label died (killed by SIGKILL)" in err.read_text()
    gaps = {}
    for name, times in received.items():
        before = [t for t in times if t <= killed]
        after = [t for t in times if t > killed]
        assert before and after, name
        gaps[name] = after[0] - before[-1]
    assert max(gaps.values()) <= 1.5, gaps
    cams, world = summary["cameras"], summary["world"]
    for name, c in cams.items():
        # each camera's frames of the gap counted as never in the world (the gap's ends
        # jitter by a frame each side of the 15 frames/s); its process restarted once;
        # the rest of its frames fused
        assert c["restarts"] == 1 and c["dropped"] >= 15 * gaps[name] - 3, (name, c, gaps)
        assert c["fused"] >= 0.75 * c["captured"], (name, c)
    assert world["duplicates"] <= 5 and world["phantoms"] == 0, world
