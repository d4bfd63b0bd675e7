"""Floor pose with a known lens on the shared real photos: 4 outer corners → the other 50.

Leave one photo out at a time: the lens comes from the other 13 photos, the pose from the
photo's 4 outer board corners given as pixel-known control points, and every other corner
is located on the floor (the board plane) and compared with its true board position.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import msgspec
import numpy as np
import pytest
from real_photos import board_xyz, opencv_corners, photo_paths, without_board
from test_cli import assert_one_line_error, ovis

from ovis.common.calibration.floor import solve_floor_pose
from ovis.common.calibration.intrinsics import calibrate_intrinsics, detect_views
from ovis.common.camera.intrinsics import read_intrinsics, write_intrinsics
from ovis.common.camera.projection import back_project
from ovis.common.config import ControlPoint
from ovis.common.vision.boards import parse_board

OUTER = (0, 8, 45, 53)  # the board's four outer inner-corners
#: the issue's bounds, in squares
MEAN_SQUARES, MAX_SQUARES = 0.015, 0.05


def floor_xy() -> np.ndarray:
    """Board corners in the floor frame of `--board` (x along the first row, z up: y = −row)."""
    xy = board_xyz()[:, :2].astype(np.float64)
    xy[:, 1] *= -1
    return xy


def corner_points(corners: np.ndarray, which) -> list[ControlPoint]:
    xy = floor_xy()
    return [
        ControlPoint(
            name=f"c{i}",
            x_cm=xy[i, 0],
            y_cm=xy[i, 1],
            row=float(corners[i, 1]),
            col=float(corners[i, 0]),
        )
        for i in which
    ]


def write_points(path: Path, corners: np.ndarray, which) -> None:
    xy = floor_xy()
    path.write_text(
        "".join(
            f'[[points]]\nname = "c{i}"\nx_cm = {xy[i, 0]}\ny_cm = {xy[i, 1]}\n'
            f"row = {corners[i, 1]}\ncol = {corners[i, 0]}\n"
            for i in which
        )
    )


@pytest.fixture(scope="module")
def views():
    spec = parse_board("chessboard:9x6")
    frames = [(p.name, cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)) for p in photo_paths()]
    return spec, detect_views(frames, spec)


def test_four_corners_locate_the_other_fifty_on_every_photo(views) -> None:
    spec, (found, rejected, size) = views
    assert not rejected and len(found) == 14
    rest = np.setdiff1d(np.arange(54), OUTER)
    table = []
    for k, held in enumerate(found):
        others = [f for j, f in enumerate(found) if j != k]
        lens = calibrate_intrinsics(None, spec, views=(others, [], size)).intrinsics()
        corners = held.view.image_xy.astype(np.float64)
        calib = solve_floor_pose(lens, corner_points(corners, OUTER), image_size=size)
        b = back_project(corners[rest, 1], corners[rest, 0], calib.camera, 0.0)
        assert b.valid.all()
        err = np.hypot(b.x_cm - floor_xy()[rest, 0], b.y_cm - floor_xy()[rest, 1])
        table.append((held.name, float(err.mean()), float(err.max()), calib.dipe_px))
    print("\nphoto       mean sq   max sq   DIPE px (4 corners)")
    for name, mean, worst, dipe in table:
        print(f"{name:11s} {mean:.4f}    {worst:.4f}   {dipe:.3f}")
    assert all(mean < MEAN_SQUARES for _, mean, _, _ in table), table
    assert all(worst < MAX_SQUARES for _, _, worst, _ in table), table


def floor_calibration(photo: Path, cam: Path, out: Path, *how: str) -> dict:
    """`ovis calibrate PHOTO --intrinsics CAM --out OUT --json` with the points given by ``how``."""
    args = ["calibrate", str(photo), "--intrinsics", str(cam), *how, "--out", str(out), "--json"]
    return json.loads(ovis(*args).stdout)


def test_cli_intrinsics_calibrate_locate_on_a_held_out_photo(tmp_path: Path) -> None:
    photos = photo_paths()
    cam, calib, points = tmp_path / "CAM.yaml", tmp_path / "calib.json", tmp_path / "pts.toml"
    ovis("intrinsics", *map(str, photos[1:]), "--board", "chessboard:9x6", "--out", str(cam))
    corners = opencv_corners(photos[0]).astype(np.float64)
    write_points(points, corners, OUTER)
    out = floor_calibration(photos[0], cam, calib, "--points", str(points))
    assert out["camera"]["model"] == "pinhole" and out["dipe_mm"] is None
    assert out["dipe_px"] < 0.3
    rest = np.setdiff1d(np.arange(54), OUTER)
    args = [a for i in rest for a in ("--pixel", f"{corners[i, 1]},{corners[i, 0]}")]
    located = json.loads(ovis("locate", str(calib), *args, "--json").stdout)
    assert [(p["row"], p["col"]) for p in located] == [
        pytest.approx((corners[i, 1], corners[i, 0])) for i in rest
    ]
    xy = np.array([[p["x_cm"], p["y_cm"]] for p in located])
    err = np.hypot(*(xy - floor_xy()[rest]).T)
    assert err.mean() < MEAN_SQUARES and err.max() < MAX_SQUARES


def test_board_on_the_floor_matches_opencvs_pose_with_held_out_error(tmp_path: Path) -> None:
    photos = photo_paths()
    cam, calib = tmp_path / "CAM.yaml", tmp_path / "calib.json"
    ovis("intrinsics", *map(str, photos[1:]), "--board", "chessboard:9x6", "--out", str(cam))
    out = floor_calibration(
        photos[0], cam, calib, "--board", "chessboard:9x6", "--square-cm", "2.5"
    )
    assert len(out["points"]) == 54
    # OpenCV's own pose of the board (its frame: y along the columns, z away from the
    # camera) is ours with y and z negated.
    lens = read_intrinsics(cam)
    obj = board_xyz().astype(np.float64) * 2.5
    _, rvec, tvec = cv2.solvePnP(obj, opencv_corners(photos[0]), lens.matrix, lens.coefficients)
    R = cv2.Rodrigues(rvec)[0]
    ours_R = cv2.Rodrigues(np.array(out["camera"]["rvec"]))[0]
    assert np.allclose(ours_R, R @ np.diag([1.0, -1.0, -1.0]), atol=1e-3)
    assert np.allclose(out["camera"]["tvec_cm"], tvec.ravel(), atol=0.02)
    loo = out["accuracy"]["leave_one_out"]
    assert loo["method"] == "leave-one-out" and len(loo["points"]) == 54
    assert loo["mean_px"] < 0.3 and loo["mean_cm"] < 0.05  # 2.5 cm squares
    assert loo["mean_px"] >= out["dipe_px"]  # held out is never better than in-sample


def test_markers_on_the_floor(tmp_path: Path) -> None:
    """Four ArUco markers drawn on a real photo's floor through a known pose: found, and
    the pose recovered from them."""
    photos = photo_paths()
    cam = tmp_path / "CAM.yaml"
    ovis("intrinsics", *map(str, photos[:6]), "--board", "chessboard:9x6", "--out", str(cam))
    lens = read_intrinsics(cam)
    rvec, tvec = np.array([2.9, 0.1, 0.2]), np.array([-5.0, 5.0, 120.0])
    floor = without_board(photos[0])
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    centres = {3: (-30.0, 20.0), 7: (30.0, 20.0), 11: (-30.0, -25.0), 12: (30.0, -25.0)}
    side = 12.0
    for marker_id, (x, y) in centres.items():
        tile = cv2.aruco.generateImageMarker(dictionary, marker_id, 120, borderBits=1)
        tile = cv2.copyMakeBorder(tile, 20, 20, 20, 20, cv2.BORDER_CONSTANT, value=255)
        s = side * 160 / 120 / 2  # the white margin around the marker too
        world = np.array(
            [[x - s, y + s, 0], [x + s, y + s, 0], [x + s, y - s, 0], [x - s, y - s, 0]]
        )
        pix, _ = cv2.projectPoints(world, rvec, tvec, lens.matrix, lens.coefficients)
        src = np.array([[0, 0], [159, 0], [159, 159], [0, 159]], np.float32)
        H = cv2.getPerspectiveTransform(src, pix.reshape(4, 2).astype(np.float32))
        warped = cv2.warpPerspective(tile, H, floor.shape[::-1], borderValue=0)
        mask = cv2.warpPerspective(np.full_like(tile, 255), H, floor.shape[::-1])
        floor[mask > 0] = warped[mask > 0]
    image = tmp_path / "floor.png"
    cv2.imwrite(str(image), floor)
    markers = tmp_path / "markers.toml"
    markers.write_text(
        'dictionary = "DICT_4X4_50"\n'
        + "".join(
            f"[[markers]]\nid = {i}\nx_cm = {x}\ny_cm = {y}\nside_cm = {side}\n"
            for i, (x, y) in centres.items()
        )
    )
    out = floor_calibration(image, cam, tmp_path / "calib.json", "--markers", str(markers))
    assert len(out["points"]) == 16 and out["dipe_px"] < 0.5
    assert np.allclose(out["camera"]["tvec_cm"], tvec, atol=1.0)
    assert np.allclose(out["camera"]["rvec"], rvec, atol=0.01)


@pytest.fixture(scope="module")
def lens_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    cam = tmp_path_factory.mktemp("lens") / "CAM.yaml"
    ovis("intrinsics", *map(str, photo_paths()[1:]), "--board", "chessboard:9x6", "--out", str(cam))
    return cam


@pytest.mark.parametrize(
    ("case", "needle"),
    [
        ("outside", "outside the 640x512 image"),
        ("too few", "at least 4 points"),
        ("collinear", "on one line"),
        ("other size", "the intrinsics are for 800x600"),
        ("no board", "chessboard:9x6 not found"),
    ],
)
def test_bad_floor_input_is_one_line_exit_2_nothing_written(
    lens_file: Path, tmp_path: Path, case: str, needle: str
) -> None:
    photo = photo_paths()[0]
    corners = opencv_corners(photo).astype(np.float64)
    points, out, cam = tmp_path / "pts.toml", tmp_path / "calib.json", lens_file
    args = ["--points", str(points)]
    if case == "outside":
        corners[53] = (700.0, 100.0)  # col 700 in a 640-wide image
        write_points(points, corners, OUTER)
    elif case == "too few":
        write_points(points, corners, OUTER[:3])
    elif case == "collinear":
        write_points(points, corners, (0, 2, 4, 8))  # all on the first row
    elif case == "other size":
        lens = read_intrinsics(lens_file)
        cam = tmp_path / "CAM800.yaml"
        write_intrinsics(cam, msgspec.structs.replace(lens, width=800, height=600))
        write_points(points, corners, OUTER)
    else:
        blank = tmp_path / "blank.png"
        cv2.imwrite(str(blank), without_board(photo))
        photo, args = blank, ["--board", "chessboard:9x6"]
    proc = ovis(
        "calibrate", str(photo), "--intrinsics", str(cam), *args, "--out", str(out), check=False
    )
    assert_one_line_error(proc, needle)
    assert proc.returncode == 2 and not out.exists()


def test_pixel_points_need_the_intrinsics(tmp_path: Path) -> None:
    photo = photo_paths()[0]
    write_points(tmp_path / "pts.toml", opencv_corners(photo), OUTER)
    out = tmp_path / "calib.json"
    proc = ovis(
        "calibrate",
        str(photo),
        "--points",
        str(tmp_path / "pts.toml"),
        "--out",
        str(out),
        check=False,
    )
    assert_one_line_error(proc, "add --intrinsics")
    assert proc.returncode == 2 and not out.exists()


def test_locate_refuses_pixels_outside_the_image(tmp_path: Path, lens_file: Path) -> None:
    photo = photo_paths()[0]
    calib = tmp_path / "calib.json"
    ovis(
        "calibrate",
        str(photo),
        "--intrinsics",
        str(lens_file),
        "--board",
        "chessboard:9x6",
        "--out",
        str(calib),
    )
    for pixel, needle in (
        ("600,10", "outside the 640x512 image"),
        ("1,nan", "finite"),
        ("12", "ROW,COL"),
    ):
        assert_one_line_error(ovis("locate", str(calib), "--pixel", pixel, check=False), needle)
