"""Fiducial markers in a grey frame (pixels only): ArUco and AprilTag 36h11 via OpenCV's
``cv2.aruco.ArucoDetector``.

:func:`find_markers` returns each decoded marker's id and its four corners in OpenCV's
order — the printed marker's top-left, top-right, bottom-right, bottom-left — as
(row, col), refined to sub-pixel on lines fitted to the marker's edges. A marker with a
corner closer than :data:`BORDER_MARGIN_PX` to the image border is cut by it (or
nearly): its corners are not trusted, and it is counted in ``partial`` instead.
:func:`marker_cells` gives the printed pattern (for the simulator).
"""

from __future__ import annotations

from functools import cache
from typing import Any, NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.config import MARKER_DICTIONARIES

__all__ = [
    "BORDER_MARGIN_PX",
    "MEDIAN_MIN_CELL_PX",
    "Markers",
    "find_markers",
    "marker_cells",
    "marker_detector",
    "median_keeps_cells",
]

#: A marker with a corner nearer than this to the image border is reported as partial.
BORDER_MARGIN_PX = 2.0
#: The 3×3 median erodes a marker's cells narrower than this (px) until their bits read
#: wrong (real photos: docs/robots.md, tests/test_markers_real.py).
MEDIAN_MIN_CELL_PX = 5.5

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
def marker_detector(
    name: str, side_px: tuple[float, float] | None = None, image_side: int = 0
) -> cv2.aruco.ArucoDetector:
    """An ``ArucoDetector`` for a dictionary of :data:`MARKER_DICTIONARIES`, with
    corners refined on the marker's edges and the adaptive-threshold windows of
    :data:`_THRESHOLD_WINDOWS` (one per settings,
    reused). ``side_px`` = the (smallest, largest) marker side expected, in pixels, in
    an image whose larger side is ``image_side``: outlines far outside it are not
    examined (most of the detector's time goes to examining candidates)."""
    params = cv2.aruco.DetectorParameters()
    # corners from lines fitted to the marker's edges: several times steadier than
    # OpenCV's corner sub-pixel search on blurred, noisy frames (see docs/robots.md)
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_CONTOUR
    params.adaptiveThreshWinSizeMin, params.adaptiveThreshWinSizeMax = _THRESHOLD_WINDOWS
    params.adaptiveThreshWinSizeStep = _THRESHOLD_WINDOWS[1] - _THRESHOLD_WINDOWS[0]
    if side_px is not None and image_side > 0:
        lo, hi = side_px
        params.minMarkerPerimeterRate = 4.0 * _SIZE_SLACK[0] * lo / image_side
        params.maxMarkerPerimeterRate = 4.0 * _SIZE_SLACK[1] * hi / image_side
    return cv2.aruco.ArucoDetector(_dictionary(name), params)


def median_keeps_cells(dictionary: str, side_px: tuple[float, float] | None) -> bool:
    """Whether the markers' cells survive a 3×3 median: the smallest marker side expected
    (``side_px``, pixels; None: unknown, taken as yes) over its cells, black border
    included, is at least :data:`MEDIAN_MIN_CELL_PX`."""
    if side_px is None:
        return True
    return side_px[0] / _cells(dictionary) >= MEDIAN_MIN_CELL_PX


@cache
def _cells(dictionary: str) -> int:
    """Cells across a marker of ``dictionary``, black border included."""
    return int(_dictionary(dictionary).markerSize) + 2


#: Adaptive-threshold windows (px) of the marker detector: a marker whose dark square
#: is about as wide as the window (a small one seen obliquely) loses its black border
#: in that window's threshold (the local mean is dark there too); the next window,
#: wider, sees the white around it (OpenCV merges the candidates of every window).
_THRESHOLD_WINDOWS = (15, 23)
#: Marker outlines between these multiples of the expected sides are examined.
_SIZE_SLACK = (0.6, 1.5)


