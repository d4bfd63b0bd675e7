"""Calibration boards and ArUco markers found in a photo, with OpenCV's own detectors.

Two boards, named as on the command line:

* ``chessboard:COLSxROWS`` — a chessboard with COLS × ROWS *inner* corners, found by
  ``cv2.findChessboardCorners`` and refined by ``cv2.cornerSubPix`` (window 11×11,
  30 iterations or 1e-3 px, OpenCV's calibration tutorial);
* ``charuco:COLSxROWS:DICT`` — a ChArUco board of COLS × ROWS *squares* whose markers come
  from the ArUco dictionary DICT (e.g. ``DICT_5X5_100``), found by
  ``cv2.aruco.CharucoDetector`` (its corners are sub-pixel already).

Board coordinates: the first inner corner is the origin, x runs along the first row
(OpenCV's corner order), y along the columns, z = 0, in the board's length unit (one
square = ``square``). Pixel positions are OpenCV's (x = column, y = row).
"""

from __future__ import annotations

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
    "find_board",
    "find_markers",
    "parse_board",
]

#: cornerSubPix settings of OpenCV's calibration tutorial (and of the shared photos' README).
SUBPIX_WINDOW = (11, 11)
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

    def describe(self) -> str:
        if self.kind == "chessboard":
            return f"chessboard:{self.cols}x{self.rows}"
        return f"charuco:{self.cols}x{self.rows}:{self.dictionary}"


class BoardView(NamedTuple):
    """A board found in one image: corners in pixels and on the board."""

    image_xy: NDArray[np.float32]  # (N, 2) OpenCV x = column, y = row
    board_xyz: NDArray[np.float32]  # (N, 3) board coordinates, z = 0
    ids: NDArray[np.int32]  # (N,) corner index on the board (row-major)


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


def find_board(gray: NDArray[np.uint8], spec: BoardSpec) -> BoardView | None:
    """The board's corners in ``gray``, or None when the board is not found."""
    if spec.kind == "chessboard":
        size = (spec.cols, spec.rows)
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH + cv2.CALIB_CB_NORMALIZE_IMAGE
        found, corners = cv2.findChessboardCorners(gray, size, flags=flags)
        if not found:
            return None
        corners = cv2.cornerSubPix(gray, corners, SUBPIX_WINDOW, (-1, -1), SUBPIX_CRITERIA)
        ids = np.arange(spec.corner_count, dtype=np.int32)
        return BoardView(corners.reshape(-1, 2), board_points(spec), ids)
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
