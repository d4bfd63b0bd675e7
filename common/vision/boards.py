"""Calibration boards and ArUco markers found in a photo, with OpenCV's own detectors.

Two boards, named as on the command line:

* ``chessboard:COLSxROWS`` — a chessboard with COLS × ROWS *inner* corners, found by
  ``cv2.findChessboardCorners`` and refined by ``cv2.cornerSubPix`` (30 iterations or
  1e-3 px, OpenCV's calibration tutorial) in a window that fits the squares of the view
  (:func:`subpix_window`), on the image slightly smoothed (:data:`SUBPIX_BLUR_PX`);
* ``charuco:COLSxROWS:DICT`` — a ChArUco board of COLS × ROWS *squares* whose markers come
  from the ArUco dictionary DICT (e.g. ``DICT_5X5_100``), found by
  ``cv2.aruco.CharucoDetector`` (its corners are sub-pixel already).

Board coordinates: the first inner corner is the origin, x runs along the first row
(OpenCV's corner order), y along the columns, z = 0, in the board's length unit (one
square = ``square``); z = x × y points into the board, away from the camera. Pixel
positions are OpenCV's (x = column, y = row).

A chessboard's corner order is made the printed board's own (:func:`board_order`):
seen from its printed face, its rows of COLS corners run left to right, the first row on
top, and — when COLS + ROWS is odd, so that a half turn swaps the colours — the square
diagonally beyond the first corner (the board's top-left corner square) is black. A board
with COLS + ROWS even looks the same turned half-way round: its first corner is one of
two, whichever the view makes it (:attr:`BoardSpec.oriented`).
"""

from __future__ import annotations

import math
import re
from typing import Literal, NamedTuple

import cv2
import msgspec
import numpy as np
from numpy.typing import NDArray

__all__ = [
    "BoardError",
    "BoardSpec",
    "BoardView",
    "MarkerView",
    "aruco_dictionary",
    "board_order",
    "board_points",
    "corner_spacing",
    "find_board",
    "find_markers",
    "parse_board",
    "subpix_window",
]

#: Bounds of cornerSubPix's half window (px; the window is 2·half + 1 wide). The upper one
#: is OpenCV's calibration tutorial's (and the shared photos' README's) fixed window.
SUBPIX_HALF_WINDOW = (2, 11)
#: cornerSubPix's half window as a share of the view's shortest corner spacing: a window
#: that reaches the edges of the neighbouring corners (from about 0.7 of a square on a
#: board turned 45° in the image) pulls the corner towards them; OpenCV advises about
#: half a square or less.
SUBPIX_WINDOW_SHARE = 0.5
#: Gaussian smoothing (σ, px) of the image cornerSubPix refines in: on a sharp image the
#: refined corner is drawn towards the middle of its pixel (pixel locking: each edge falls
#: on too few pixels for its gradient); a symmetric blur spreads the edges without moving
#: the corner. Chosen on the shared real photos, each held out (see tests/test_intrinsics.py).
SUBPIX_BLUR_PX = 0.5
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)
#: A ChArUco view needs this many corners to take part in a calibration or a pose.
MIN_CHARUCO_CORNERS = 6

_BOARD_RE = re.compile(r"^(chessboard|charuco):(\d+)x(\d+)(?::(DICT_\w+))?$")


class BoardError(ValueError):
    """A board description that cannot be used; the message says the expected form."""


class BoardSpec(msgspec.Struct, frozen=True, kw_only=True):
    """A calibration board: kind, size, square (and marker) side in the board's unit."""

    kind: Literal["chessboard", "charuco"]
    cols: int  # chessboard: inner corners per row; charuco: squares per row
    rows: int
    square: float = 1.0
    marker: float | None = None  # charuco only
    dictionary: str | None = None  # charuco only, e.g. "DICT_5X5_100"

    @property
    def corner_count(self) -> int:
        """Inner corners of the whole board."""
        if self.kind == "chessboard":
            return self.cols * self.rows
        return (self.cols - 1) * (self.rows - 1)

    @property
    def oriented(self) -> bool:
        """Whether the printed board fixes its own origin corner: a ChArUco board always
        (its markers), a chessboard when COLS + ROWS is odd (a half turn swaps its colours)."""
        return self.kind == "charuco" or (self.cols + self.rows) % 2 == 1

    def describe(self) -> str:
        if self.kind == "chessboard":
            return f"chessboard:{self.cols}x{self.rows}"
        return f"charuco:{self.cols}x{self.rows}:{self.dictionary}"


