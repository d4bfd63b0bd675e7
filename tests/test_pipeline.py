"""The per-message steps of the frame path and the services' bookkeeping, without Zenoh
(ovis.common.pipeline): checked against OpenCV, the one-process detector and the
simulator's ground truth, and with known answers."""

from __future__ import annotations

import threading
import time

import cv2
import msgspec
import numpy as np
import pytest

from ovis.common.analysis.evaluation import match_objects
from ovis.common.calibration.file import Calibration, calibration_from_config
from ovis.common.calibration.validity import calibration_problem
from ovis.common.config import ControlPoint, load_config
from ovis.common.messages import (
    BinaryFrame,
    BlobList,
    CalibrateRequest,
    Frame,
    ObstacleFrame,
    TruthFrame,
    decode,
    encode,
)
from ovis.common.pipeline.counters import StageCounters, rss_mb, worth_logging
from ovis.common.pipeline.health import SERVICE_STATE, StreamWatch
from ovis.common.pipeline.pacing import Pacer
from ovis.common.pipeline.recalibration import (
    KEEP_FRAMES,
    FrameKeeper,
    calibrate_reply,
    config_for_request,
    points_for,
)
from ovis.common.pipeline.restarts import (
    BACKOFF_MAX_S,
    BACKOFF_START_S,
    HEALTHY_S,
    RestartBudget,
    describe_exit,
)
from ovis.common.pipeline.stages import (
    MAX_CLOCK_SKEW_S,
    SizeFilter,
    binary_frame,
    blob_list,
    clock_skew,
    obstacle_frame,
    wrong_size,
)
from ovis.common.sim.arena import Arena, control_points
from ovis.common.vision.contrast import ObjectWindow
from ovis.common.vision.frames import as_gray
from ovis.common.vision.segmentation import segmentation
from ovis.common.vision.smoothing import smooth
from ovis.common.world.detection import Detector, size_filter_px

CFG = load_config(preset="default")


def _true_calibration(arena: Arena, version: int = 1) -> Calibration:
    """The simulated arena's own camera as a calibration (what a perfect GA finds)."""
    return msgspec.structs.replace(
        calibration_from_config(arena.config), camera=arena.truth_camera, version=version
    )


def _wire(msg: object, kind: type) -> object:
    """The message as the next stage gets it: encoded, then decoded with validation."""
    return decode(encode(msg), kind)


@pytest.fixture(scope="module")
def scene() -> tuple[Arena, np.ndarray, TruthFrame, Calibration]:
    arena = Arena(CFG, seed=3)
    arena.step()
    image, truth = arena.render()
    return arena, image, TruthFrame(seq=7, objects=truth.objects), _true_calibration(arena)


# --- the stages ---------------------------------------------------------------------------


def test_binary_frame_is_opencvs_median_and_threshold(scene) -> None:
    _, image, _, calib = scene
    calib = msgspec.structs.replace(
        calib, image=msgspec.structs.replace(calib.image, median="ordinary", threshold=101)
    )
    frame = Frame.from_image(image, seq=7, stamp_ns=time.time_ns())
    out = _wire(binary_frame(frame, as_gray(frame.image()), calib), BinaryFrame)
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    _, expected = cv2.threshold(cv2.medianBlur(gray, 3), 100, 1, cv2.THRESH_BINARY)
    assert np.array_equal(out.mask(), expected)  # bright polarity: pixel >= 101 → 1
    assert (out.seq, out.stamp_ns, out.threshold, out.calibration_version) == (
        7,
        frame.stamp_ns,
        101,
        1,
    )
    assert 0 < expected.mean() < 0.5  # objects and floor both present: the test can fail


