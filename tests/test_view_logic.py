"""The live view's pure logic (ovis.common.view) on real simulated frames: the camera
footprint, the scene objects of an obstacle message, pictures and overlays, health,
settings; and the picture wire format of the server."""

from __future__ import annotations

import json
import math
import struct
from datetime import UTC, datetime, timedelta

import cv2
import msgspec
import numpy as np
import pytest

from ovis.common.calibration.file import PointResidual, calibration_from_config
from ovis.common.camera.projection import project
from ovis.common.config import NavigationConfig, load_config
from ovis.common.messages import (
    BinaryFrame,
    BlobList,
    ReplayMark,
    RobotCommand,
    RobotDrive,
    ServiceStatus,
    StreamHealth,
)
from ovis.common.sim.arena import Arena
from ovis.common.view import picture
from ovis.common.view.driving import (
    COMMAND_FROM,
    GOAL_FROM,
    WORLD_TRAIL_FROM,
    Drives,
    command_state,
    robot_poses,
)
from ovis.common.view.freshness import (
    STALL_S,
    Freshness,
    Seen,
    freshness,
    read_replay_mark,
    replay_of_result,
)
from ovis.common.view.grid import MAX_LINES, grid_step_cm, map_grid_step
from ovis.common.view.health import (
    HEALTH_STALE_S,
    STAGES,
    LatencyWindow,
    listed,
    summarize,
    summarize_calibration,
)
from ovis.common.view.pairing import DETECTIONS_WAIT_S, frame_to_draw
from ovis.common.view.picture import (
    POINT,
    ROBOT,
    binary_image,
    downscale,
    draw_overlay,
    object_marks,
    to_jpeg,
)
from ovis.common.view.scene import camera_footprint, scene_objects
from ovis.common.view.settings import parse_listen, view_settings
from ovis.common.world.detection import Detector, binarize_frame, measure_blobs


@pytest.fixture(scope="module")
def scene():
    """One simulated frame, its truth, and what the detector finds in it."""
    config = load_config()
    image, truth = next(Arena(config, seed=3).frames(1))
    det = Detector(config.camera, config.image, config.pose).detect(image)
    return config, image, truth, det


def test_footprint_back_projects_the_image_border(scene) -> None:
    config, _, truth, _ = scene
    cam = config.camera
    poly = camera_footprint(cam, per_side=8)
    assert len(poly) == 32
    x, y = np.array(poly).T
    p = project(x, y, np.zeros_like(x), cam)
    assert np.all(p.valid)
    # Every point projects back onto the image border (±0.5 px beyond the last pixel).
    on_edge = np.minimum.reduce(
        [
            np.abs(p.row + 0.5),
            np.abs(p.row - (cam.rows - 0.5)),
            np.abs(p.col + 0.5),
            np.abs(p.col - (cam.cols - 0.5)),
        ]
    )
    assert on_edge.max() < 1e-3
    # Every simulated object's floor position is inside it.
    contour = np.array(poly, np.float32).reshape(-1, 1, 2)
    for obj in truth.objects:
        assert cv2.pointPolygonTest(contour, (obj.x_cm, obj.y_cm), False) > 0
    with pytest.raises(ValueError, match="per_side"):
        camera_footprint(cam, per_side=1)


def test_scene_objects_read_todays_message_and_a_robots_list(scene) -> None:
    _, _, truth, det = scene
    robot = next(o for o in det.objects if o.kind == "robot")
    message = {
        "robot": msgspec.to_builtins(robot),
        "obstacles": [msgspec.to_builtins(o) for o in det.objects if o.kind == "obstacle"],
        "robots": [],  # no marked robots: the paper's unmarked robot is the one drawn
    }
    objs = scene_objects(message)
    assert [o.kind for o in objs] == ["robot", "obstacle", "obstacle", "obstacle"]
    assert objs[0].x_cm == robot.x_cm and objs[0].row == robot.row
    truth_robot = next(o for o in truth.objects if o.kind == "robot")
    assert math.hypot(objs[0].x_cm - truth_robot.x_cm, objs[0].y_cm - truth_robot.y_cm) < 1.0
    # A message with marked robots (ids, names, headings) draws those, and
    # entries without finite coordinates are skipped.
    future = {
        "robots": [
            {"id": 4, "name": "alpha", "x_cm": 10.0, "y_cm": 20.0, "heading_deg": 90.0},
            {"id": 5, "x_cm": float("nan"), "y_cm": 1.0},
            {"id": 6, "x_cm": "12", "y_cm": 1.0},
        ],
        "robot": {"id": 0, "x_cm": 1.0, "y_cm": 1.0},
        "obstacles": "not a list",
    }
    (only,) = scene_objects(future)
    assert (only.id, only.name, only.kind, only.heading_deg) == (4, "alpha", "robot", 90.0)
    assert scene_objects({}) == []


