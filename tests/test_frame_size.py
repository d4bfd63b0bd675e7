"""A calibration against the source's frame size: used as it is, scaled exactly when only
the size differs (checked on the shared real photos resized), refused otherwise; the
simulator's calibration never taken for a real camera's; `ovis up`'s exit code from its
summary; a taken router endpoint seen before anything starts."""

from __future__ import annotations

import socket

import cv2
import msgspec
import numpy as np
import pytest
from real_photos import BOARD, SUBPIX, opencv_corners, photo_paths
from test_floor_pose import OUTER, corner_points, floor_xy

from ovis.common.analysis.live import LiveScore, with_verdict
from ovis.common.calibration.file import calibration_from_config
from ovis.common.calibration.floor import solve_floor_pose
from ovis.common.calibration.frame_size import FrameSizeError, fit_to_frames, made_on_simulator
from ovis.common.calibration.intrinsics import calibrate_intrinsics, detect_views
from ovis.common.camera.projection import project
from ovis.common.camera.scaling import same_aspect, scale_camera
from ovis.common.config import load_config
from ovis.common.messages import ObstacleFrame, ServiceStatus
from ovis.common.vision.boards import parse_board
from ovis.services.bus import endpoint_in_use


@pytest.fixture(scope="module")
def photo_calibration():
    """The floor pose of left01 with the lens of the other 13 photos (as
    `ovis calibrate --intrinsics`), at the photos' own 640x512."""
    spec = parse_board("chessboard:9x6")
    photos = photo_paths()
    frames = [(p.name, cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)) for p in photos[1:]]
    lens = calibrate_intrinsics(None, spec, views=detect_views(frames, spec)).intrinsics()
    corners = opencv_corners(photos[0]).astype(np.float64)
    return solve_floor_pose(lens, corner_points(corners, OUTER), image_size=(640, 512))


def _map(p: np.ndarray, factor: float) -> np.ndarray:
    """A pixel coordinate in the image resized by ``factor`` (pixel centres whole)."""
    return factor * (p + 0.5) - 0.5


def test_a_resized_photo_moves_its_corners_as_the_scaled_camera_says(photo_calibration) -> None:
    """The shared photo left01 resized to 1280x1024 (OpenCV, bilinear): the chessboard
    corners OpenCV finds in it are where the scaled camera projects the board, as
    closely as the camera at 640x512 projects them in the photo itself."""
    calib = photo_calibration
    big_cam = scale_camera(calib.camera, 1024, 1280)
    assert (big_cam.rows, big_cam.cols, big_cam.fx) == (1024, 1280, 2 * calib.camera.fx)
    gray = cv2.imread(str(photo_paths()[0]), cv2.IMREAD_GRAYSCALE)
    big = cv2.resize(gray, (1280, 1024), interpolation=cv2.INTER_LINEAR)
    found, c = cv2.findChessboardCorners(big, BOARD)
    assert found
    seen = cv2.cornerSubPix(big, c, (21, 21), *SUBPIX[1:]).reshape(-1, 2)
    xy = floor_xy()
    small = project(xy[:, 0], xy[:, 1], np.zeros(54), calib.camera)
    scaled = project(xy[:, 0], xy[:, 1], np.zeros(54), big_cam)
    at_640 = opencv_corners(photo_paths()[0])
    err_small = np.hypot(small.col - at_640[:, 0], small.row - at_640[:, 1])
    err_big = np.hypot(scaled.col - seen[:, 0], scaled.row - seen[:, 1])
    # twice the pixels: twice the error in pixels, the same on the board
    assert err_big.mean() < 2 * err_small.mean() + 0.1, (err_big.mean(), err_small.mean())
    # the half-pixel matters: a principal point merely doubled is off by half a pixel
    naive = msgspec.structs.replace(big_cam, cx=2 * calib.camera.cx, cy=2 * calib.camera.cy)
    off = project(xy[:, 0], xy[:, 1], np.zeros(54), naive)
    err_naive = np.hypot(off.col - seen[:, 0], off.row - seen[:, 1])
    assert err_naive.mean() > err_big.mean() + 0.2


