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

from ovis.common.calibration.file import calibration_from_config
from ovis.common.camera.projection import project
from ovis.common.config import load_config
from ovis.common.messages import BinaryFrame, BlobList, ServiceStatus, StreamHealth
from ovis.common.sim.arena import Arena
from ovis.common.view.health import LatencyWindow, summarize, summarize_calibration
from ovis.common.view.picture import ROBOT, binary_image, downscale, draw_overlay, to_jpeg
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
    out = draw_overlay(small, scale, objects=objects, blobs=blobs, camera=config.camera)
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
