"""Several cameras fused across hosts (issue 19), with a stage split out onto the other
host (issue 38): the two cameras' captures, and one label and one pose process serving
both cameras, on one host; one preprocess process serving both cameras and the fusion
service on another, each host with its own router and the two routers meshed across the
link between them. Each host is a Linux network namespace (the lab of
tests/test_multihost.py)::

      host-a 10.231.0.1  router A (deploy router-a.json5); the capture of camera "west"
                         and of camera "east" (each its own process: two scenes);
                         ``ovis run label`` and ``ovis run pose`` serving both cameras
                         (clients of router A); a subscriber of the world topic
      host-b 10.231.0.2  router B (router-b.json5); ``ovis run preprocess --cameras
                         east,west`` and ``ovis run fusion`` (clients of B); a subscriber
                         of the world and of both cameras' obstacles and truth; the ovis
                         CLI (``ovis status``)

both joined by a veth link to a bridge in a "switch" namespace, Zenoh shared memory off.
The cameras look at the two halves of a floor (east's 300 cm along X, as in
test_fusion_service.py's two-chains test), unsynchronised, at 15 frames/s.

Every frame crosses to host B and its binary image back to host A. Checks: world
frames of both cameras reach host B and hold every object of each camera's frame once,
where that camera saw it, within 1 cm of the simulator's truth; each camera's stages
answer `ovis status` on its own rows, one process per stage serving both; the world is
as readable on host A; cutting host B's link makes fusion's status say that no camera's
frames come, and once it is back world frames of both cameras flow again within a bound
and both chains run at their full rate (how long they paused during the cut is printed
with ``pytest -s``: see docs/deployment.md); no process dies or logs a Traceback.

Needs root and iproute2 (``ip netns``); skips with the reason otherwise.
"""

from __future__ import annotations

import copy
import sys
import time
import tomllib
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
import tomli_w
from test_multihost import (
    FPS,
    Lab,
    Records,
    Write,
    assert_none_died_or_crashed,
    cli_json,
    decoded,
    run_probe,
    running_lab,
    wait_for,
)

# alone: network namespaces of fixed names; no world frame lost to a cut
pytestmark = pytest.mark.alone

HOSTS = {"host-a": 1, "host-b": 2}
ROUTER_NAMES = {"ovis-router-a": "host-a", "ovis-router-b": "host-b"}
CAMERAS = ("east", "west")  # sorted, as a world frame lists them
EAST_SHIFT_CM = 300.0  # the east camera and its half of the floor, along X
#: unsynchronised cameras at FPS: frames within half a period are one instant
MATCH_WINDOW_MS = 500.0 / FPS
CUT_S = 6.0  # host B's link down: longer than the 3 s Zenoh lease, so the mesh breaks
#: world positions against the simulator's truth: the bound the single-host tests
#: (test_multihost.py, test_fusion_service.py) hold each camera's own chain to; fusion of
#: non-overlapping halves must pass each camera's positions through unchanged
TRUTH_TOLERANCE_CM = 1.0
#: from the link back to a world frame of both cameras: the routers retry connecting to
#: each other every 1 s doubling to 4 s (Zenoh's default back-off), an attempt made while
#: the link was down may still be failing (ARP, 3 s), then a frame of each camera
RECOVERY_S = 10.0
SILENT = "no frames from east, west (area uncovered)"


