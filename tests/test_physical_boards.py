"""Calibrating a physical camera the documented way (issue 36, item 4), against the
truth of the physical world: a printed chessboard rendered by MuJoCo through the
oblique rig's camera (640 × 480, 50° across, with lens distortion), held before it at
45–85 cm for `ovis intrinsics`, then laid on the floor for `ovis calibrate --board`,
placed in the arena's frame, and checked with `ovis locate` on known floor points.

The seeds and placements here were not used to choose the corner window, the smoothing
or anything else (those used seeds 100–102, 200–203 and 300–326, and other placements)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import msgspec
import numpy as np
import pytest
from cli_helpers import ovis
from physical_helpers import skip_module_without_physical

skip_module_without_physical()  # before MuJoCo is imported: without OpenGL its import fails

from ovis.common.camera.projection import project  # noqa: E402
from ovis.common.config import load_config  # noqa: E402
from ovis.common.physical.boards import BoardScene, held_poses, lying_on_floor  # noqa: E402
from ovis.common.physical.rigs import rig  # noqa: E402
from ovis.common.vision.boards import SUBPIX_CRITERIA, find_board, parse_board  # noqa: E402

#: The board held up: 9 × 6 inner corners of 2 cm (an A4 print).
HELD = parse_board("chessboard:9x6", 2.0)
#: Views of it for one lens, as docs/real-camera.md asks for (15–20).
VIEWS = 15
#: The issue's bounds: focal length (share of the truth) and floor points located (cm).
FOCAL_SHARE, LOCATE_CM = 0.003, 0.2


def _config():
    """The issue's arena: 150 × 120 cm."""
    config = load_config()
    arena = {"arena_x_cm": (0.0, 150.0), "arena_y_cm": (0.0, 120.0)}
    simulator = msgspec.structs.replace(config.simulator, **arena)
    return msgspec.structs.replace(config, simulator=simulator)


def _camera():
    """The oblique rig over that arena: 140 cm up, 120 cm back from its middle."""
    return rig("oblique", _config())


def _truth_px(camera, xyz: np.ndarray) -> np.ndarray:
    """(N, 2) pixels (x = column, y = row) where the camera sees world points (cm)."""
    p = project(xyz[:, 0], xyz[:, 1], xyz[:, 2], camera)
    assert p.valid.all()
    return np.column_stack([p.col, p.row])


def test_board_corners_are_found_where_the_camera_sees_them() -> None:
    """Rendered boards at the far end of the range (80–85 cm, tilted up to 50°): every
    corner found within a quarter pixel of its true image position, in the printed
    board's own order. The calibration tutorial's fixed 11-pixel half window puts corners
    of these views more than a pixel off (their squares are narrower than the window):
    what the window fitted to the squares mends."""
    camera = _camera()
    worst, fixed_worst = 0.0, 0.0
    poses = held_poses(camera, HELD, 4, seed=43, distance_cm=(80.0, 85.0), max_tilt_deg=50.0)
    with BoardScene(HELD, camera, seed=43) as scene:
        for k, pose in enumerate(poses):
            frame = scene.render(pose, k)
            view = find_board(frame, HELD)
            assert view is not None, k
            truth = _truth_px(camera, pose.corners_cm(HELD))
            worst = max(worst, float(np.linalg.norm(view.image_xy - truth, axis=1).max()))
            found, raw = cv2.findChessboardCorners(frame, (HELD.cols, HELD.rows))
            assert found
            fixed = cv2.cornerSubPix(frame, raw, (11, 11), (-1, -1), SUBPIX_CRITERIA)
            # OpenCV's own order is the printed board's here: compare corner by corner
            fixed_err = np.linalg.norm(fixed.reshape(-1, 2) - truth, axis=1)
            fixed_worst = max(fixed_worst, float(np.sort(fixed_err)[-1]))
    assert worst < 0.25, worst
    assert fixed_worst > 1.0, fixed_worst


def _held_views(folder: Path, seed: int) -> Path:
    """``VIEWS`` photos of the held board before the camera, as PNG files in ``folder``."""
    camera = _camera()
    folder.mkdir(parents=True, exist_ok=True)
    with BoardScene(HELD, camera, seed=seed) as scene:
        for k, pose in enumerate(held_poses(camera, HELD, VIEWS, seed=seed)):
            cv2.imwrite(str(folder / f"view{k:02d}.png"), scene.render(pose, k))
    return folder


def _intrinsics(folder: Path, cam: Path) -> dict:
    args = ["--board", "chessboard:9x6", "--square-cm", "2", "--out", str(cam), "--json"]
    return json.loads(ovis("intrinsics", str(folder), *args).stdout)


