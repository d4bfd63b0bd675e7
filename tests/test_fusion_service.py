"""The fusion service as a real process on loopback Zenoh (issue 19): a real camera chain
(capture → preprocess → label → pose) publishing on its per-camera topics, fused into
``ovis/<arena>/world``; and four cameras of the simulated 2×2 arena, a camera going
silent while the others keep flowing."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import msgspec
import numpy as np
import pytest
from zenoh_helpers import alive, client, free_port, ovis_cmd, spawn, stop, wait_for

from ovis.common.analysis.multicam import detections_frame
from ovis.common.calibration.file import calibration_from_config
from ovis.common.config import FusionConfig, dump_toml, load_config
from ovis.common.fusion.scoring import WorldScorer
from ovis.common.messages import (
    ENCODING,
    CalibrationUpdate,
    ObstacleFrame,
    ServiceStatus,
    Topics,
    TruthFrame,
    WorldFrame,
    decode,
    encode,
)
from ovis.common.sim.multiview import GridScene, camera_grid, grid_arena, measure
from ovis.common.trust.keys import PublicKeyFile, load_or_create_private
from ovis.common.trust.proof import Signer, Verifier
from ovis.services.trust import attachment_of

CELL = (100.0, 75.0)
#: The simulated cameras' frame period (30 frames/s).
PERIOD_NS = 1_000_000_000 // 30


def _write(path: Path, data: dict) -> Path:
    path.write_text(dump_toml(data))
    return path


def _base(endpoint: str, tmp: Path) -> dict:
    data = msgspec.to_builtins(load_config())
    data["zenoh"]["connect"] = [endpoint]
    data["service"]["state_dir"] = str(tmp / "state")
    return data


def _signer(tmp: Path, role: str) -> Signer:
    """``role``'s signer with the key in :func:`_base`'s state folder, as the chains'
    processes sign: fusion believes only what the pose stages and calibrators signed."""
    return Signer(load_or_create_private(tmp / "state" / "keys" / f"{role}.key"))


def _put_signed(pub, signer: Signer, payload: bytes) -> None:
    pub.put(payload, attachment=signer.attachment(str(pub.key_expr), payload))


class Collector:
    """Every message on a key, decoded. Zenoh's thread only keeps the payload: decoding
    there would hold this process's interpreter (and start its garbage collections)
    while the test publishes the cameras' frames."""

    def __init__(self, session, key: str, kind) -> None:
        self._kind = kind
        self._payloads: list[bytes] = []
        self._decoded: list = []
        self._lock = threading.Lock()

        def on(sample) -> None:
            payload = sample.payload.to_bytes()
            with self._lock:
                self._payloads.append(payload)

        self._sub = session.declare_subscriber(key, on)

    def snapshot(self) -> list:
        with self._lock:
            fresh, self._payloads = self._payloads, []
            self._decoded += [decode(p, self._kind) for p in fresh]
            return list(self._decoded)