# --- the subscriber run on each host: `python test_multihost_fusion.py probe ...` -------
def subscribe_world(session: Any, key: str, write: Write) -> None:
    """World frames, and each camera's obstacles (what fusion takes of them) and truth."""
    from ovis.common.messages import ObstacleFrame, TruthFrame, WorldFrame
    from ovis.services.fusion import frame_columns

    def camera(sample: Any) -> str:
        return str(sample.key_expr).split("/")[3]  # ovis/<arena>/cam/<name>/…

    def on_world(sample: Any) -> None:
        rx = time.time_ns()
        w = decoded(sample, WorldFrame, write)
        if w is None:
            return
        objs = [[o.kind, o.x_cm, o.y_cm, o.radius_cm, o.sigma_cm, o.cameras] for o in w.objects]
        write(
            {
                "k": "w", "seq": w.seq, "stamp": w.stamp_ns, "rx": rx, "cameras": w.cameras,
                "missing": w.missing, "late": w.late_frames, "objs": objs,
            }
        )  # fmt: skip

    def on_obstacles(sample: Any) -> None:
        m = decoded(sample, ObstacleFrame, write)
        if m is None:
            return
        seen = frame_columns(camera(sample), m).to_list()
        objs = [[d.kind, d.x_cm, d.y_cm, d.radius_cm] for d in seen]
        write(
            {
                "k": "co", "cam": camera(sample), "seq": m.seq, "stamp": m.stamp_ns,
                "rx": time.time_ns(), "objs": objs,
            }
        )  # fmt: skip

    def on_truth(sample: Any) -> None:
        t = decoded(sample, TruthFrame, write)
        if t is None:
            return
        objs = [[o.kind, o.x_cm, o.y_cm, o.radius_cm] for o in t.objects]
        write({"k": "ct", "cam": camera(sample), "seq": t.seq, "objs": objs})

    session.declare_subscriber(f"{key}/world", on_world)
    session.declare_subscriber(f"{key}/cam/*/obstacles", on_obstacles)
    session.declare_subscriber(f"{key}/cam/*/truth", on_truth)


def worlds(rec: Records, since_ns: int = 0) -> list[dict[str, Any]]:
    """World frames received (at ``rx``) after ``since_ns``."""
    return [w for w in rec.poll().other.get("w", []) if w["rx"] > since_ns]


