"""Marked robots on real photos: OpenCV's ChArUco tutorial photos (tests/data/opencv-charuco,
see its README), a printed board of 17 markers of DICT_6X6_250 between the squares of a
5 × 7 chessboard, taken with the camera whose intrinsics come with them.

The chessboard's corners (OpenCV's ChArUco detector, independent of the markers' own
corners) give the camera's pose on the board with ``cv2.solvePnP``: that is the
calibration. Each marker stands for a robot lying on the board (marker height 0); ovis
finds the markers, puts each robot's centre on the board and its heading, and the board's
layout gives the known answer: the centre of the marker's chessboard square, and one
heading shared by every marker.
"""

from __future__ import annotations

import cmath
import math
from pathlib import Path

import cv2
import msgspec
import numpy as np
import pytest

from ovis.common.calibration.file import calibration_from_config
from ovis.common.config import PinholeParams, PoseConfig, RobotSpec, load_config
from ovis.common.messages import BinaryFrame, Frame, decode, encode
from ovis.common.pipeline.stages import binary_frame
from ovis.common.vision.markers import find_markers, median_keeps_cells
from ovis.common.world.marker_search import BlobMarkers, marker_side_px, markers_around
from ovis.common.world.robots import RobotTracker, corner_pose

DATA = Path(__file__).parent / "data" / "opencv-charuco"
#: the board of the tutorial (``-w=5 -h=7 -sl=0.04 -ml=0.02 -d=10``), in cm
SQUARES, SQUARE_CM, MARKER_CM = (5, 7), 4.0, 2.0
DICTIONARY = "aruco_6x6_250"
#: photo → the markers OpenCV's own detector (default settings) finds in it
PHOTOS = {"choriginal.jpg": set(range(17)), "chocclusion_original.jpg": {*range(11), 12, 15}}


def _board() -> cv2.aruco.CharucoBoard:
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    return cv2.aruco.CharucoBoard(SQUARES, SQUARE_CM, MARKER_CM, d)


def _camera(gray: np.ndarray) -> PinholeParams:
    """The photo's camera on the board (world = the board's frame, cm): the tutorial's
    intrinsics, and the pose from the chessboard corners (reprojected within 0.5 px)."""
    fs = cv2.FileStorage(str(DATA / "tutorial_camera_charuco.yml"), cv2.FILE_STORAGE_READ)
    k, dist = fs.getNode("camera_matrix").mat(), fs.getNode("distortion_coefficients").mat()
    board = _board()
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(gray)
    obj, img = board.matchImagePoints(corners, ids)
    ok, rvec, tvec = cv2.solvePnP(obj, img, k, dist)
    assert ok and len(obj) >= 12
    again, _ = cv2.projectPoints(obj, rvec, tvec, k, dist)
    assert np.linalg.norm(again.reshape(-1, 2) - img.reshape(-1, 2), axis=1).max() < 0.5
    k1, k2, p1, p2, k3 = dist.ravel().tolist()
    (fx, _, cx), (_, fy, cy), _ = k.tolist()
    return PinholeParams(
        rows=gray.shape[0], cols=gray.shape[1], fx=fx, fy=fy, cx=cx, cy=cy,
        k1=k1, k2=k2, p1=p1, p2=p2, k3=k3,
        rvec=tuple(rvec.ravel().tolist()), tvec_cm=tuple(tvec.ravel().tolist()),
    )  # fmt: skip


def _pose() -> PoseConfig:
    """Every marker of the board as a robot lying on it."""
    robots = [
        RobotSpec(
            id=i,
            name=f"m{i}",
            marker_id=i,
            marker_side_cm=MARKER_CM,
            marker_height_cm=0.0,
            radius_cm=1.5,
        )
        for i in range(17)
    ]
    return PoseConfig(robots=robots, marker_dictionary=DICTIONARY, robot_height_cm=0.0)


def _truth() -> dict[int, tuple[float, float, float]]:
    """Each marker's centre on the board and heading, from the board's layout."""
    board = _board()
    out = {}
    for marker, corners in zip(board.getIds().ravel().tolist(), board.getObjPoints(), strict=True):
        tl, tr, br, bl = (complex(x, y) for x, y, _ in corners.tolist())
        out[marker] = corner_pose(tl, tr, br, bl)
    return out