def test_downscale_and_jpeg_keep_the_picture(scene) -> None:
    _, image, _, _ = scene
    small, scale = downscale(image, 320)
    assert small.shape == (240, 320) and scale == 0.5
    same, one = downscale(image, 4000)
    assert same is image and one == 1.0  # never enlarged
    jpeg = to_jpeg(small, 80)
    back = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert back.shape == small.shape
    assert np.abs(back.astype(int) - small.astype(int)).mean() < 3.0
    assert len(jpeg) < small.nbytes / 3
    with pytest.raises(ValueError, match="quality"):
        to_jpeg(small, 0)
    with pytest.raises(ValueError, match="max_side"):
        downscale(image, 0)


def test_overlay_marks_the_robot_and_its_heading(scene) -> None:
    config, image, _, det = scene
    binary = binarize_frame(image, config.image, config.camera)
    blobs = BlobList.measures(
        measure_blobs(binary, config.image, config.camera, config.pose.obstacle_height_cm)
    )
    robot = next(o for o in det.objects if o.kind == "robot")
    objects = scene_objects({"robot": msgspec.to_builtins(robot), "obstacles": []})
    small, scale = downscale(image, 320)
    marks = object_marks(objects, config.camera)
    assert [m.label for m in marks] == ["R0"] and (marks[0].row, marks[0].col) == (
        robot.row,
        robot.col,
    )
    out = draw_overlay(small, scale, marks=marks, blobs=blobs)
    assert out.shape == (*small.shape, 3)
    changed = np.any(out != cv2.cvtColor(small, cv2.COLOR_GRAY2BGR), axis=2)
    assert changed.sum() > 100
    # The heading arrow ends at the projection of a point ahead of the robot.
    h = math.radians(robot.heading_deg)
    tip = project(
        robot.x_cm + 8 * math.cos(h), robot.y_cm + 8 * math.sin(h), robot.z_cm, config.camera
    )
    r, c = round(float(tip.row) * scale), round(float(tip.col) * scale)
    patch = out[r - 2 : r + 3, c - 2 : c + 3].reshape(-1, 3).astype(int)
    assert np.min(np.abs(patch - np.array(ROBOT)).sum(axis=1)) < 60


def test_binary_image_is_the_mask() -> None:
    mask = (np.arange(12 * 10).reshape(12, 10) % 3 == 0).astype(np.uint8)
    msg = BinaryFrame(
        seq=1,
        stamp_ns=1,
        rows=12,
        cols=10,
        bits=np.packbits(mask).tobytes(),
        threshold=100,
        calibration_version=0,
    )
    assert np.array_equal(binary_image(msg), mask * 255)


def test_latency_window_percentiles_and_expiry() -> None:
    w = LatencyWindow(window_s=10.0, limit=100)
    assert w.percentiles(0.0) == (None, None, 0)
    values = np.arange(1, 201, dtype=float)
    for i, v in enumerate(values):
        w.add(v, now_s=i * 0.01)
    w.add(float("nan"), now_s=2.0)
    p50, p99, n = w.percentiles(now_s=2.0)
    kept = values[-100:]  # bounded: the newest 100
    assert n == 100 and p50 == pytest.approx(np.percentile(kept, 50))
    assert p99 == pytest.approx(np.percentile(kept, 99))
    assert w.percentiles(now_s=30.0) == (None, None, 0)


def _status(name: str, **kw) -> ServiceStatus:
    return ServiceStatus(service=name, pid=1, host="h", started_ns=1, state="ok", **kw)