class BoardView(NamedTuple):
    """A board found in one image: corners in pixels and on the board."""

    image_xy: NDArray[np.float32]  # (N, 2) OpenCV x = column, y = row
    board_xyz: NDArray[np.float32]  # (N, 3) board coordinates, z = 0
    ids: NDArray[np.int32]  # (N,) corner index on the board (row-major)
    #: cornerSubPix's half window (px) for a chessboard; None for ChArUco (its detector
    #: refines its own corners)
    window_px: int | None = None


class MarkerView(NamedTuple):
    """ArUco markers found in one image."""

    ids: NDArray[np.int32]  # (M,)
    corners_xy: NDArray[np.float32]  # (M, 4, 2) OpenCV order: top-left, TR, BR, BL


def aruco_dictionary(name: str) -> cv2.aruco.Dictionary:
    """The predefined ArUco dictionary called ``name`` (e.g. ``DICT_4X4_50``)."""
    code = getattr(cv2.aruco, name, None) if name.startswith("DICT_") else None
    if not isinstance(code, int):
        known = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
        raise BoardError(f"unknown ArUco dictionary {name!r}; choose one of {', '.join(known)}")
    return cv2.aruco.getPredefinedDictionary(code)


def parse_board(text: str, square: float = 1.0, marker: float | None = None) -> BoardSpec:
    """Parse ``chessboard:COLSxROWS`` or ``charuco:COLSxROWS:DICT`` (see module docstring)."""
    m = _BOARD_RE.match(text.strip())
    if m is None:
        raise BoardError(
            f"board {text!r} is not chessboard:COLSxROWS (inner corners, e.g. chessboard:9x6) "
            "or charuco:COLSxROWS:DICT (squares, e.g. charuco:7x5:DICT_5X5_100)"
        )
    kind, cols, rows, dictionary = m.group(1), int(m.group(2)), int(m.group(3)), m.group(4)
    if not (np.isfinite(square) and square > 0):
        raise BoardError(f"the square size must be a positive length, got {square}")
    if kind == "chessboard":
        if dictionary is not None:
            raise BoardError("a chessboard has no ArUco dictionary; drop the ':DICT' part")
        if min(cols, rows) < 3:
            raise BoardError(f"a chessboard needs at least 3x3 inner corners, got {cols}x{rows}")
        return BoardSpec(kind="chessboard", cols=cols, rows=rows, square=square)
    if dictionary is None:
        raise BoardError("a ChArUco board needs its dictionary, as in charuco:7x5:DICT_5X5_100")
    aruco_dictionary(dictionary)
    if min(cols, rows) < 3:
        raise BoardError(f"a ChArUco board needs at least 3x3 squares, got {cols}x{rows}")
    if marker is None or not (np.isfinite(marker) and 0 < marker < square):
        raise BoardError(
            f"a ChArUco board needs the marker side (--marker-cm), smaller than the square "
            f"({square:g}), got {marker}"
        )
    return BoardSpec(
        kind="charuco", cols=cols, rows=rows, square=square, marker=marker, dictionary=dictionary
    )


def _charuco_board(spec: BoardSpec) -> cv2.aruco.CharucoBoard:
    return cv2.aruco.CharucoBoard(
        (spec.cols, spec.rows), spec.square, spec.marker, aruco_dictionary(spec.dictionary or "")
    )


def board_points(spec: BoardSpec) -> NDArray[np.float32]:
    """(N, 3) board coordinates of every inner corner, in OpenCV's corner order."""
    if spec.kind == "charuco":
        return np.asarray(_charuco_board(spec).getChessboardCorners(), np.float32).reshape(-1, 3)
    grid = np.mgrid[0 : spec.cols, 0 : spec.rows].T.reshape(-1, 2)
    out = np.zeros((grid.shape[0], 3), np.float32)
    out[:, :2] = grid * spec.square
    return out