@pytest.fixture(scope="module", params=sorted(PHOTOS))
def photo(request: pytest.FixtureRequest) -> tuple[str, np.ndarray, PinholeParams]:
    gray = cv2.imread(str(DATA / request.param), cv2.IMREAD_GRAYSCALE)
    assert gray is not None, f"missing {DATA / request.param}"
    return request.param, gray, _camera(gray)


def test_opencv_finds_the_markers_we_expect(photo) -> None:
    name, gray, _ = photo
    _, ids, _ = cv2.aruco.ArucoDetector(_board().getDictionary()).detectMarkers(gray)
    assert set(ids.ravel().tolist()) == PHOTOS[name]


def test_cells_too_small_for_the_median_are_searched_in_the_photo_itself(photo) -> None:
    """30 px markers of 8 cells: the 3×3 median would lose up to 6 of 17 of them."""
    name, gray, camera = photo
    side_px = marker_side_px(_pose(), camera)
    assert not median_keeps_cells(DICTIONARY, side_px)
    found = find_markers(gray, DICTIONARY, side_px=side_px)
    assert set(found.ids.tolist()) == PHOTOS[name] and found.partial == 0
    in_median = find_markers(cv2.medianBlur(gray, 3), DICTIONARY, side_px=side_px, median_done=True)
    assert len(in_median.ids) < len(PHOTOS[name])  # what the median would have cost
    # the running pipeline: the preprocess stage sends the label stage the photo itself
    calib = calibration_from_config(load_config())
    calib = msgspec.structs.replace(calib, camera=camera, pose=_pose(), version=1)
    frame = Frame.from_image(gray, seq=1, stamp_ns=1)
    sent = decode(encode(binary_frame(frame, gray, calib, BlobMarkers())), BinaryFrame)
    assert np.array_equal(sent.median_image(), gray)


def test_boxes_around_the_markers_find_what_the_whole_photo_does(photo) -> None:
    """The search in boxes (as around the blobs) gives the same corners as the whole
    photo: a box holds what the detector needs."""
    _, gray, camera = photo
    pose = _pose()
    side_px = marker_side_px(pose, camera)
    whole = find_markers(gray, DICTIONARY, side_px=side_px)
    centre = whole.corners.mean(axis=1)
    h = 0.75 * side_px[1] + 6.0
    # blobs as marker_boxes reads them: row, col, area, (perimeter, compactness), moments
    n = len(centre)
    var = np.full(n, (h / 2.4) ** 2)
    blobs = (centre[:, 0], centre[:, 1], np.full(n, 1.0), None, None, var, var, np.zeros(n))
    boxed = markers_around(gray, blobs, pose, side_px)
    assert boxed.ids.tolist() == whole.ids.tolist()
    assert np.abs(boxed.corners - whole.corners).max() < 0.3


def test_robot_positions_and_headings_match_the_board(photo) -> None:
    """Known answer: where the board's layout puts each marker, and its heading."""
    name, gray, camera = photo
    pose = _pose()
    tracker = RobotTracker(pose)
    found = find_markers(gray, DICTIONARY, side_px=marker_side_px(pose, camera))
    robots, unknown = tracker.update(found, camera, 0.0)
    assert not unknown and {r.marker_id for r in robots} == PHOTOS[name]
    truth = _truth()
    position = [abs(complex(r.x_cm, r.y_cm) - complex(*truth[r.marker_id][:2])) for r in robots]
    heading = [
        abs(math.degrees(cmath.phase(cmath.rect(1, math.radians(r.heading_deg - t[2])))))
        for r in robots
        for t in [truth[r.marker_id]]
    ]
    # 2 cm markers of some 30 px (0.07 cm a pixel): centres within half a millimetre on
    # average and 2 mm at worst, headings within 0.5° on average and 1.5° at worst
    assert np.mean(position) < 0.05 and max(position) < 0.2, position
    assert np.mean(heading) < 0.5 and max(heading) < 1.5, heading