def test_health_summary_says_which_stage_is_dead() -> None:
    config = load_config()
    calib = msgspec.structs.replace(
        calibration_from_config(config),
        version=3,
        dipe_px=0.2,
        created=(datetime.now(UTC) - timedelta(seconds=90)).isoformat(timespec="seconds"),
    )
    w = LatencyWindow()
    w.add(5.0)
    statuses = {
        "capture": _status("capture", fps=14.5, frames_out=10),
        "label": _status("label", errors={"bad_binary": 2, "processing": 1}, dropped=4),
        "pose": _status("pose"),  # an old status of a stage that has since died
    }
    s = summarize(
        "a",
        {"capture", "label", "preprocess", "extra"},
        statuses,
        w,
        StreamHealth(state="ok", published_ns=1),
        calib,
    )
    by = {st.name: st for st in s.stages}
    assert list(by) == ["capture", "preprocess", "label", "pose", "calibrator", "extra"]
    assert by["capture"].alive and by["capture"].fps == 14.5
    assert by["label"].errors == 3 and by["label"].dropped == 4
    assert not by["pose"].alive and by["pose"].state == "not running" and by["pose"].fps is None
    assert by["preprocess"].alive and by["preprocess"].state == "starting"
    assert s.stream == "ok" and s.latency_p50_ms == 5.0 and s.latency_samples == 1
    assert s.calibration.version == 3 and 85 <= s.calibration.age_s <= 120
    # No pose service: no health message; version 0 is no calibration.
    s0 = summarize("a", set(), {}, LatencyWindow(), None, calibration_from_config(config))
    assert s0.stream == "no pose service" and s0.calibration is None
    assert not any(st.alive for st in s0.stages)
    assert summarize_calibration(msgspec.structs.replace(calib, created="garbage")).age_s is None


def test_optional_services_are_listed_while_they_run_and_never_missing() -> None:
    """`ovis status` and the page list the stages always (one not running is a problem)
    and the ROS 2 bridge or the fusion only when they run: not started is not missing."""
    assert listed(STAGES, {}) == list(STAGES)
    assert listed({"capture", "ros2"}, {}) == [*STAGES, "ros2"]
    assert listed(STAGES, {"ros2": _status("ros2"), "fusion": _status("fusion")}) == [
        *STAGES,
        "fusion",
        "ros2",
    ]
    s = summarize("a", set(STAGES), {}, LatencyWindow(), None, None)
    assert [st.name for st in s.stages] == list(STAGES) and all(st.alive for st in s.stages)
    s = summarize("a", {"pose", "ros2"}, {"ros2": _status("ros2")}, LatencyWindow(), None, None)
    assert [(st.name, st.alive) for st in s.stages][-2:] == [("calibrator", False), ("ros2", True)]


def test_a_camera_frame_waits_for_its_detections_before_it_is_drawn() -> None:
    """The frame just seen, its detections not yet come, is not drawn bare (the page
    would show its robots as not found); the newest with detections is; without any,
    the newest is drawn bare only once waiting no longer helps."""
    t = 100.0
    kept = [(1, t), (2, t + 0.05), (3, t + 0.1)]
    assert frame_to_draw([(1, t)], set(), t + 0.01, full=False) is None  # the race
    assert frame_to_draw(kept, {1, 2}, t + 0.11, full=False) == (2, True)
    assert frame_to_draw(kept, {1, 2, 3}, t + 0.11, full=False) == (3, True)
    assert frame_to_draw(kept, set(), t + DETECTIONS_WAIT_S - 0.01, full=False) is None
    assert frame_to_draw(kept, set(), t + DETECTIONS_WAIT_S, full=False) == (3, False)
    assert frame_to_draw(kept, set(), t + 0.11, full=True) == (3, False)
    assert frame_to_draw([], {1}, t, full=False) is None


def test_settings_are_validated() -> None:
    assert parse_listen("127.0.0.1:8080") == ("127.0.0.1", 8080)
    assert parse_listen("[::1]:0") == ("::1", 0)
    for bad in ("8080", "host:", "host:99999", "a b:1"):
        with pytest.raises(ValueError, match="HOST:PORT"):
            parse_listen(bad)
    assert view_settings(max_fps=None).max_fps == 10.0
    for field, value in (
        ("max_fps", 0.0),
        ("max_fps", float("nan")),
        ("max_side", 10),
        ("operator_token", "short"),
        ("jpeg_quality", 101),
    ):
        with pytest.raises(ValueError, match=field):
            view_settings(**{field: value})