@pytest.fixture(scope="module")
def lens(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """`ovis intrinsics` on the held board's photos (seed 41): CAM.yaml and its report."""
    home = tmp_path_factory.mktemp("lens")
    cam = home / "CAM.yaml"
    return cam, _intrinsics(_held_views(home / "photos", 41), cam)


def _assert_true_lens(report: dict) -> None:
    camera = _camera()
    K = np.array(report["camera_matrix"])
    print(
        f"\nlens: RMS {report['rms_px']:.3f} px, fx {100 * (K[0, 0] / camera.fx - 1):+.3f} %, "
        f"fy {100 * (K[1, 1] / camera.fy - 1):+.3f} %, principal point off by "
        f"({K[0, 2] - camera.cx:+.2f}, {K[1, 2] - camera.cy:+.2f}) px"
    )
    assert abs(K[0, 0] / camera.fx - 1.0) < FOCAL_SHARE, (K[0, 0], camera.fx)
    assert abs(K[1, 1] / camera.fy - 1.0) < FOCAL_SHARE, (K[1, 1], camera.fy)
    # the principal point is less well determined by 15 views (within 2 px on the tuning seeds)
    assert abs(K[0, 2] - camera.cx) < 3.0 and abs(K[1, 2] - camera.cy) < 3.0, K
    assert report["rms_px"] < 0.1 and not report["outliers"]
    assert len(report["views_used"]) == VIEWS
    # every view's window fits its squares: at most OpenCV's tutorial's, smaller on small squares
    windows = [v["window_px"] for v in report["per_view"]]
    assert max(windows) <= 23 and min(windows) < 23, windows


def test_intrinsics_from_a_held_board_give_the_true_focal_length(lens) -> None:
    _assert_true_lens(lens[1])


def test_intrinsics_on_another_seed(tmp_path: Path) -> None:
    _assert_true_lens(_intrinsics(_held_views(tmp_path / "photos", 42), tmp_path / "CAM.yaml"))


def _arena_points(camera) -> tuple[np.ndarray, np.ndarray]:
    """Floor points of the arena the camera sees (cm, z = 0) and their true pixels."""
    config = _config()
    (x0, x1), (y0, y1) = config.simulator.arena_x_cm, config.simulator.arena_y_cm
    gx, gy = np.meshgrid(np.linspace(x0, x1, 7), np.linspace(y0, y1, 6))
    xyz = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    p = project(xyz[:, 0], xyz[:, 1], xyz[:, 2], camera)
    inside = p.valid & (p.col >= 0) & (p.col <= camera.cols - 1)
    inside &= (p.row >= 0) & (p.row <= camera.rows - 1)
    return xyz[inside], np.column_stack([p.row, p.col])[inside]


@pytest.mark.parametrize(
    ("square_cm", "x_cm", "y_cm", "angle_deg"),
    [
        (2.5, 70.0, 55.0, 15.0),
        (5.0, 80.0, 62.0, -35.0),
        (5.0, 68.0, 64.0, 180.0),  # along the arena's axes, as a lab lays it
        (10.0, 72.0, 66.0, 190.0),
    ],
)
def test_a_board_on_the_floor_placed_in_the_arena(
    lens, tmp_path: Path, square_cm: float, x_cm: float, y_cm: float, angle_deg: float
) -> None:
    """The board lying on the floor before the oblique camera (turned any way, even
    upside down as the camera sees it; its edges along the pixel rows too, where
    cornerSubPix is most drawn to pixel centres), its origin corner and its first row's
    end given in the arena's frame: the calibration is accepted (its residuals explained
    by the lens) and `ovis locate` puts a grid over the whole arena floor where it is."""
    cam, _ = lens
    camera = _camera()
    spec = parse_board("chessboard:9x6", square_cm)
    pose = lying_on_floor(spec, x_cm, y_cm, angle_deg)
    with BoardScene(spec, camera, floor=True, seed=int(square_cm * 10)) as scene:
        cv2.imwrite(str(tmp_path / "floor.png"), scene.render(pose))
    corners = pose.corners_cm(spec)
    origin, row_end = corners[0], corners[spec.cols - 1]
    calib = tmp_path / "calib.json"
    proc = ovis(
        "calibrate", str(tmp_path / "floor.png"), "--intrinsics", str(cam),
        "--board", "chessboard:9x6", "--square-cm", f"{square_cm:g}",
        "--board-origin", f"{origin[0]:.3f},{origin[1]:.3f}",
        "--board-row-end", f"{row_end[0]:.3f},{row_end[1]:.3f}",
        "--out", str(calib), "--json",
    )  # fmt: skip
    out = json.loads(proc.stdout)
    assert out["accuracy"]["lens"]["explained"], out["accuracy"]["lens"]
    assert out["accuracy"]["notes"][0].startswith("floor frame: the arena's")
    # the corners' control points are in the arena's frame (their printed face, 0.01 cm up)
    got = np.array([[p["x_cm"], p["y_cm"]] for p in out["points"]])
    assert np.abs(got - corners[:, :2]).max() < 1e-3
    xyz, pixels = _arena_points(camera)
    assert len(xyz) >= 30
    args = [a for r, c in pixels for a in ("--pixel", f"{r:.4f},{c:.4f}")]
    located = json.loads(ovis("locate", str(calib), *args, "--json").stdout)
    xy = np.array([[p["x_cm"], p["y_cm"]] for p in located])
    err = np.hypot(*(xy - xyz[:, :2]).T)
    print(f"\n{square_cm:g} cm squares at {angle_deg:g} deg: {len(err)} arena points located, "
          f"mean {err.mean():.3f} cm, max {err.max():.3f} cm")  # fmt: skip
    assert err.max() < LOCATE_CM, err.max()