def corner_spacing(grid: NDArray[np.floating]) -> float:
    """The shortest distance (px) between neighbouring corners of a (rows, cols, 2) grid,
    along its rows and its columns: the smallest square of the view."""
    along = np.linalg.norm(np.diff(grid, axis=1), axis=2)
    across = np.linalg.norm(np.diff(grid, axis=0), axis=2)
    return float(min(along.min(), across.min()))


def subpix_window(spacing_px: float) -> int:
    """cornerSubPix's half window (px) for a view whose smallest square is ``spacing_px``
    wide: :data:`SUBPIX_WINDOW_SHARE` of it, within :data:`SUBPIX_HALF_WINDOW`."""
    low, high = SUBPIX_HALF_WINDOW
    return int(np.clip(math.floor(SUBPIX_WINDOW_SHARE * spacing_px), low, high))


def board_order(gray: NDArray[np.uint8], grid: NDArray[np.float32]) -> NDArray[np.float32]:
    """A chessboard's (rows, cols, 2) corner grid in the printed board's own order (module
    docstring): the rows reversed when the board's z (along a row × along the columns)
    would point towards the camera, then the whole grid turned half-way round when the
    squares coloured as the one diagonally beyond the first corner are the light ones
    (COLS + ROWS odd only: otherwise a half turn shows the same colours)."""
    rows, cols = grid.shape[:2]
    along = (grid[:, -1] - grid[:, 0]).mean(axis=0)
    across = (grid[-1] - grid[0]).mean(axis=0)
    if along[0] * across[1] - along[1] * across[0] < 0:  # image x right, y down
        grid = grid[::-1]
    if (rows + cols) % 2 == 1:
        centres = (grid[:-1, :-1] + grid[1:, :-1] + grid[:-1, 1:] + grid[1:, 1:]) / 4.0
        level = cv2.remap(
            gray.astype(np.float32),
            np.ascontiguousarray(centres[..., 0], np.float32),
            np.ascontiguousarray(centres[..., 1], np.float32),
            cv2.INTER_LINEAR,
        )
        i, j = np.meshgrid(np.arange(cols - 1), np.arange(rows - 1))
        like_first = (i + j) % 2 == 0  # coloured as the square beyond the first corner
        if level[like_first].mean() > level[~like_first].mean():
            grid = grid[::-1, ::-1]
    return np.ascontiguousarray(grid)


def find_board(gray: NDArray[np.uint8], spec: BoardSpec) -> BoardView | None:
    """The board's corners in ``gray``, or None when the board is not found."""
    if spec.kind == "chessboard":
        size = (spec.cols, spec.rows)
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH + cv2.CALIB_CB_NORMALIZE_IMAGE
        found, corners = cv2.findChessboardCorners(gray, size, flags=flags)
        if not found:
            return None
        grid = board_order(gray, corners.reshape(spec.rows, spec.cols, 2))
        half = subpix_window(corner_spacing(grid))
        smooth = cv2.GaussianBlur(gray, (0, 0), SUBPIX_BLUR_PX)
        corners = cv2.cornerSubPix(
            smooth, grid.reshape(-1, 1, 2), (half, half), (-1, -1), SUBPIX_CRITERIA
        )
        ids = np.arange(spec.corner_count, dtype=np.int32)
        return BoardView(corners.reshape(-1, 2), board_points(spec), ids, half)
    board = _charuco_board(spec)
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(gray)
    if ids is None or len(ids) < MIN_CHARUCO_CORNERS:
        return None
    ids = ids.reshape(-1).astype(np.int32)
    return BoardView(corners.reshape(-1, 2).astype(np.float32), board_points(spec)[ids], ids)


def find_markers(gray: NDArray[np.uint8], dictionary: str) -> MarkerView:
    """Every ArUco marker of ``dictionary`` in ``gray`` (``cv2.aruco.ArucoDetector``,
    sub-pixel corner refinement)."""
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), params)
    corners, ids, _ = detector.detectMarkers(gray)
    if ids is None:
        return MarkerView(np.zeros(0, np.int32), np.zeros((0, 4, 2), np.float32))
    return MarkerView(
        ids.reshape(-1).astype(np.int32), np.asarray(corners, np.float32).reshape(-1, 4, 2)
    )