def of_both(ws: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [w for w in ws if w["cameras"] == list(CAMERAS)]


def judge(rec: Records, ws: list[dict[str, Any]]) -> tuple[int, list[float], list[float]]:
    """World frames of both cameras against the two camera frames they were made of: the
    world holds each camera's objects once, where it saw them (asserted); and against
    the simulator's truth of those frames (no object missed or extra, asserted). Returns
    how many frames were judged, the position errors (cm) and error/sigma_cm ratios."""
    from ovis.common.analysis.evaluation import match_to_truth

    frames = rec.poll().other.get("co", [])
    truth = {(t["cam"], t["seq"]): t["objs"] for t in rec.other.get("ct", [])}
    window = MATCH_WINDOW_MS * 1e6
    judged, errors, ratios = 0, [], []
    for w in of_both(ws):
        mine = [f for f in frames if abs(f["stamp"] - w["stamp"]) <= window]
        if sorted(f["cam"] for f in mine) != list(CAMERAS):
            continue  # a camera frame not (yet) recorded
        seen = sorted((o[0], round(o[1], 6), round(o[2], 6)) for f in mine for o in f["objs"])
        fused = sorted((o[0], round(o[1], 6), round(o[2], 6)) for o in w["objs"])
        assert fused == seen, f"world frame {w['seq']}: {fused} != cameras' {seen}"
        for o in w["objs"]:  # the halves do not overlap: one camera each, the right one
            assert o[5] == (["east"] if o[1] > EAST_SHIFT_CM - 50 else ["west"]), o
        if any((f["cam"], f["seq"]) not in truth for f in mine):
            continue
        true = [o for f in mine for o in truth[(f["cam"], f["seq"])]]
        acc = match_to_truth(
            [o[1:4] for o in w["objs"]],
            [o[0] for o in w["objs"]],
            [o[1:] for o in true],
            [o[0] for o in true],
        )
        assert (acc.missed, acc.spurious, bool(acc.kind_correct.all())) == (0, 0, True), (w, true)
        errors.extend(acc.position_error_cm.tolist())
        sigma = np.array([w["objs"][i][4] for i in acc.detection_index])
        ratios.extend((acc.position_error_cm / sigma).tolist())
        judged += 1
    return judged, errors, ratios


# --- the lab ---------------------------------------------------------------------------
def fusion_configs(conf: dict[str, Path]) -> None:
    """Beside deploy/'s role files with the test settings (``conf``, from write_configs):
    a capture file per camera (capture.toml's: router A, the simulated camera; its
    camera_name, seed, pose and half of the floor), the camera host's stages' file
    (capture.toml's, router A, with both cameras' models in [[cameras]]), the fusion
    file (processing.toml's: router B; both cameras' models and the matching of
    unsynchronised frames; host B's preprocess serves the cameras with it too), a
    subscriber file per host."""
    folder = conf["capture"].parent
    from ovis.common.config import load_config

    capture = tomllib.loads(conf["capture"].read_text())
    default = load_config(conf["capture"])
    models = {}
    for name, seed, shift in (("west", 11, 0.0), ("east", 12, EAST_SHIFT_CM)):
        data = copy.deepcopy(capture)
        data["service"].update(camera_name=name, seed=seed)
        # the chains sign with the keys the lab's hosts share (fusion trusts them there)
        data["trust"] = {"keys_dir": str(folder / "keys")}
        data["camera"] = {"X0_cm": default.camera.X0_cm + shift}
        data["simulator"] = {"arena_x_cm": [x + shift for x in default.simulator.arena_x_cm]}
        conf[name] = folder / f"{name}.toml"
        conf[name].write_text(tomli_w.dumps(data))
        models[name] = load_config(conf[name]).camera
    fusion = tomllib.loads(conf["processing"].read_text())
    fusion["cameras"] = [{"name": n, "camera": msgspec.to_builtins(m)} for n, m in models.items()]
    fusion["fusion"] = {"match_window_ms": MATCH_WINDOW_MS, "wait_ms": 40.0}
    fusion["service"]["frame_timeout_s"] = 1.0  # a camera silent this long is not waited for
    conf["fusion"] = folder / "fusion.toml"
    conf["fusion"].write_text(tomli_w.dumps(fusion))
    stages = copy.deepcopy(capture)
    stages["cameras"] = fusion["cameras"]
    stages["trust"] = {"keys_dir": str(folder / "keys")}
    conf["stages-a"] = folder / "stages-a.toml"
    conf["stages-a"].write_text(tomli_w.dumps(stages))
    subscriber = tomllib.loads(conf["subscriber"].read_text())
    for host, router in (("host-a", "ovis-router-a"), ("host-b", "ovis-router-b")):
        subscriber["zenoh"]["connect"] = [f"tcp/{router}:7447"]
        conf[f"subscriber-{host}"] = folder / f"subscriber-{host}.toml"
        conf[f"subscriber-{host}"].write_text(tomli_w.dumps(subscriber))


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory):
    t0 = time.monotonic()
    with running_lab(tmp_path_factory, "multihost-fusion", HOSTS, ROUTER_NAMES) as (lb, conf):
        tmp = lb.tmp
        fusion_configs(conf)
        recs = {}
        for host in HOSTS:
            out = tmp / f"probe-{host}.jsonl"
            lb.spawn(
                host, f"probe-{host}",
                [str(Path(__file__).resolve()), "probe", "--config",
                 str(conf[f"subscriber-{host}"]), "--key", "ovis/default", "--out", str(out)],
            )  # fmt: skip
            recs[host] = Records(out)
        lb.ovis("host-b", "fusion", "run", "fusion", "--config", str(conf["fusion"]))
        for stage in ("pose", "label"):  # one process per stage serving both cameras
            lb.ovis("host-a", stage, "run", stage, "--config", str(conf["stages-a"]))
        cameras = ",".join(CAMERAS)  # the stage split out onto the other host
        lb.ovis("host-b", "preprocess", "run", "preprocess", "--config", str(conf["fusion"]),
                "--cameras", cameras)  # fmt: skip
        for cam in CAMERAS:
            lb.ovis("host-a", f"capture-{cam}", "run", "capture", "--config", str(conf[cam]))
        wait_for(
            lambda: len(of_both(worlds(recs["host-b"]))) >= 10,
            60,
            "10 world frames of both cameras on host B",
            lb,
        )
        print(f"\n[multihost-fusion] 2 hosts, 2 chains and fusion up in "
              f"{time.monotonic() - t0:.1f} s")  # fmt: skip
        yield {"lab": lb, "conf": conf, "a": recs["host-a"], "b": recs["host-b"]}


