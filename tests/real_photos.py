"""The shared real photos (14 views of a 9×6 chessboard) and OpenCV's own answers on them."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest


def _find_photos() -> Path:
    """``../shared/data/chessboard-9x6`` beside the clone (CI), or beside a folder above it
    (a git worktree one level deeper)."""
    root = Path(__file__).resolve().parents[1]
    for folder in root.parents:
        candidate = folder / "shared" / "data" / "chessboard-9x6"
        if candidate.is_dir():
            return candidate
    return root.parent / "shared" / "data" / "chessboard-9x6"


PHOTOS = _find_photos()
BOARD = (9, 6)
SUBPIX = ((11, 11), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3))


def photo_paths() -> list[Path]:
    """left01..left14.jpg, or skip the test with the reason."""
    files = sorted(PHOTOS.glob("left*.jpg"))
    if len(files) != 14:
        pytest.skip(
            f"the shared real photos are not at {PHOTOS} (CI has ../shared beside the clone)"
        )
    return files


def board_xyz() -> np.ndarray:
    """(54, 3) board coordinates in squares, OpenCV's corner order."""
    obj = np.zeros((54, 3), np.float32)
    obj[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2)
    return obj


def opencv_corners(path: Path, half_window: int = SUBPIX[0][0], blur_px: float = 0.0) -> np.ndarray:
    """The README's recipe: findChessboardCorners + cornerSubPix (its 11-pixel half window,
    or ``half_window``; on the photo smoothed by a Gaussian of ``blur_px`` when > 0),
    (54, 2) x = column."""
    gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    found, c = cv2.findChessboardCorners(gray, BOARD)
    assert found, path
    if blur_px > 0:
        gray = cv2.GaussianBlur(gray, (0, 0), blur_px)
    return cv2.cornerSubPix(gray, c, (half_window, half_window), *SUBPIX[1:]).reshape(-1, 2)


def opencv_calibration(
    paths: list[Path], half_windows: list[int] | None = None, blur_px: float = 0.0
):
    """cv2.calibrateCamera over the views (rms, K, dist), their corners refined as the
    README says (or each in its own half window, on the photo smoothed by ``blur_px``)."""
    windows = half_windows or [SUBPIX[0][0]] * len(paths)
    corners = [
        opencv_corners(p, w, blur_px).reshape(-1, 1, 2) for p, w in zip(paths, windows, strict=True)
    ]
    rms, K, d, _, _ = cv2.calibrateCamera(
        [board_xyz()] * len(paths), corners, (640, 512), None, None
    )
    return rms, K, d.ravel()


def without_board(path: Path) -> np.ndarray:
    """A real photo with the board's region painted over by the photo's median grey."""
    gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    hull = cv2.convexHull(opencv_corners(path)).astype(np.int32)
    mask = np.zeros_like(gray)
    cv2.fillConvexPoly(mask, hull, 255)
    mask = cv2.dilate(mask, np.ones((61, 61), np.uint8))
    out = gray.copy()
    out[mask > 0] = int(np.median(gray))
    return out


def photo_bytes_and_pixels(paths: list[Path] | None = None) -> list[tuple[bytes, np.ndarray]]:
    """The photos (all by default) as their JPEG files' bytes and as OpenCV decodes them
    (grey, as they are)."""
    return [
        (p.read_bytes(), cv2.imread(str(p), cv2.IMREAD_UNCHANGED))
        for p in (photo_paths() if paths is None else paths)
    ]


def photo_calibration(folder: Path, square_cm: float = 2.5) -> tuple[Path, Path]:
    """A calibration of the photos' camera made with the commands docs/real-camera.md
    shows: the lens from the other 13 photos (`ovis intrinsics`), the
    board of the first one as the floor (`ovis calibrate --board`). Written into
    ``folder``: the lens file and the calibration."""
    from cli_helpers import ovis

    paths = photo_paths()
    lens, calib = folder / "CAM.yaml", folder / "calib.json"
    board = ["--board", "chessboard:9x6"]
    ovis("intrinsics", *map(str, paths[1:]), *board, "--out", str(lens))
    ovis("calibrate", str(paths[0]), "--intrinsics", str(lens), *board,
         "--square-cm", str(square_cm), "--out", str(calib))  # fmt: skip
    return lens, calib
