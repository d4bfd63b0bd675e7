"""`ovis intrinsics` on the shared real photos against OpenCV's own calibration of them."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from cli_helpers import assert_one_line_error, ovis
from real_photos import opencv_calibration, photo_paths, without_board

from ovis.common.camera.intrinsics import read_intrinsics
from ovis.common.vision.boards import BoardError, parse_board


@pytest.fixture(scope="module")
def photos_with_blank(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The 14 photos and one real photo whose board was painted over (left00_blank.png)."""
    folder = tmp_path_factory.mktemp("photos")
    for p in photo_paths():
        shutil.copy(p, folder / p.name)
    cv2.imwrite(str(folder / "left00_blank.png"), without_board(photo_paths()[0]))
    return folder


def test_intrinsics_gives_opencvs_result_and_rejects_the_blank_photo(
    photos_with_blank: Path, tmp_path: Path
) -> None:
    cam, plot = tmp_path / "CAM.yaml", tmp_path / "coverage.png"
    proc = ovis(
        "intrinsics",
        str(photos_with_blank),
        "--board",
        "chessboard:9x6",
        "--square-cm",
        "2.5",
        "--out",
        str(cam),
        "--plot",
        str(plot),
        "--json",
    )
    out = json.loads(proc.stdout)
    rms, K, d = opencv_calibration(photo_paths())
    assert out["rms_px"] == pytest.approx(rms, rel=1e-3)
    got = np.array(out["camera_matrix"])
    for i, j in ((0, 0), (1, 1), (0, 2), (1, 2)):  # fx, fy, cx, cy
        assert got[i, j] == pytest.approx(K[i, j], rel=1e-3)
    assert np.allclose(out["dist"], d, atol=1e-3)
    # The README's figures, as a second opinion.
    assert out["rms_px"] == pytest.approx(0.1235, abs=5e-4)
    assert got[0, 0] == pytest.approx(516.2, abs=0.1) and got[1, 2] == pytest.approx(250.0, abs=0.1)
    assert out["views_used"] == [p.name for p in photo_paths()]
    assert out["views_rejected"] == [
        {"view": "left00_blank.png", "reason": "chessboard:9x6 not found"}
    ]
    # Per-view RMS: 54 corners each, so the overall RMS is their quadratic mean.
    per_view = np.array([v["rms_px"] for v in out["per_view"]])
    assert np.sqrt(np.mean(per_view**2)) == pytest.approx(out["rms_px"], rel=1e-6)
    assert out["outliers"] == [] and 0 < out["coverage"]["fraction"] < 1
    # CAM.yaml: OpenCV's FileStorage reads it, with the same numbers.
    fs = cv2.FileStorage(str(cam), cv2.FILE_STORAGE_READ)
    assert np.allclose(fs.getNode("camera_matrix").mat(), K, rtol=1e-3)
    assert fs.getNode("distortion_coefficients").mat().shape == (1, 5)
    assert (fs.getNode("image_width").real(), fs.getNode("image_height").real()) == (640, 512)
    assert fs.getNode("avg_reprojection_error").real() == pytest.approx(rms, rel=1e-3)
    fs.release()
    assert read_intrinsics(cam).width == 640
    image = cv2.imread(str(plot))
    assert image is not None and image.shape[1] == 800


def test_intrinsics_flags_a_bent_board_as_an_outlier(tmp_path: Path) -> None:
    """A real photo remapped by a sine wave (a bent board): found, but no lens explains it."""
    for p in photo_paths():
        shutil.copy(p, tmp_path / p.name)
    gray = cv2.imread(str(photo_paths()[4]), cv2.IMREAD_GRAYSCALE)
    yy, xx = np.mgrid[0 : gray.shape[0], 0 : gray.shape[1]].astype(np.float32)
    bent = cv2.remap(gray, xx + 6 * np.sin(yy / 25), yy + 6 * np.sin(xx / 30), cv2.INTER_LINEAR)
    cv2.imwrite(str(tmp_path / "zz_bent.png"), bent)
    out = json.loads(
        ovis("intrinsics", str(tmp_path), "--board", "chessboard:9x6", "--json").stdout
    )
    assert out["outliers"] == ["zz_bent.png"] and out["rms_px"] > 1.0
    dropped = json.loads(
        ovis(
            "intrinsics", str(tmp_path), "--board", "chessboard:9x6", "--json", "--drop-outliers"
        ).stdout
    )
    assert dropped["outliers_dropped"] and "zz_bent.png" not in dropped["views_used"]
    rms, _, _ = opencv_calibration(photo_paths())
    assert dropped["rms_px"] == pytest.approx(rms, rel=1e-3)