def fusion_state(lb: Lab, conf: dict[str, Path]) -> str | None:
    """Fusion's state as `ovis status` on host B shows it (None: not listed as alive).

    Not listed happens during a cut: from the lease's expiry until about 10 s after the
    cut (or the link's return), router B answers no query of a client that connects
    meanwhile (Zenoh's router while it drops the dead link to router A; seen with raw
    Zenoh queries too, not ovis's doing)."""
    rows = cli_json(lb, "host-b", "status", "--config", str(conf["subscriber-host-b"]))
    row = next((r for r in rows if r["service"] == "fusion"), None)
    return row["status"]["state"] if row and row["alive"] and row["status"] else None


# --- the checks ------------------------------------------------------------------------
def test_world_of_both_cameras_on_the_fusion_host_matches_truth(lab) -> None:
    lb: Lab = lab["lab"]
    b: Records = lab["b"]
    since = time.time_ns()
    wait_for(lambda: len(of_both(worlds(b, since))) >= 30, 30, "30 world frames on B", lb)
    time.sleep(0.5)  # the camera frames of the last world frames are recorded too
    judged, errors, ratios = judge(b, worlds(b, since))
    assert judged >= 20, f"only {judged} world frames could be judged"
    assert max(errors) < TRUTH_TOLERANCE_CM, f"worst world position error {max(errors):.3f} cm"
    seqs = [w["seq"] for w in worlds(b)]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), "world frames lost on host B"
    assert not b.bad
    print(
        f"\n[multihost-fusion] host B: {judged} world frames of both cameras judged; "
        f"position error vs truth mean {np.mean(errors):.3f} cm, max {max(errors):.3f} cm "
        f"(max {max(ratios):.1f} sigma_cm)"
    )


def test_each_camera_has_its_rows_served_by_one_process_per_stage_across_hosts(lab) -> None:
    lb: Lab = lab["lab"]
    rows = cli_json(lb, "host-b", "status", "--config", str(lab["conf"]["subscriber-host-b"]))
    got = {(r["camera"], r["service"]): r for r in rows}
    for stage in ("capture", "preprocess", "label", "pose"):
        assert all(got[(cam, stage)]["alive"] for cam in CAMERAS), stage
    for stage, name in (("preprocess", "preprocess"), ("label", "label"), ("pose", "pose")):
        pids = {got[(cam, stage)]["status"]["pid"] for cam in CAMERAS}
        assert pids == {lb.procs[name].pid}, (stage, pids)  # one process for both
    captures = {got[(cam, "capture")]["status"]["pid"] for cam in CAMERAS}
    assert captures == {lb.procs[f"capture-{cam}"].pid for cam in CAMERAS}  # one each
    for cam in CAMERAS:  # each camera's frames went through host B's preprocess
        pre = got[(cam, "preprocess")]["status"]
        assert pre["frames_out"] > 30 and pre["state"] == "ok", (cam, pre)


def test_world_is_readable_on_the_camera_host(lab) -> None:
    lb: Lab = lab["lab"]
    a: Records = lab["a"]
    b: Records = lab["b"]
    since = time.time_ns()
    wait_for(lambda: len(of_both(worlds(a, since))) >= 20, 20, "20 world frames on A", lb)
    on_a = worlds(a, since)
    on_b = {w["seq"]: w for w in worlds(b)}  # read after A's: B's has them all
    # the same world frames as on host B: same objects, same cameras
    assert all(w["seq"] in on_b for w in on_a[:-3])
    same = [w for w in on_a if w["seq"] in on_b]
    assert all(
        (w["stamp"], w["cameras"], w["objs"]) == (on_b[w["seq"]]["stamp"],
        on_b[w["seq"]]["cameras"], on_b[w["seq"]]["objs"]) for w in same
    )  # fmt: skip
    assert not a.bad


