"""Fiducial markers in a grey frame (pixels only): ArUco and AprilTag 36h11 via OpenCV's
``cv2.aruco.ArucoDetector``.

:func:`find_markers` returns each decoded marker's id and its four corners in OpenCV's
order — the printed marker's top-left, top-right, bottom-right, bottom-left — as
(row, col) with sub-pixel refinement. A marker with a corner closer than
:data:`BORDER_MARGIN_PX` to the image border is cut by it (or nearly): its corners are
not trusted, and it is counted in ``partial`` instead. :func:`marker_cells` gives the
printed pattern (for the simulator).
"""

from __future__ import annotations

from functools import cache
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.config import MARKER_DICTIONARIES

__all__ = ["BORDER_MARGIN_PX", "Markers", "find_markers", "marker_cells", "marker_detector"]

#: A marker with a corner nearer than this to the image border is reported as partial.
BORDER_MARGIN_PX = 2.0

_OPENCV_NAMES = {
    "apriltag_36h11": "DICT_APRILTAG_36h11",
    **{f"aruco_{n}x{n}_{k}": f"DICT_{n}X{n}_{k}" for n in (4, 5, 6) for k in (50, 100, 250, 1000)},
}


class Markers(NamedTuple):
    """Markers decoded in one frame: ids (n,), corners (n, 4, 2) as (row, col) in OpenCV's
    corner order, and how many were dropped for touching the image border."""

    ids: NDArray[np.int64]
    corners: NDArray[np.float64]
    partial: int = 0

    @classmethod
    def none(cls) -> Markers:
        return cls(np.zeros(0, dtype=np.int64), np.zeros((0, 4, 2)), 0)


def _dictionary(name: str) -> cv2.aruco.Dictionary:
    if name not in MARKER_DICTIONARIES:
        raise ValueError(
            f"unknown marker dictionary {name!r}; choose one of {', '.join(MARKER_DICTIONARIES)}"
        )
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, _OPENCV_NAMES[name]))


@cache
def marker_detector(name: str) -> cv2.aruco.ArucoDetector:
    """An ``ArucoDetector`` for a dictionary of :data:`MARKER_DICTIONARIES`, with
    sub-pixel corner refinement (one per dictionary, reused)."""
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.cornerRefinementWinSize = 3
    params.cornerRefinementMinAccuracy = 0.01
    params.cornerRefinementMaxIterations = 50
    return cv2.aruco.ArucoDetector(_dictionary(name), params)


def find_markers(gray: NDArray[np.uint8], dictionary: str) -> Markers:
    """Decode every marker of ``dictionary`` in a grey uint8 frame."""
    if gray.dtype != np.uint8 or gray.ndim != 2:
        raise ValueError(f"expected a grey uint8 (H, W) image, got {gray.dtype} {gray.shape}")
    corners, ids, _ = marker_detector(dictionary).detectMarkers(gray)
    if ids is None or not len(ids):
        return Markers.none()
    xy = np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2)  # OpenCV: (x = col, y = row)
    rc = xy[:, :, ::-1].copy()
    rows, cols = gray.shape
    m = BORDER_MARGIN_PX
    inside = (
        (rc[:, :, 0] >= m)
        & (rc[:, :, 0] <= rows - 1 - m)
        & (rc[:, :, 1] >= m)
        & (rc[:, :, 1] <= cols - 1 - m)
    ).all(axis=1)
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    return Markers(ids[inside], rc[inside], int((~inside).sum()))


def marker_cells(dictionary: str, marker_id: int) -> NDArray[np.bool_]:
    """The printed pattern of one marker, black border included: (k, k) bools, True for
    white cells, row 0 at the marker's top edge and column 0 at its left."""
    d = _dictionary(dictionary)
    if not 0 <= marker_id < MARKER_DICTIONARIES[dictionary]:
        raise ValueError(f"{dictionary} has no marker {marker_id}")
    k = d.markerSize + 2
    image = cv2.aruco.generateImageMarker(d, int(marker_id), k, borderBits=1)
    return image > 127