def test_one_odd_sized_image_is_skipped_not_blamed_on_the_good_photos(tmp_path: Path) -> None:
    """scikit-image's coins photo saved as aaa.png sorts before the 14 board photos: the
    size most images share (640x512) is kept, aaa.png is skipped with one warning naming
    it, and the lens is the 14 photos' (OpenCV's result on them)."""
    from skimage import data

    for p in photo_paths():
        shutil.copy(p, tmp_path / p.name)
    cv2.imwrite(str(tmp_path / "aaa.png"), data.coins())
    proc = ovis("intrinsics", str(tmp_path), "--board", "chessboard:9x6", "--json")
    out = json.loads(proc.stdout)
    warnings = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(warnings) == 1 and warnings[0].startswith("warning: "), proc.stderr
    assert "aaa.png (384x303)" in warnings[0] and "640x512" in warnings[0]
    assert out["views_used"] == [p.name for p in photo_paths()]
    assert [r["view"] for r in out["views_rejected"]] == ["aaa.png"]
    assert "384x303" in out["views_rejected"][0]["reason"]
    assert (out["image_width"], out["image_height"]) == (640, 512)
    rms, K, d = opencv_calibration(photo_paths())
    assert out["rms_px"] == pytest.approx(rms, rel=1e-3)
    assert np.allclose(np.array(out["camera_matrix"]), K, rtol=1e-3)
    assert np.allclose(out["dist"], d, atol=1e-3)


def test_export_reads_cam_yaml(photos_with_blank: Path, tmp_path: Path) -> None:
    cam, ros = tmp_path / "CAM.yaml", tmp_path / "ros.yaml"
    ovis("intrinsics", *map(str, photo_paths()[:6]), "--board", "chessboard:9x6", "--out", str(cam))
    ovis("export", str(cam), "--ros", str(ros))
    import yaml

    info = yaml.safe_load(ros.read_text())
    K = np.array(info["camera_matrix"]["data"]).reshape(3, 3)
    assert np.allclose(K, read_intrinsics(cam).matrix)


def test_intrinsics_bad_input_is_one_line_and_writes_nothing(tmp_path: Path) -> None:
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), without_board(photo_paths()[0]))
    cam = tmp_path / "CAM.yaml"
    proc = ovis(
        "intrinsics", str(blank), "--board", "chessboard:9x6", "--out", str(cam), check=False
    )
    assert_one_line_error(proc, "found in 0 view(s)", "blank.png")
    assert proc.returncode == 2 and not cam.exists()
    # A board of the wrong size is not found either.
    proc = ovis(
        "intrinsics",
        *map(str, photo_paths()[:4]),
        "--board",
        "chessboard:8x6",
        "--out",
        str(cam),
        check=False,
    )
    assert_one_line_error(proc, "chessboard:8x6 found in 0 view(s)")
    for board in ("chess:9x6", "chessboard:9", "charuco:5x5"):
        proc = ovis("intrinsics", str(blank), "--board", board, "--out", str(cam), check=False)
        assert_one_line_error(proc)
        assert proc.returncode == 2 and not cam.exists()


def test_board_specs() -> None:
    spec = parse_board("charuco:7x5:DICT_5X5_100", 3.0, 2.2)
    assert (spec.kind, spec.corner_count, spec.marker) == ("charuco", 24, 2.2)
    with pytest.raises(BoardError, match="marker side"):
        parse_board("charuco:7x5:DICT_5X5_100", 3.0)
    with pytest.raises(BoardError, match="unknown ArUco dictionary"):
        parse_board("charuco:7x5:DICT_9X9_1", 3.0, 2.0)


def test_charuco_board_found_at_its_true_corners() -> None:
    """A ChArUco board drawn by OpenCV and seen through a homography: every corner found
    within 0.3 px of where the homography puts it."""
    from ovis.common.vision.boards import _charuco_board, find_board

    spec = parse_board("charuco:7x5:DICT_5X5_100", 60.0, 44.0)
    board_img = _charuco_board(spec).generateImage((420 + 80, 300 + 80), marginSize=40)
    H = np.array([[0.9, 0.12, 60], [-0.05, 0.95, 40], [1e-4, 2e-4, 1]])
    photo = cv2.warpPerspective(board_img, H, (640, 480), borderValue=255)
    view = find_board(photo, spec)
    assert view is not None and len(view.ids) == 24
    # board unit (60 per square) → board image pixel (1 per unit, + margin)
    src = view.board_xyz[:, :2] + 40 - 0.5
    truth = cv2.perspectiveTransform(src.reshape(-1, 1, 2).astype(np.float64), H).reshape(-1, 2)
    assert np.abs(view.image_xy - truth).max() < 0.3


def test_intrinsics_from_a_source_keeps_distinct_views(tmp_path: Path) -> None:
    """--source reads frames (here a folder of the photos, each twice: a camera repeats
    itself) and keeps only views that differ: OpenCV's 14-view result again."""
    for p in photo_paths():
        for copy in ("a", "b"):
            shutil.copy(p, tmp_path / f"{p.stem}{copy}.jpg")
    out = json.loads(
        ovis(
            "intrinsics",
            "--source",
            str(tmp_path),
            "--board",
            "chessboard:9x6",
            "--max-views",
            "30",
            "--min-shift-px",
            "5",
            "--json",
        ).stdout
    )
    assert len(out["views_used"]) == 14
    rms, K, _ = opencv_calibration(photo_paths())
    assert out["rms_px"] == pytest.approx(rms, rel=1e-3)
    assert np.allclose(np.array(out["camera_matrix"]), K, rtol=1e-3)