def test_picture_wire_format() -> None:
    from ovis.services.view.pictures import Picture
    from ovis.services.view.server import pack_picture

    pic = Picture(
        arena="a",
        kind="camera",
        seq=7,
        stamp_ns=5,
        width=2,
        height=1,
        scale=0.5,
        jpeg=b"\xff\xd8jpeg",
    )
    data = pack_picture(pic)
    (n,) = struct.unpack(">I", data[:4])
    header = json.loads(data[4 : 4 + n])
    assert header["seq"] == 7 and header["kind"] == "camera" and header["jpeg"] == ""
    assert data[4 + n :] == b"\xff\xd8jpeg"


def test_a_slow_browser_gets_the_newest_update_not_a_queue() -> None:
    """Updates not yet sent are replaced by newer ones of the same kind: what waits
    for a browser is bounded by the number of kinds, whatever the rate."""
    from ovis.services.view.server import Viewer

    viewer = Viewer(ws=None, arena="default")  # type: ignore[arg-type]  (never sent here)
    for i in range(1000):
        viewer.offer("picture", bytes([i % 256]) * 1000)
        viewer.offer("health", f"health {i}")
    assert list(viewer.slots) == ["picture", "health"]
    assert viewer.slots["health"] == "health 999" and viewer.replaced == 2 * 999
    assert viewer.wake.is_set()


# --- how current the page is ----------------------------------------------------------
T0 = 1_790_000_000_000_000_000  # a capture stamp, ns since the epoch


def test_a_live_frame_ages_by_the_wall_clock_and_stalls_after_2_s() -> None:
    seen = Seen(seq=5, stamp_ns=T0, received_ns=T0 + 30_000_000, received_s=100.0)
    f = freshness(seen, T0 + 530_000_000, 100.5)
    assert (f.state, f.seq, f.stale) == ("live", 5, False)
    assert f.age_s == pytest.approx(0.53) and f.since_s == pytest.approx(0.5)
    assert freshness(seen, T0 + 2_030_000_000, 100.0 + STALL_S).state == "live"
    # Nothing newer for 12 s: stalled, and the seconds keep growing with the clock.
    f = freshness(seen, T0 + 12_030_000_000, 112.0)
    assert (f.state, f.stale) == ("stalled", True)
    assert f.since_s == pytest.approx(12.0) and f.age_s == pytest.approx(12.03)
    assert freshness(seen, T0 + 20_030_000_000, 120.0).since_s == pytest.approx(20.0)


def test_waiting_counts_from_when_the_view_started_looking() -> None:
    f = freshness(None, T0, 50.0, looking_since_s=42.0)
    assert (f.state, f.since_s, f.seq, f.stale) == ("waiting", 8.0, None, False)
    assert freshness(None, T0, 50.0).since_s is None


def test_frames_that_arrive_264_s_old_are_late_not_live() -> None:
    """The issue's replay without a mark: stamps 264 745 ms before they arrived."""
    seen = Seen(seq=1, stamp_ns=T0, received_ns=T0 + 264_745_000_000, received_s=10.0)
    f = freshness(seen, T0 + 264_845_000_000, 10.1)
    assert (f.state, f.stale) == ("late", True) and f.age_s == pytest.approx(264.845)


def test_a_replay_is_labelled_with_its_recording_and_own_time_not_an_age() -> None:
    mark = ReplayMark(recording="run.mcap", recorded_ns=T0 + 12_300_000_000, start_ns=T0)
    assert read_replay_mark(msgspec.msgpack.encode(mark)) == mark
    assert read_replay_mark(None) is None and read_replay_mark(b"") is None
    for bad in (b"\xc1garbage", msgspec.msgpack.encode({"recording": "x"})):
        with pytest.raises(ValueError, match="not a replay mark"):
            read_replay_mark(bad)
    received = T0 + 264_745_000_000
    seen = Seen(seq=3, stamp_ns=T0, received_ns=received, received_s=5.0, replay=mark)
    f = freshness(seen, received + 200_000_000, 5.2)
    assert (f.state, f.age_s, f.stale, f.recording) == ("replay", None, False, "run.mcap")
    assert f.recorded_ns == T0 + 12_300_000_000 and f.into_s == pytest.approx(12.3)
    # The replay ends: stalled, still saying which recording and where it stopped.
    f = freshness(seen, received + 4_000_000_000, 9.0)
    assert (f.state, f.stale, f.recording) == ("stalled", True, "run.mcap")
    assert f.since_s == pytest.approx(4.0) and f.age_s is None