def test_link_cut_between_hosts_is_reported_and_healed(lab) -> None:
    lb: Lab = lab["lab"]
    a: Records = lab["a"]
    b: Records = lab["b"]
    conf = lab["conf"]
    assert fusion_state(lb, conf) == "ok"
    t_cut, t_cut_ns = time.monotonic(), time.time_ns()
    lb.link("host-b", up=False)
    try:
        # within 20 s: past the router's pause described in fusion_state
        wait_for(lambda: fusion_state(lb, conf) == SILENT, 20, "fusion to report both silent", lb)
        reported = time.monotonic() - t_cut
        time.sleep(max(0.0, CUT_S - (time.monotonic() - t_cut)))
    finally:
        lb.link("host-b", up=True)
    t_up, t_up_ns = time.monotonic(), time.time_ns()
    cut = t_up - t_cut
    # the chains on host A pause while their preprocess on host B is cut off: measured,
    # not asserted (see docs/deployment.md)
    pauses = {}
    for cam in CAMERAS:
        rx = np.array([f["rx"] for f in a.poll().other["co"] if f["cam"] == cam]) / 1e9
        during = rx[(rx >= t_cut_ns / 1e9) & (rx <= t_up_ns / 1e9)]
        pauses[cam] = round(float(np.diff([t_cut_ns / 1e9, *during, t_up_ns / 1e9]).max()), 2)
    back = wait_for(
        lambda: of_both(worlds(b, t_up_ns)), RECOVERY_S, "world frames of both cameras", lb
    )[0]
    back_after = (back["rx"] - t_up_ns) / 1e9
    wait_for(lambda: len(of_both(worlds(b, t_up_ns))) >= 30, 20, "30 world frames after", lb)
    wait_for(lambda: of_both(worlds(a, t_up_ns)), 10, "the world on host A again", lb)
    resumed = {}
    for cam in CAMERAS:  # each chain on host A at its full rate again, once it resumed
        # (its preprocess is on host B: it resumes when the routers meet again, within
        # RECOVERY_S, as the world frames above)
        rx = [f["rx"] for f in a.poll().other["co"] if f["cam"] == cam and f["rx"] > t_up_ns]
        assert rx, f"camera {cam}'s chain on host A did not resume"
        resumed[cam] = round((rx[0] - t_up_ns) / 1e9, 2)
        assert resumed[cam] <= RECOVERY_S, (cam, resumed[cam])
        rate_s = (time.time_ns() - rx[0]) / 1e9
        assert len(rx) >= FPS * rate_s - 2 * FPS, (cam, len(rx), rate_s)
    state_after = wait_for(
        lambda: (s := fusion_state(lb, conf)) == "ok" and s, 15, "fusion 'ok' again", lb
    )
    time.sleep(0.5)  # the camera frames of the last world frames
    after = worlds(b, t_up_ns)
    judged, errors, _ = judge(b, after)
    assert judged >= 20 and max(errors) < TRUTH_TOLERANCE_CM, (judged, max(errors))
    # nothing stale: no frame captured during the cut came out of a queue afterwards
    gap = [w for w in worlds(b) if t_cut_ns + 1e9 < w["stamp"] < t_up_ns]
    oldest = max((w["rx"] - w["stamp"]) / 1e6 for w in after)
    assert not gap, f"{len(gap)} world frames of frames captured while the link was down"
    assert oldest < 1000.0, f"a world frame {oldest:.0f} ms old after the link came back"
    seqs = [w["seq"] for w in worlds(b)]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    print(
        f"\n[multihost-fusion] host B's link down {cut:.1f} s: fusion's status said "
        f"{SILENT!r} {reported:.1f} s after the cut; world frames of both cameras back "
        f"{back_after:.1f} s after the link, status {state_after!r}; {judged} judged after, "
        f"worst error {max(errors):.3f} cm; oldest world frame after {oldest:.0f} ms; "
        f"late camera frames {after[-1]['late']}; longest pause of each chain on host A "
        f"during the cut {pauses} s, resumed {resumed} s after the link"
    )


def test_no_process_died_or_crashed(lab) -> None:
    assert_none_died_or_crashed(lab["lab"], lab["a"], lab["b"])


if __name__ == "__main__" and sys.argv[1:2] == ["probe"]:
    run_probe(sys.argv[2:], subscribe_world)