def test_the_live_stage_applies_the_calibrations_whole_segmentation(scene, tmp_path) -> None:
    """A calibration in "auto" mode with a region of interest: the preprocess stage's
    binary frame is what `ovis detect` segments (same pixels, the level it used), not
    the fixed level alone; nothing outside the region."""
    _, image, _, calib = scene
    gray = as_gray(Frame.from_image(image, seq=1, stamp_ns=time.time_ns()).image())
    roi = np.zeros_like(gray)
    roi[:, : gray.shape[1] // 2] = 255
    cv2.imwrite(str(tmp_path / "roi.png"), roi)
    params = msgspec.structs.replace(
        calib.image, threshold_mode="auto", threshold=250, roi=str(tmp_path / "roi.png")
    )
    calib = msgspec.structs.replace(calib, image=params)
    frame = Frame.from_image(image, seq=7, stamp_ns=time.time_ns())
    window = ObjectWindow()
    out = _wire(binary_frame(frame, gray, calib, window=window), BinaryFrame)
    seg = segmentation(smooth(gray, params.median), params)
    assert np.array_equal(out.mask(), seg.binary) and out.threshold == seg.level != 250
    assert out.mask()[:, gray.shape[1] // 2 :].sum() == 0 and out.mask().sum() > 100
    again = binary_frame(frame, gray, calib, window=window)  # the window carried over
    assert np.array_equal(again.mask(), out.mask()) and window.looks == 1


def test_the_stages_over_the_wire_find_what_one_process_finds(scene) -> None:
    """preprocess → label → pose, each message encoded and decoded between them, gives
    the objects of Detector.detect on the same frame, and they are the true objects."""
    _, image, truth, calib = scene
    frame = Frame.from_image(image, seq=7, stamp_ns=time.time_ns())
    binary = _wire(binary_frame(frame, as_gray(frame.image()), calib), BinaryFrame)
    blobs = _wire(blob_list(binary, calib, SizeFilter().min_area_px(calib)), BlobList)
    detector = Detector(calib.camera, calib.image, calib.pose)
    now = time.time_ns()
    out = _wire(obstacle_frame(blobs, detector, calib.version, "a1", now), ObstacleFrame)
    assert (out.seq, out.arena, out.calibration_version, out.published_ns) == (7, "a1", 1, now)
    assert out.frame_age_ms == pytest.approx((now - frame.stamp_ns) / 1e6)
    staged = ([out.robot] if out.robot else []) + out.obstacles

    alone = Detector(calib.camera, calib.image, calib.pose).detect(image).objects
    assert len(staged) == len(alone) == len(truth.objects)

    def by_x(objects: list) -> list:
        return sorted(objects, key=lambda o: o.x_cm)

    for a, b in zip(by_x(staged), by_x(alone), strict=True):
        assert (a.kind, a.x_cm, a.y_cm) == pytest.approx((b.kind, b.x_cm, b.y_cm), abs=1e-6)
    acc = match_objects(staged, truth.objects)
    assert acc.missed == acc.spurious == 0 and acc.kind_correct.all()
    assert acc.position_error_cm.max() < 1.0
    assert out.robot is not None and len(out.planner) == len(out.obstacles)


def test_pose_ignores_maps_made_with_another_calibration(scene) -> None:
    _, image, _, calib = scene
    frame = Frame.from_image(image, seq=1, stamp_ns=time.time_ns())
    binary = binary_frame(frame, as_gray(frame.image()), calib)
    blobs = blob_list(binary, calib, 0.0)
    with_maps = obstacle_frame(blobs, Detector(calib.camera, calib.image, calib.pose), 1, "a", 0)
    # Maps from version 1 with a detector at version 2: back-projected afresh, same camera.
    fresh = obstacle_frame(blobs, Detector(calib.camera, calib.image, calib.pose), 2, "a", 0)
    assert fresh.calibration_version == 2
    assert [o.x_cm for o in fresh.obstacles] == pytest.approx(
        [o.x_cm for o in with_maps.obstacles], abs=1e-6
    )


def test_pose_takes_a_frame_with_no_blob_over_the_wire(scene) -> None:
    """A frame where nothing passes the size filter: its maps have empty columns, which
    must still decode to a boolean ``valid`` (pose failed on every such frame with a
    TypeError, issue 15)."""
    _, image, _, calib = scene
    frame = Frame.from_image(np.zeros_like(image), seq=3, stamp_ns=time.time_ns())
    binary = binary_frame(frame, as_gray(frame.image()), calib)
    blobs = _wire(blob_list(binary, calib, 0.0), BlobList)
    assert blobs.blobs == [] and blobs.maps is not None
    assert blobs.maps.obstacle.jacobian().valid.dtype == bool
    detector = Detector(calib.camera, calib.image, calib.pose)
    out = obstacle_frame(blobs, detector, calib.version, "a", time.time_ns())
    assert out.robot is None and out.obstacles == [] and out.planner == []


def test_size_filter_is_computed_once_per_calibration_version(scene) -> None:
    _, _, _, calib = scene
    sf = SizeFilter()
    first = sf.min_area_px(calib)
    assert first == size_filter_px(calib.image, calib.camera, calib.pose.obstacle_height_cm) > 0
    bigger = msgspec.structs.replace(
        calib, image=msgspec.structs.replace(calib.image, size_filter_cm2=80.0)
    )
    assert sf.min_area_px(bigger) == first  # same version: the cached value
    newer = msgspec.structs.replace(bigger, version=2)
    grown = 80.0 / calib.image.size_filter_cm2  # the bound is proportional to A^f
    assert sf.min_area_px(newer) == pytest.approx(grown * first)


def test_frames_refused_before_processing() -> None:
    frame = Frame.from_image(np.zeros((48, 64), np.uint8), seq=5, stamp_ns=10**18)
    now = 10**18 + int(MAX_CLOCK_SKEW_S * 1e9)
    assert clock_skew(frame, now) is None
    late = clock_skew(frame, now + 2 * 10**9)
    assert late is not None and "frame 5 is stamped 3602 s away" in late and "NTP" in late
    cam = CFG.camera
    assert wrong_size(frame, cam, "frame") == (
        f"frame 5 is 64x48, the camera is configured for {cam.cols}x{cam.rows}"
    )
    ok = Frame.from_image(np.zeros((cam.rows, cam.cols), np.uint8), seq=6, stamp_ns=0)
    assert wrong_size(ok, cam, "frame") is None


def test_calibration_of_another_image_size_is_refused() -> None:
    calib = calibration_from_config(CFG)
    assert (calib.version, calib.camera, calib.image) == (0, CFG.camera, CFG.image)
    assert calibration_problem(calib, CFG) is None
    small = load_config(preset="paper")
    other = msgspec.structs.replace(calib, camera=small.camera, version=3)
    assert calibration_problem(other, CFG) == (
        f"calibration v3 refused: it is for {small.camera.cols}x{small.camera.rows} images, "
        f"this arena's camera is {CFG.camera.cols}x{CFG.camera.rows}"
    )


# --- a stage's counters and the stream's health --------------------------------------------


def test_counters_count_gaps_rate_and_errors() -> None:
    c = StageCounters()
    # 3, 4 missing after 2 (4 comes late: not lost), 7–9 missing, each gap confirmed one
    # frame at a time by the frames after it
    for seq in (0, 1, 2, 5, 4, 6, 10, 11, 12, 13):
        c.saw_frame(seq, stamp_ns=time.time_ns())
        c.sent()
    assert (c.frames_in, c.frames_out, c.seq_gaps, c.last_seq) == (10, 10, 4, 13)
    assert c.error("bad_frame", "one") == 1 and c.error("bad_frame", "two") == 2
    st = c.status("label", started_ns=1, state="ok", dropped_here=3, calibration_version=4)
    assert (st.service, st.dropped, st.last_error) == ("label", 7, "two")  # 4 gaps + 3 here
    assert st.errors == {"bad_frame": 2}
    assert st.calibration_version == 4 and st.fps > 0 and 0 <= st.last_frame_age_s < 5
    assert st.rss_mb == pytest.approx(rss_mb(), rel=0.2) and st.rss_mb > 10


def test_gaps_under_overload_are_all_counted_one_frame_at_a_time() -> None:
    """Every fifth frame arrives (four lost each time): each frame after a gap confirms
    one more lost frame, the frames of earlier gaps are kept, and once the sequence goes
    on without gaps the count reaches every frame lost."""
    c = StageCounters()
    for seq in range(0, 55, 5):  # 0, 5, …, 50: ten gaps of four
        c.saw_frame(seq, 0)
    assert c.seq_gaps == 9  # frames 10…50 each confirmed one
    for seq in range(51, 100):
        c.saw_frame(seq, 0)
    assert (c.seq_gaps, c.seq_jumps) == (40, 0)


def test_a_forged_pair_far_apart_moves_the_count_by_at_most_one() -> None:
    c = StageCounters()
    for seq in (*range(11), 510, 900, *range(11, 21)):  # two forged numbers, then the real
        c.saw_frame(seq, 0)
    assert (c.seq_gaps, c.seq_jumps, c.last_seq) == (1, 1, 20)


def test_counters_rate_is_frames_per_second_of_arrival() -> None:
    c = StageCounters()
    for seq in range(6):
        c.saw_frame(seq, 0)
        time.sleep(0.05)
    assert 8 < c.fps() < 22  # 5 intervals of ≥ 50 ms: at most 20/s, more than 8 on a busy CI


def test_counters_from_many_threads_lose_nothing() -> None:
    c = StageCounters()

    def work(base: int) -> None:
        for i in range(500):
            c.saw_frame(base + i, 0)
            c.error("x", "m")

    threads = [threading.Thread(target=work, args=(k * 1000,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert c.frames_in == 2000 and c.errors["x"] == 2000


def test_errors_are_logged_first_five_then_every_hundredth() -> None:
    assert [n for n in range(1, 301) if worth_logging(n)] == [1, 2, 3, 4, 5, 100, 200, 300]


def test_stream_watch_states_and_changes() -> None:
    w = StreamWatch(timeout_s=2.0)
    assert (w.state, w.update(None)) == ("waiting", False)
    assert w.update(0.5) and w.state == "ok"
    assert not w.update(2.0)  # at the timeout: still ok
    assert w.update(2.01) and w.state == "stalled" and SERVICE_STATE[w.state] == "no frames"
    msg = w.message(
        last_seq=None,
        seconds_since_frame=2.01,
        last_frame_age_ms=None,
        frames_dropped=4,
        calibration_version=2,
    )
    assert (msg.state, msg.last_seq, msg.frames_dropped, msg.calibration_version) == (
        "stalled",
        -1,
        4,
        2,
    )


def test_pacer_keeps_the_rate_and_does_not_catch_up() -> None:
    now = [100.0]
    pacer = Pacer(fps=10.0, clock=lambda: now[0])
    now[0] += 0.03  # a frame took 30 ms
    assert pacer.delay() == pytest.approx(0.07)
    now[0] += 0.07 + 0.5  # waited, then a 500 ms stall
    assert pacer.delay() == 0.0  # late: no wait...
    now[0] += 0.01
    assert pacer.delay() == pytest.approx(0.09)  # ...and the schedule starts from then
    assert Pacer(fps=0.0).delay() == 0.0  # 0: as fast as possible


# --- the calibrator's bookkeeping -----------------------------------------------------------


def _truth(seq: int) -> TruthFrame:
    return TruthFrame(seq=seq, objects=[])


def test_keeper_picks_the_newest_frame_with_its_truth() -> None:
    k = FrameKeeper(needs_truth=True)
    assert k.pick(None).error == "no frame received yet from capture"
    assert not k.first_frame.is_set()
    for seq in range(3):
        k.add_frame(seq, b"f%d" % seq)
    k.add_truth(_truth(1))
    t0 = time.monotonic()
    picked = k.pick(None, truth_wait_s=0.3)
    assert (picked.seq, picked.payload, picked.truth, picked.error) == (1, b"f1", _truth(1), "")
    assert time.monotonic() - t0 < 0.25 and k.first_frame.is_set()  # had its truth: no wait


def test_keeper_waits_for_a_named_frames_truth() -> None:
    k = FrameKeeper(needs_truth=True)
    k.add_frame(4, b"f4")
    threading.Timer(0.1, k.add_truth, args=(_truth(4),)).start()
    picked = k.pick(4, truth_wait_s=2.0)
    assert picked.truth == _truth(4)
    t0 = time.monotonic()
    k.add_frame(5, b"f5")
    late = k.pick(5, truth_wait_s=0.2)  # never comes: the frame without its truth
    assert (late.payload, late.truth) == (b"f5", None) and time.monotonic() - t0 >= 0.19


def test_keeper_keeps_the_last_frames_and_says_why_one_is_missing() -> None:
    k = FrameKeeper(needs_truth=False)
    for seq in range(10, 10 + KEEP_FRAMES + 6):
        k.add_frame(seq, b"x")
    first, last = 16, 15 + KEEP_FRAMES
    assert next(iter(k.frames)) == first and len(k.frames) == KEEP_FRAMES
    gone = k.pick(12)
    assert gone.seq == 12 and gone.payload is None
    assert gone.error == f"frame 12 is gone: the calibrator keeps the last 64 ({first}–{last})"
    assert "never reached the calibrator" in k.pick(last + 5).error
    assert k.pick(None).seq == last  # without truth needed: the newest


def test_points_ga_and_reply_of_a_request() -> None:
    arena = Arena(CFG, seed=1)
    _, truth = arena.render()
    tf = TruthFrame(seq=2, objects=truth.objects)
    given = [ControlPoint(name="a", x_cm=1.0, y_cm=2.0, z_cm=0.0)]
    assert points_for(2, given, tf) is given
    assert points_for(2, None, tf) == control_points(tf)
    assert "no ground truth for frame 2 within 1 s" in points_for(2, None, None)

    cfg = config_for_request(CFG, CalibrateRequest(seed=9, generations=3))
    assert (cfg.ga.seed, cfg.ga.generations, cfg.ga.population) == (9, 3, CFG.ga.population)
    assert config_for_request(CFG, CalibrateRequest()) is CFG

    calib = msgspec.structs.replace(
        _true_calibration(arena, version=4), dipe_px=0.25, dipe_mm=0.1, elapsed_s=2.0
    )
    reply = calibrate_reply(calib, 2, "/s/v4.json")
    assert (reply.ok, reply.version, reply.frame_seq, reply.dipe_px, reply.saved_to) == (
        True,
        4,
        2,
        0.25,
        "/s/v4.json",
    )
    assert reply.parameters["threshold"] == calib.image.threshold
    assert reply.parameters["Z0_cm"] == pytest.approx(calib.camera.Z0_cm)


# --- the supervisor's restart rule ----------------------------------------------------------


def test_first_restart_is_immediate_then_backoff_doubles_to_its_cap_and_resets() -> None:
    b = RestartBudget(max_restarts=100, window_s=60.0)
    delays = []
    for i in range(6):
        delays.append(b.died(now=float(i)))
        b.restarted(now=float(i))
    assert delays == [0.0, BACKOFF_START_S, 2.0, 4.0, 8.0, BACKOFF_MAX_S]
    assert b.restarts == 6
    b.running(now=100.0, started_at=100.0 - HEALTHY_S / 2)
    assert b.backoff == BACKOFF_MAX_S  # not long enough
    b.running(now=100.0, started_at=100.0 - HEALTHY_S - 1)
    assert b.backoff == 0.0  # the next restart is immediate again


def test_restart_budget_is_per_window() -> None:
    b = RestartBudget(max_restarts=2, window_s=10.0)
    for t in (0.0, 1.0):
        assert b.died(t) is not None
        b.restarted(t)
    assert b.died(2.0) is None  # 2 restarts within 10 s: left stopped
    assert b.died(10.5) is not None  # the first has left the window


def test_exit_descriptions() -> None:
    assert describe_exit(3) == "exit code 3"
    assert describe_exit(-9) == "killed by SIGKILL"
    assert describe_exit(-200) == "killed by signal 200"


# --- ids across kinds, live and offline ------------------------------------------------------


def _true_calibration_file(folder, version: int = 1) -> Calibration:
    """The calibration of an `ovis simulate` folder's true camera and configuration (its
    points.toml [config]), what a perfect GA finds."""
    from ovis.common.config import config_from_dict, load_points

    cfg = config_from_dict(load_points(folder / "points.toml").config)
    return msgspec.structs.replace(calibration_from_config(cfg), version=version)


def test_ids_are_unique_across_kinds_live_and_offline(tmp_path) -> None:
    """`ovis simulate --robots 4` frames through `ovis detect` and through the stages, the
    pose stage's detector started (as services/pose.py does) from a configuration without
    robots and handed the robots' calibration afterwards (the order that numbered the
    obstacles 1–6 beside robots 1–4): the same ids both ways, none shared by two objects,
    and every planner entry names one object of its kind."""
    import json

    from cli_helpers import ovis

    from ovis.common.world.marker_search import BlobMarkers

    folder = tmp_path / "sim"
    ovis("simulate", "--out", str(folder), "--frames", "6", "--seed", "2929", "--robots", "4")
    calib = _true_calibration_file(folder)
    path = tmp_path / "calib.json"
    from ovis.common.calibration.file import save_calibration

    save_calibration(path, calib)
    frames = sorted(folder.glob("frame_*.png"))
    offline = json.loads(
        ovis("detect", *map(str, frames), "--calibration", str(path), "--json").stdout
    )
    plain = msgspec.structs.replace(calib.pose, robots=[])
    detector = Detector(calib.camera, calib.image, plain)  # the configuration's, version 0
    detector.recalibrate(calib.camera, calib.image, calib.pose)  # then the calibration
    fps = 30.0
    for k, (png, off) in enumerate(zip(frames, offline, strict=True)):
        image = cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)
        frame = Frame.from_image(image, seq=k, stamp_ns=round(1e18 + k * 1e9 / fps))
        binary = _wire(binary_frame(frame, as_gray(image), calib), BinaryFrame)
        blobs = _wire(blob_list(binary, calib, 0.0, BlobMarkers()), BlobList)
        out = obstacle_frame(blobs, detector, calib.version, "a", frame.stamp_ns)
        live = _wire(out, ObstacleFrame)
        robots = [r.id for r in live.robots]
        obstacles = [o.id for o in live.obstacles]
        assert robots == [1, 2, 3, 4] and len(obstacles) == 3
        assert not set(robots) & set(obstacles)
        assert robots == [r["id"] for r in off["robots"]]
        assert obstacles == [o["id"] for o in off["objects"] if o["kind"] == "obstacle"]
        kinds = {**dict.fromkeys(robots, "robot"), **dict.fromkeys(obstacles, "obstacle")}
        for plan in live.robot_plans:
            assert all(kinds[e.target_id] == e.target_kind for e in plan.entries)
        assert all(kinds[e.obstacle_id] == "obstacle" for e in live.planner)