def test_obstacles_made_from_replayed_frames_are_a_replay_too() -> None:
    """`ovis up --source SESSION.mcap`: the pose stage's results carry no mark, their
    frames do."""
    mark = ReplayMark(recording="run.mcap", recorded_ns=T0, start_ns=T0)
    frame = Seen(seq=8, stamp_ns=T0, received_ns=T0 + 10, received_s=3.0, replay=mark)
    live = Seen(seq=8, stamp_ns=T0, received_ns=T0 + 10, received_s=3.0)
    assert replay_of_result(frame, None, T0, 3.1) == mark
    assert replay_of_result(live, frame, T0, 3.1) is None  # its own frame was live
    # Its frame is gone (or another stream's): the newest frame's while it is current.
    assert replay_of_result(None, frame, T0 + 5, 3.0 + STALL_S) == mark
    assert replay_of_result(live, frame, T0 + 5, 3.1) == mark
    assert replay_of_result(None, frame, T0, 3.0 + STALL_S + 0.1) is None
    assert replay_of_result(None, None, T0, 3.1) is None


def test_health_of_a_replay_has_no_latency_and_a_silent_pose_is_unknown() -> None:
    w = LatencyWindow()
    w.add(264745.0)
    replay = Freshness(state="replay", seq=3, recording="run.mcap", recorded_ns=T0, into_s=1.0)
    s = summarize(
        "a",
        {"pose"},
        {},
        w,
        StreamHealth(state="ok", published_ns=1),
        None,
        stream_age_s=0.5,
        fresh={"camera": replay},
    )
    assert s.replay == "run.mcap" and s.latency_p50_ms is None and s.latency_samples == 0
    assert s.stream == "ok" and s.fresh["camera"].state == "replay"
    live = summarize("a", {"pose"}, {}, w, StreamHealth(state="ok", published_ns=1), None)
    assert live.replay == "" and live.latency_p50_ms == 264745.0
    lost = StreamHealth(state="source lost", published_ns=1, reason="camera:0 stopped answering")
    s = summarize("a", {"pose"}, {}, w, lost, None, stream_age_s=1.0)
    assert (s.stream, s.stream_reason) == ("source lost", "camera:0 stopped answering")
    s = summarize("a", {"pose"}, {}, w, lost, None, stream_age_s=HEALTH_STALE_S + 2)
    assert s.stream == "unknown" and "no health message from the pose stage for 5 s" in (
        s.stream_reason
    )


# --- the map's grid, the picture's labels and control points -----------------------------
@pytest.mark.parametrize(
    ("extent", "step"),
    [
        (100.0, 10.0),
        (95.0, 10.0),
        (101.0, 20.0),
        (30.0, 5.0),
        (250.0, 50.0),
        (1234.0, 200.0),
        (0.7, 0.1),
        (10.0, 1.0),
    ],
)
def test_grid_step_is_1_2_5_with_at_most_10_lines(extent: float, step: float) -> None:
    got = grid_step_cm(extent)
    assert got == pytest.approx(step)
    assert extent / got <= MAX_LINES + 1e-9
    assert extent / got > MAX_LINES / 2.5 - 1e-9  # the next smaller step would be too many


def test_map_grid_step_comes_from_what_the_map_shows() -> None:
    assert map_grid_step([]) is None and map_grid_step([(float("nan"), 1.0)]) is None
    # A 150 × 100 cm footprint and 10 cm around it: 170 cm across, lines every 20 cm.
    assert map_grid_step([(0.0, 0.0), (150.0, 100.0)]) == 20.0
    for bad in (0.0, -3.0, float("inf"), float("nan")):
        with pytest.raises(ValueError, match="extent"):
            grid_step_cm(bad)