@pytest.mark.parametrize("model", ["pinhole", "paper"])
def test_scaling_moves_every_projection_exactly_as_the_pixels(photo_calibration, model) -> None:
    cam = photo_calibration.camera if model == "pinhole" else load_config().camera
    rng = np.random.default_rng(3)
    x, y = rng.uniform(-20, 140, 200), rng.uniform(-20, 140, 200)
    before = project(x, y, np.zeros(200), cam)
    for rows, cols in ((2 * cam.rows, 2 * cam.cols), (cam.rows * 3 // 4, cam.cols * 3 // 4)):
        after = project(x, y, np.zeros(200), scale_camera(cam, rows, cols))
        ok = before.valid & after.valid
        assert ok.sum() > 50
        np.testing.assert_allclose(after.row[ok], _map(before.row[ok], rows / cam.rows), atol=1e-6)
        np.testing.assert_allclose(after.col[ok], _map(before.col[ok], cols / cam.cols), atol=1e-6)


def test_a_calibration_fits_its_own_size_scales_to_the_same_aspect_and_refuses_others(
    photo_calibration,
) -> None:
    calib = photo_calibration
    same, note = fit_to_frames(calib, 640, 512, source="DIR", name="C")
    assert same is calib and note == ""
    big, note = fit_to_frames(calib, 1280, 1024, source="DIR", name="C")
    assert "is for 640x512, DIR delivers 1280x1024" in note and "scaled by 2" in note
    assert (big.camera.cols, big.camera.rows) == (1280, 1024)
    assert "scaled from 640x512 to 1280x1024" in big.source_image
    assert same_aspect(1920, 1080, 1280, 720) and same_aspect(640, 512, 320, 256)
    assert not same_aspect(640, 512, 640, 480)
    with pytest.raises(FrameSizeError) as err:
        fit_to_frames(calib, 640, 480, source="DIR", name="C")
    assert "DIR delivers 640x480 frames but C is for 640x512" in str(err.value)
    # a background image of the calibration's size cannot be scaled: said, not guessed
    with_bg = msgspec.structs.replace(
        calib, image=msgspec.structs.replace(calib.image, background="floor.png")
    )
    with pytest.raises(FrameSizeError, match="background image is made for 640x512"):
        fit_to_frames(with_bg, 1280, 1024, source="DIR", name="C")


def test_the_simulators_calibration_is_never_a_real_cameras(photo_calibration) -> None:
    assert not made_on_simulator(photo_calibration)
    sim = msgspec.structs.replace(calibration_from_config(load_config()), version=1)
    assert made_on_simulator(msgspec.structs.replace(sim, simulated=True))
    # before the flag was written: the calibrator's ("frame N") on the preset's set-up
    assert made_on_simulator(msgspec.structs.replace(sim, source_image="frame 12"))
    assert not made_on_simulator(msgspec.structs.replace(sim, source_image="floor.png"))


def _status(service: str, **fields) -> ServiceStatus:
    return ServiceStatus(service=service, pid=1, host="h", started_ns=0, **fields)


def _frames(live: LiveScore, stream: str, n: int) -> None:
    for seq in range(n):
        msg = ObstacleFrame(
            seq=seq, stamp_ns=10**9, published_ns=10**9, frame_age_ms=1.0,
            calibration_version=1, robot=None, obstacles=[], planner=[], stream=stream,
        )  # fmt: skip
        live.add_obstacles(msg, 10**9 + 2_000_000)


def test_the_exit_code_says_what_came_out() -> None:
    live = LiveScore()
    capture = _status("capture", state="ok", frames_out=5, stream="ours")
    _frames(live, "ours", 5)
    _frames(live, "theirs", 7)  # another system's frames on the same bus: not counted
    ok = with_verdict(live.summary({"capture": capture}, {}, 3.0, streams={"ours"}), capture, [])
    assert (ok.frames_processed, ok.exit_code, ok.reason, ok.health) == (5, 0, "", {})
    lost = _status("capture", state="source lost", reason="camera 0 unplugged", frames_out=5)
    end = with_verdict(live.summary({"capture": lost}, {}, 3.0, streams={"ours"}), lost, [])
    assert end.exit_code == 3 and "camera 0 unplugged" in end.reason
    assert end.health["capture"] == "source lost: camera 0 unplugged"
    # nothing processed: exit 3, and the health is never "ok"
    gone = _status("capture", state="source lost", last_error="folder D is gone")
    idle = with_verdict(LiveScore().summary({"capture": gone}, {}, 3.0), gone, [])
    assert idle.exit_code == 3 and idle.reason == "no frame was captured: folder D is gone"
    assert idle.health["run"] == "no frame processed"
    refused = _status("preprocess", state="failing", reason="9 inputs, no output")
    statuses = {"capture": _status("capture", state="ok", frames_out=9), "preprocess": refused}
    none = with_verdict(LiveScore().summary(statuses, {}, 3.0), statuses["capture"], [])
    assert (
        none.reason == "9 frames captured, none processed: preprocess failing: 9 inputs, no output"
    )
    died = with_verdict(live.summary({"capture": capture}, {}, 3.0), capture, ["pose died"])
    assert (died.exit_code, died.reason) == (1, "pose died")


def test_a_taken_endpoint_is_seen_before_anything_starts() -> None:
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        assert endpoint_in_use(f"tcp/127.0.0.1:{port}") is not None
        assert endpoint_in_use(f"tcp/localhost:{port}") is not None
    assert endpoint_in_use(f"tcp/127.0.0.1:{port}") is None
    assert endpoint_in_use("tcp/127.0.0.1:0") is None  # any port: nothing to check


def test_board_corners_of_the_fixture_are_the_photos(photo_calibration) -> None:
    """The fixture is the photos' own calibration (a wrong fixture would pass the rest)."""
    xy = floor_xy()
    p = project(xy[:, 0], xy[:, 1], np.zeros(54), photo_calibration.camera)
    seen = opencv_corners(photo_paths()[0])
    assert np.hypot(p.col - seen[:, 0], p.row - seen[:, 1]).mean() < 0.5