def test_a_real_camera_chain_on_its_own_topics_is_fused_into_the_world(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    chain = _base(endpoint, tmp_path)
    chain["service"].update(camera_name="north", fps=15.0, seed=5)
    fusion = _base(endpoint, tmp_path)
    fusion["cameras"] = [{"name": "north", "source": "sim", "camera": chain["camera"]}]
    chain_cfg = _write(tmp_path / "chain.toml", chain)
    fusion_cfg = _write(tmp_path / "fusion.toml", fusion)
    procs = [spawn(ovis_cmd("router", "--listen", endpoint), tmp_path / "router.log")]
    stages = ("capture", "preprocess", "label", "pose")
    procs += [
        spawn(ovis_cmd("run", s, "--config", str(chain_cfg)), tmp_path / f"{s}.log") for s in stages
    ]
    procs.append(
        spawn(ovis_cmd("run", "fusion", "--config", str(fusion_cfg)), tmp_path / "fusion.log")
    )
    cam = Topics("default").of_camera("north")
    try:
        with client(endpoint) as session:
            wait_for(lambda: "fusion" in alive(session), 60, "fusion alive")
            wait_for(lambda: set(stages) <= alive(session, "default/cam/north"), 60, "chain")
            world = Collector(session, Topics("default").world, WorldFrame)
            obstacles = Collector(session, cam.obstacles, ObstacleFrame)
            truth = Collector(session, cam.truth, TruthFrame)
            wait_for(lambda: len(world.snapshot()) >= 30, 60, "30 world frames")
    finally:
        stop(procs[1:])
        stop(procs[:1])
    for name in (*stages, "fusion"):
        log = (tmp_path / f"{name}.log").read_text()
        assert "Traceback" not in log, f"{name} log:\n{log}"
    # nothing on the single-camera topics: the chain used its camera's
    by_stamp = {m.stamp_ns: m for m in obstacles.snapshot()}
    truths = {t.seq: t for t in truth.snapshot()}
    checked = 0
    for w in world.snapshot():
        assert w.cameras == ["north"] and w.missing == []
        frame = by_stamp.get(w.stamp_ns)
        if frame is None or frame.seq not in truths:
            continue
        true_obs = [o for o in truths[frame.seq].objects if o.kind == "obstacle"]
        fused = [o for o in w.objects if o.kind == "obstacle"]
        assert len(fused) == len(frame.obstacles)
        for o in fused:
            assert o.cameras == ["north"] and o.sigma_cm > 0
            err = min(np.hypot(o.x_cm - t.x_cm, o.y_cm - t.y_cm) for t in true_obs)
            assert err < 1.0
        checked += 1
    assert checked >= 10


def test_four_cameras_fused_live_and_a_silent_camera_leaves_the_rest_flowing(
    tmp_path: Path,
) -> None:
    """The 2×2 arena's per-camera detections (simulated measurements of the ground truth,
    published as each camera's pose service would) through a real fusion process."""
    seed = 909
    specs = camera_grid(2, 2, cell_cm=CELL, seed=seed)
    scene = GridScene(*grid_arena(2, 2, CELL), robots=4, obstacles=10, seed=seed)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    data = _base(endpoint, tmp_path)
    data["cameras"] = [msgspec.to_builtins(s) for s in specs]
    data["service"]["frame_timeout_s"] = 0.5
    # a shared, loaded 2-core machine: wait up to 60 ms for a camera's frame
    data["fusion"]["wait_ms"] = 60.0
    cfg = _write(tmp_path / "fusion.toml", data)
    pose, calibrator = _signer(tmp_path, "pose"), _signer(tmp_path, "calibrator")
    procs = [spawn(ovis_cmd("router", "--listen", endpoint), tmp_path / "router.log")]
    procs.append(spawn(ovis_cmd("run", "fusion", "--config", str(cfg)), tmp_path / "fusion.log"))
    rng = np.random.default_rng(seed)
    sigma = FusionConfig().pixel_sigma_px
    topics = Topics("default")
    sent_truth: dict[int, tuple] = {}
    frames, silent_from, forged_at, recalibrated_at = 240, 150, 40, 100
    # cam00 recalibrated half-way: a focal length half as long, so each of its pixels
    # covers twice the floor and its sightings' sigma doubles; the others are untouched
    first = specs[0].camera
    halved = msgspec.structs.replace(first, fx=first.fx / 2, fy=first.fy / 2)
    recalibration = CalibrationUpdate(
        calibration=msgspec.structs.replace(
            calibration_from_config(msgspec.structs.replace(load_config(), camera=halved)),
            version=1,
        )
    )
    # a forger's push before it, without the calibrator's proof (a focal length a quarter
    # as long, a version above the genuine one): never taken
    quartered = msgspec.structs.replace(first, fx=first.fx / 4, fy=first.fy / 4)
    forged = CalibrationUpdate(
        calibration=msgspec.structs.replace(
            calibration_from_config(msgspec.structs.replace(load_config(), camera=quartered)),
            version=2**62,
        )
    )
    cam00_calibration = topics.of_camera("cam00").calibration
    try:
        with client(endpoint) as session:
            wait_for(lambda: "fusion" in alive(session), 60, "fusion alive")
            world = Collector(session, topics.world, WorldFrame)
            pubs = {
                s.name: session.declare_publisher(
                    topics.of_camera(s.name).obstacles, encoding=ENCODING
                )
                for s in specs
            }
            # Frame f is captured at start + f periods by the cameras' clock, whenever this
            # process gets to publish it: a pause here (a garbage collection, the machine's
            # load) then delays frames, as a slow network would, but does not squeeze the
            # stamps of the frames it publishes next into one matching window.
            start, start_ns = time.monotonic(), time.time_ns()
            for f in range(frames):
                truth = scene.objects(f)
                if f == forged_at:
                    session.put(cam00_calibration, encode(forged), encoding=ENCODING)
                if f == recalibrated_at:
                    genuine = encode(recalibration)
                    session.put(
                        cam00_calibration,
                        genuine,
                        encoding=ENCODING,
                        attachment=calibrator.attachment(cam00_calibration, genuine),
                    )
                stamp = start_ns + f * PERIOD_NS
                seen_ids: set[int] = set()
                payloads = {}
                for s in specs:  # the cameras capture at once, then publish
                    if s.name == "cam11" and f >= silent_from:
                        continue
                    seen = measure(s.camera, truth, sigma, rng)
                    seen_ids |= {o.id for o in seen}
                    payloads[s.name] = encode(detections_frame(f, stamp, seen))
                for name, payload in payloads.items():
                    _put_signed(pubs[name], pose, payload)
                sent_truth[stamp] = (truth, seen_ids)
                time.sleep(max(0.0, start + (f + 1) * PERIOD_NS / 1e9 - time.monotonic()))
            wait_for(lambda: len(world.snapshot()) >= frames - 2, 10, "every world frame")
    finally:
        stop(procs[1:])
        stop(procs[:1])
    log = (tmp_path / "fusion.log").read_text()
    assert "Traceback" not in log, log
    assert "unproven_calibration" in log and "no proof of origin" in log, log
    got = world.snapshot()
    assert len(got) >= frames - 2
    scorer = WorldScorer()
    for w in got:
        truth, seen_ids = sent_truth[w.stamp_ns]
        scorer.add(
            [(o.id, o.x_cm, o.y_cm, tuple(o.cameras)) for o in w.objects],
            [(o.id, o.x_cm, o.y_cm) for o in truth],
            seen_ids,
        )
    score = scorer.score()
    partial = [(w.seq, w.cameras, w.missing) for w in got if w.seq < silent_from and w.missing]
    assert score.duplicates == 0 and score.phantoms == 0 and score.missed == 0, (
        partial,
        got[-1].late_frames,
    )
    assert score.identity_swaps == 0
    assert score.handover_jump_cm <= 1.0 and score.world_error_cm_mean <= 0.5
    before = [w for w in got if w.stamp_ns in sent_truth and w.seq < silent_from - 5]
    assert all(w.cameras == ["cam00", "cam01", "cam10", "cam11"] for w in before)
    after = got[-30:]  # cam11 silent: the world frames go on without it, not late
    assert all("cam11" not in w.cameras for w in after)
    assert all(w.missing == [] for w in after[-10:])  # stale now: no longer waited for
    assert any(w.missing == ["cam11"] for w in got)  # said so while it was waited for
    assert got[-1].late_frames == dict.fromkeys(["cam00", "cam10", "cam01", "cam11"], 0)

    # recalibration of cam00 changed cam00's weights only
    def sigmas(cams: list[str], seqs: range) -> dict[int, float]:
        return {o.id: o.sigma_cm for w in got if w.seq in seqs for o in w.objects
                if o.kind == "obstacle" and o.cameras == cams}  # fmt: skip

    before0, after0 = sigmas(["cam00"], range(50, 95)), sigmas(["cam00"], range(110, 145))
    before1, after1 = sigmas(["cam10"], range(50, 95)), sigmas(["cam10"], range(110, 145))
    assert before0.keys() & after0.keys() and before1.keys() & after1.keys()
    for k in before0.keys() & after0.keys():
        assert after0[k] / before0[k] == pytest.approx(2.0, rel=0.05)
    for k in before1.keys() & after1.keys():
        assert after1[k] == pytest.approx(before1[k], rel=1e-6)


def test_two_real_chains_fused_and_a_killed_chain_recovers(tmp_path: Path) -> None:
    """Two cameras over two halves of a floor (the east camera 300 cm along X), each
    with its real capture → preprocess → label → pose chain, unsynchronised; fusion
    gives one world of both; the east pose killed, the west keeps flowing, then the
    east chain is back in the world."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    west = _base(endpoint, tmp_path)
    west["service"].update(camera_name="west", fps=15.0, seed=11)
    east = _base(endpoint, tmp_path)
    east["camera"]["X0_cm"] += 300.0
    east["simulator"]["arena_x_cm"] = [x + 300.0 for x in east["simulator"]["arena_x_cm"]]
    east["service"].update(camera_name="east", fps=15.0, seed=12)
    fusion = _base(endpoint, tmp_path)
    fusion["cameras"] = [
        {"name": "west", "camera": west["camera"]},
        {"name": "east", "camera": east["camera"]},
    ]
    # unsynchronised cameras at 15 frames/s: frames within half a period are one instant
    fusion["fusion"] = {"match_window_ms": 33.0, "wait_ms": 40.0}
    fusion["service"]["frame_timeout_s"] = 1.0
    files = {n: _write(tmp_path / f"{n}.toml", d) for n, d in
             (("west", west), ("east", east), ("fusion", fusion))}  # fmt: skip
    stages = ("capture", "preprocess", "label", "pose")
    procs = {"router": spawn(ovis_cmd("router", "--listen", endpoint), tmp_path / "router.log")}
    for cam in ("west", "east"):
        for s in stages:
            procs[f"{cam}-{s}"] = spawn(
                ovis_cmd("run", s, "--config", str(files[cam])), tmp_path / f"{cam}-{s}.log"
            )
    procs["fusion"] = spawn(
        ovis_cmd("run", "fusion", "--config", str(files["fusion"])), tmp_path / "fusion.log"
    )
    topics = Topics("default")
    try:
        with client(endpoint) as session:
            wait_for(lambda: "fusion" in alive(session), 60, "fusion alive")
            world = Collector(session, topics.world, WorldFrame)
            per_cam = {
                c: Collector(session, topics.of_camera(c).obstacles, ObstacleFrame)
                for c in ("west", "east")
            }

            def both(since: int) -> int:
                return sum(w.cameras == ["east", "west"] for w in world.snapshot()[since:])

            wait_for(lambda: both(0) >= 20, 90, "20 world frames of both cameras")
            stop([procs["east-pose"]], timeout=0.1)  # SIGTERM, then kill
            killed_at = len(world.snapshot())
            wait_for(
                lambda: sum(w.cameras == ["west"] and w.missing == []
                            for w in world.snapshot()[killed_at:]) >= 10,
                30, "west alone, east no longer waited for",
            )  # fmt: skip
            replies = session.get(topics.status("fusion"), timeout=2.0)
            states = [decode(r.ok.payload.to_bytes(), ServiceStatus).state for r in replies if r.ok]
            assert states == ["no frames from east (area uncovered)"]
            procs["east-pose"] = spawn(
                ovis_cmd("run", "pose", "--config", str(files["east"])),
                tmp_path / "east-pose-2.log",
            )
            back_at = len(world.snapshot())
            wait_for(lambda: both(back_at) >= 10, 60, "east back in the world")
    finally:
        stop([p for n, p in procs.items() if n != "router"])
        stop([procs["router"]])
    for log in tmp_path.glob("*.log"):
        assert "Traceback" not in log.read_text(), log.name
    got = world.snapshot()
    frames = {c: {m.stamp_ns: m for m in col.snapshot()} for c, col in per_cam.items()}
    checked = 0
    for w in got:
        for o in w.objects:
            assert o.cameras in (["west"], ["east"])  # the halves do not overlap
            assert (o.x_cm > 250.0) == (o.cameras == ["east"])
        if w.cameras != ["east", "west"]:
            continue
        # every object of each camera's frame is in the world, once, where it saw it
        mine = [f for c in ("west", "east") for f in frames[c].values()
                if abs(f.stamp_ns - w.stamp_ns) <= 33_000_000]  # fmt: skip
        if len(mine) != 2:
            continue
        seen = sorted((round(o.x_cm, 6), round(o.y_cm, 6)) for f in mine for o in f.obstacles)
        fused = sorted((round(o.x_cm, 6), round(o.y_cm, 6)) for o in w.objects
                       if o.kind == "obstacle")  # fmt: skip
        assert fused == seen
        checked += 1
    assert checked >= 10
    seqs = [w.seq for w in got]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)


def test_status_says_every_camera_is_silent_when_all_stop(tmp_path: Path) -> None:
    """When every camera stops at once (a cut network link), no world frame is made any
    more; the status must still say which areas are uncovered, not the last "ok". Each
    world frame carries the fusion key's proof of origin (its public key, made on
    fusion's first start, verifies it; the pose key's does not)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    data = _base(endpoint, tmp_path)
    cam = data["camera"]
    data["cameras"] = [{"name": "west", "camera": cam}, {"name": "east", "camera": cam}]
    data["service"]["frame_timeout_s"] = 0.5
    cfg = _write(tmp_path / "fusion.toml", data)
    pose = _signer(tmp_path, "pose")
    procs = [spawn(ovis_cmd("router", "--listen", endpoint), tmp_path / "router.log")]
    procs.append(spawn(ovis_cmd("run", "fusion", "--config", str(cfg)), tmp_path / "fusion.log"))
    topics = Topics("default")

    def state(session) -> list[str]:
        replies = session.get(topics.status("fusion"), timeout=2.0)
        return [decode(r.ok.payload.to_bytes(), ServiceStatus).state for r in replies if r.ok]

    try:
        with client(endpoint) as session:
            wait_for(lambda: "fusion" in alive(session), 60, "fusion alive")
            world = Collector(session, topics.world, WorldFrame)
            signed: list[tuple[str, bytes, bytes | None]] = []
            session.declare_subscriber(
                topics.world,
                lambda s: signed.append((str(s.key_expr), s.payload.to_bytes(), attachment_of(s))),
            )
            pubs = {
                c: session.declare_publisher(topics.of_camera(c).obstacles, encoding=ENCODING)
                for c in ("west", "east")
            }
            for seq in range(10):
                stamp = time.time_ns()
                for pub in pubs.values():
                    _put_signed(pub, pose, encode(detections_frame(seq, stamp, [])))
                time.sleep(1 / 15)
            wait_for(lambda: len(world.snapshot()) >= 5, 10, "world frames of both cameras")
            last = world.snapshot()[-1]
            assert (last.cameras, last.missing) == (["east", "west"], [])
            keys = tmp_path / "state" / "keys"
            fusion = Verifier(PublicKeyFile(keys / "fusion.pub"))
            proofs = [fusion.problem(*s) for s in list(signed)]
            assert len(proofs) >= 5 and set(proofs) == {None}, proofs
            wrong = Verifier(PublicKeyFile(keys / "pose.pub")).problem(*signed[0])
            assert wrong is not None and wrong.startswith("signed by key"), wrong
            # both silent: after frame_timeout_s neither is live any more
            wait_for(
                lambda: state(session) == ["no frames from east, west (area uncovered)"],
                5,
                "the status to say both cameras are silent",
            )
            frames = len(world.snapshot())
            # one camera back: its world frames flow, the other's area is still uncovered
            for seq in range(10, 20):
                _put_signed(pubs["west"], pose, encode(detections_frame(seq, time.time_ns(), [])))
                time.sleep(1 / 15)
            wait_for(lambda: len(world.snapshot()) > frames, 10, "world frames of west")
            assert state(session) == ["no frames from east (area uncovered)"]
    finally:
        stop(procs[1:])
        stop(procs[:1])
    assert "Traceback" not in (tmp_path / "fusion.log").read_text()