def test_marked_robots_are_labelled_where_the_calibration_projects_them(scene) -> None:
    config, *_ = scene
    cam = config.camera
    message = {
        "robots": [
            {
                "id": 4,
                "name": "alpha",
                "x_cm": 60.0,
                "y_cm": 90.0,
                "z_cm": 10.0,
                "heading_deg": 0.0,
            },
            {"id": 7, "x_cm": 100.0, "y_cm": 60.0, "z_cm": 10.0, "heading_deg": 90.0},
        ],
        "obstacles": [{"id": 2, "x_cm": 80.0, "y_cm": 70.0, "row": 100.5, "col": 200.25}],
    }
    marks = object_marks(scene_objects(message), cam)
    assert [m.label for m in marks] == ["R4 alpha", "R7", "O2"]
    for m, (x, y, h) in zip(marks, [(60.0, 90.0, 0.0), (100.0, 60.0, 90.0)], strict=False):
        p = project(x, y, 10.0, cam)
        assert (m.row, m.col) == pytest.approx((float(p.row), float(p.col)), abs=1e-9)
        ahead = project(
            x + 8 * math.cos(math.radians(h)), y + 8 * math.sin(math.radians(h)), 10.0, cam
        )
        assert m.tip == pytest.approx((float(ahead.row), float(ahead.col)), abs=1e-9)
    assert (marks[2].row, marks[2].col, marks[2].tip) == (100.5, 200.25, None)
    # Without a calibration a robot that has no pixel cannot be placed; a measured one can.
    assert [m.label for m in object_marks(scene_objects(message), None)] == ["O2"]
    small, scale = downscale(np.zeros((480, 640), np.uint8), 320)
    out = draw_overlay(small, scale, marks=marks)
    r, c = round(marks[1].row * scale), round(marks[1].col * scale)
    patch = out[r - 2 : r + 3, c - 2 : c + 3].reshape(-1, 3).astype(int)
    assert np.min(np.abs(patch - np.array(ROBOT)).sum(axis=1)) < 60


def test_control_points_only_on_the_calibrations_own_frame() -> None:
    frame_of, points_of = picture.calibration_frame, picture.control_points
    config = load_config()
    base = calibration_from_config(config)
    assert frame_of(base) is None  # version 0: the configuration, not a calibration
    points = []
    for k, (x, y) in enumerate([(20.0, 30.0), (120.0, 40.0), (70.0, 110.0)]):
        p = project(x, y, 0.0, config.camera)
        row, col = float(p.row), float(p.col)
        points.append(
            PointResidual(
                name=f"P{k}",
                x_cm=x,
                y_cm=y,
                z_cm=0.0,
                detected_row=row + 0.5,
                detected_col=col,
                predicted_row=row,
                predicted_col=col,
                dipe_px=0.5,
                dipe_mm=None,
            )
        )
    calib = msgspec.structs.replace(base, version=2, source_image="frame 9", points=points)
    assert frame_of(calib) == 9
    assert frame_of(msgspec.structs.replace(calib, source_image="board.jpg")) is None
    assert frame_of(msgspec.structs.replace(calib, source_image="frame 9b")) is None
    assert points_of(calib, 9) == points
    assert points_of(calib, 10) == [] and points_of(None, 9) == []
    # Drawn: magenta at the projected point's circle on frame 9's picture.
    out = draw_overlay(np.zeros((480, 640), np.uint8), 1.0, points=points_of(calib, 9))
    magenta = np.abs(out.astype(int) - np.array(POINT)).sum(axis=2) < 120
    assert magenta.sum() > 3 * 20, magenta.sum()
    blank = draw_overlay(np.zeros((480, 640), np.uint8), 1.0, points=points_of(calib, 8))
    assert not blank.any()


# --- driven robots: goal, command, the world's trail (ovis.common.view.driving) -------
def _command(seq: int, stamp_ns: int, **fields) -> RobotCommand:
    base = dict(robot_id=0, seq=seq, stream="s1", stamp_ns=stamp_ns, published_ns=stamp_ns,
                v_cm_s=12.0, omega_deg_s=-30.0, goal_cm=(50.0, -20.0), planner="fuzzy")  # fmt: skip
    return RobotCommand(**{**base, **fields})


def _drive(t_s: float, x: float) -> RobotDrive:
    pose = dict(x_cm=x, y_cm=1.0, heading_deg=90.0, v_cm_s=10.0, omega_deg_s=0.0)
    return RobotDrive(robot_id=0, stamp_ns=int(t_s * 1e9), t_s=t_s, goal_cm=(9.0, 9.0), **pose)