def find_markers(
    gray: NDArray[np.uint8],
    dictionary: str,
    *,
    side_px: tuple[float, float] | None = None,
    boxes: NDArray[np.int64] | list[tuple[int, int, int, int]] | None = None,
    median_done: bool = False,
) -> Markers:
    """Decode every marker of ``dictionary`` in a grey uint8 frame.

    ``side_px``: the range of marker sides to look for (pixels); ``boxes``: (k, 4)
    ``row0, row1, col0, col1`` regions to search instead of the whole frame (e.g. around
    the blobs that may carry a marker: much faster). Each region is searched in its 3×3
    median unless the cells are too small for it (:func:`median_keeps_cells`) or
    ``median_done``: ``gray`` is already what to search (the frame's median, which the
    paper's smoothing step makes, or the frame itself for small cells).
    """
    if gray.dtype != np.uint8 or gray.ndim != 2:
        raise ValueError(f"expected a grey uint8 (H, W) image, got {gray.dtype} {gray.shape}")
    rows, cols = gray.shape
    if boxes is None:
        boxes = [(0, rows, 0, cols)]
    elif not isinstance(boxes, list):
        boxes = np.asarray(boxes, dtype=np.int64).reshape(-1, 4).tolist()
    median = not median_done and median_keeps_cells(dictionary, side_px)
    found_ids: list[int] = []
    found_xy: list[Any] = []  # OpenCV's corners, (1, 4, 2) each, x = col, y = row
    origin: list[tuple[int, int]] = []  # the crop's (row, col) in the frame, per marker
    for r0, r1, c0, c1 in boxes:
        r0, c0, r1, c1 = max(r0, 0), max(c0, 0), min(r1, rows), min(c1, cols)
        if r1 - r0 < 8 or c1 - c0 < 8:
            continue
        # a 3×3 median first: a dark speck touching a marker's edge (sensor pepper, dust)
        # otherwise bends its outline out of a quadrilateral and the marker is missed
        crop = gray[r0:r1, c0:c1]
        if median:
            crop = cv2.medianBlur(np.ascontiguousarray(crop), 3)
        detector = marker_detector(dictionary, side_px, max(r1 - r0, c1 - c0))
        corners, ids, _ = detector.detectMarkers(crop)
        if ids is not None:
            found_ids += ids.ravel().tolist()
            found_xy += corners
            origin += [(r0, c0)] * len(corners)
    if not found_ids:
        return Markers.none()
    # a few markers a frame: as few array calls as can be (each costs more than its work)
    xy = np.array(found_xy, dtype=np.float64).reshape(-1, 4, 2)
    rc = xy[:, :, ::-1] + np.array(origin, dtype=np.float64)[:, None, :]
    ids = np.array(found_ids, dtype=np.int64)
    if len(set(found_ids)) < len(found_ids):
        ids, rc = _unique(ids, rc)
    m = BORDER_MARGIN_PX
    inside = [
        min(p) >= m and max(p[0::2]) <= rows - 1 - m and max(p[1::2]) <= cols - 1 - m
        for p in rc.reshape(-1, 8).tolist()
    ]
    if all(inside):
        return Markers(ids, rc, 0)
    keep = np.array(inside, dtype=bool)
    return Markers(ids[keep], rc[keep], len(inside) - int(keep.sum()))


def _unique(
    ids: NDArray[np.int64], rc: NDArray[np.float64]
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Drop a marker found twice (in overlapping boxes): same id, centres within 2 px."""
    centre = rc.mean(axis=1)
    keep = np.ones(ids.size, dtype=bool)
    for k in range(1, ids.size):
        same = (ids[:k] == ids[k]) & keep[:k]
        if same.any() and (np.hypot(*(centre[:k][same] - centre[k]).T) < 2.0).any():
            keep[k] = False
    return ids[keep], rc[keep]


def marker_cells(dictionary: str, marker_id: int) -> NDArray[np.bool_]:
    """The printed pattern of one marker, black border included: (k, k) bools, True for
    white cells, row 0 at the marker's top edge and column 0 at its left."""
    d = _dictionary(dictionary)
    if not 0 <= marker_id < MARKER_DICTIONARIES[dictionary]:
        raise ValueError(f"{dictionary} has no marker {marker_id}")
    k = d.markerSize + 2
    image = cv2.aruco.generateImageMarker(d, int(marker_id), k, borderBits=1)
    return image > 127