def test_a_command_is_stale_past_either_of_the_robots_limits() -> None:
    nav = NavigationConfig(max_frame_age_s=0.5, command_timeout_s=0.22)
    assert command_state(0.3, 0.1, "", nav) == ("current", "")
    state, why = command_state(0.51, 0.1, "", nav)
    assert state == "stale" and "0.51 s old" in why and "max_frame_age_s" in why
    state, why = command_state(0.1, 0.23, "", nav)
    assert state == "stale" and "0.23 s" in why and "command_timeout_s" in why
    assert command_state(0.1, 0.1, "source lost", nav) == (
        "stop",
        "the planner says stop: source lost",
    )
    assert command_state(0.9, 0.1, "source lost", nav)[0] == "stale"  # stale wins


def test_drives_show_goal_command_on_its_frame_and_the_worlds_trail() -> None:
    nav = NavigationConfig(max_frame_age_s=0.5, command_timeout_s=0.22)
    drives = Drives(nav)
    t0 = 1_700_000_000 * 10**9
    for i in range(3):
        drives.drive(_drive(i * 0.1, float(i)))
    (robot,) = drives.shown(t0, 100.0, {}, {})
    assert robot.goal_cm == (9.0, 9.0) and robot.goal_from == GOAL_FROM["world"]  # no command
    assert robot.trail_cm == [(0.0, 1.0), (1.0, 1.0), (2.0, 1.0)]
    assert robot.trail_from == WORLD_TRAIL_FROM and robot.command is None
    drives.command(_command(7, t0 - 200_000_000), received_s=100.0, replay=None)
    drives.command(_command(6, t0 - 300_000_000), received_s=100.0, replay=None)  # older: kept 7
    frames = {t0 - 200_000_000: 41, t0 - 100_000_000: 42}
    poses = {41: {0: (1.0, 2.0, 30.0)}, 42: {0: (3.0, 4.0, 35.0)}}
    (robot,) = drives.shown(t0, 100.1, frames, poses)
    c = robot.command
    assert robot.goal_cm == (50.0, -20.0) and robot.goal_from == GOAL_FROM["planner"]
    assert (c.seq, c.frame_seq, c.at, c.at_from) == (7, 41, (1.0, 2.0, 30.0), COMMAND_FROM["frame"])
    assert c.age_s == pytest.approx(0.2) and c.since_s == pytest.approx(0.1)
    assert (c.state, c.v_cm_s, c.omega_deg_s) == ("current", 12.0, -30.0)
    (robot,) = drives.shown(t0 + 150_000_000, 100.25, {}, poses)  # its frame gone; no newer cmd
    c = robot.command
    assert (c.frame_seq, c.at, c.at_from) == (None, (3.0, 4.0, 35.0), COMMAND_FROM["newest"])
    assert c.state == "stale" and "watchdog" in c.reason
    # a new run of the world (t_s back at 0) starts a new trail
    drives.drive(_drive(0.0, 5.0))
    assert drives.shown(t0, 100.0, {}, {})[0].trail_cm == [(5.0, 1.0)]


def test_a_replayed_command_is_aged_on_the_recordings_clock() -> None:
    nav = NavigationConfig(max_frame_age_s=0.5, command_timeout_s=0.22)
    drives = Drives(nav)
    recorded = 1_600_000_000 * 10**9  # years before now: its age is not now's
    mark = ReplayMark(recording="drive.mcap", recorded_ns=recorded, start_ns=recorded)
    drives.command(_command(3, recorded - 150_000_000), received_s=50.0, replay=mark)
    (robot,) = drives.shown(1_800_000_000 * 10**9, 50.05, {}, {})
    c = robot.command
    assert c.age_s == pytest.approx(0.2) and c.state == "current"
    assert c.replay == "drive.mcap" and c.at is None
    assert drives.shown(1_800_000_000 * 10**9, 50.4, {}, {})[0].command.state == "stale"


def test_robot_poses_of_an_obstacle_message() -> None:
    message = {"robots": [{"id": 2, "x_cm": 1.5, "y_cm": -2.0, "heading_deg": 45.0},
                          {"id": 3, "x_cm": "bad"}, {"x_cm": 1.0}]}  # fmt: skip
    assert robot_poses(message) == {2: (1.5, -2.0, 45.0)}
    assert robot_poses({}) == {}
