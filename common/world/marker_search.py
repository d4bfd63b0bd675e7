"""Where to look for the robots' markers in a frame, and how big they can be there.

Searching the whole frame costs the marker detector several times what the rest of a
frame's pipeline costs, so :class:`ovis.common.world.detection.Detector` searches only
boxes around the blobs that may carry a marker: a marker's black square is a hole in
its robot's bright top, so such a blob fills less of its own second-moment ellipse
than a solid shape does (:data:`MAX_FILL`), and is at least as large as the smallest
marker. :func:`marker_side_px` gives the range of marker sides in pixels anywhere in the
frame (through the camera, on each robot's marker plane), which also keeps the
detector from examining outlines of other sizes. The search runs on the frame's 3×3
median, which the paper's smoothing step computes anyway, unless the markers' cells are
too small to survive it (:func:`marker_search_image`). The running pipeline does the
same in the label service (:class:`BlobMarkers`), where the blobs are known: the
preprocess service sends it that image with the binary frame.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ovis.common.camera.projection import pixel_footprint_cm2
from ovis.common.config import CameraModel, PoseConfig
from ovis.common.vision.markers import Markers, find_markers, median_keeps_cells

__all__ = [
    "MAX_FILL",
    "BlobMarkers",
    "marker_boxes",
    "marker_search_image",
    "marker_side_px",
    "markers_around",
    "search_markers",
    "top_side_cm",
]

#: A blob filling more than this share of its second-moment ellipse (4π·√det Σ; a
#: solid disk fills 1, a solid rectangle 0.95) has no hole, hence no marker.
MAX_FILL = 0.85
#: A blob whose holes cover this share of the smallest marker's square may carry one.
MIN_HOLE_SHARE = 0.3
#: Box half-size in standard deviations of the blob along its wider image axis, plus px.
_BOX_SIGMAS = 2.4
_BOX_PAD_PX = 6.0
#: Half the diagonal of a square, in sides (a marker seen at any angle fits this far).
_MARKER_HALF = 0.75


def _grid(camera: CameraModel) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A 9×9 grid of pixels over the frame, (row, col)."""
    return np.meshgrid(np.linspace(0, camera.rows - 1, 9), np.linspace(0, camera.cols - 1, 9))


def marker_side_px(pose: PoseConfig, camera: CameraModel) -> tuple[float, float]:
    """(smallest, largest) side of a configured marker in the frame, pixels (sampled on
    a 9×9 grid of the image, on each robot's marker plane)."""
    r, c = _grid(camera)
    lo, hi = np.inf, 0.0
    for robot in pose.robots:
        area = pixel_footprint_cm2(r, c, camera, robot.marker_height_cm)
        cm_per_px = np.sqrt(area[area > 0])
        if cm_per_px.size:
            lo = min(lo, robot.marker_side_cm / float(cm_per_px.max()))
            hi = max(hi, robot.marker_side_cm / float(cm_per_px.min()))
    if not np.isfinite(lo):
        return 1.0, float(max(camera.rows, camera.cols))
    return lo, hi


def top_side_cm(pose: PoseConfig, camera: CameraModel) -> float:
    """The side, in cm on the robot plane (``pose.robot_height_cm``), of a square that
    looks as large as the largest configured marker (a marker mounted above that plane
    looks larger; the ratio sampled on a 9×9 grid of the image): the marker side seen
    at a blob is this over the square root of the blob's pixel footprint on that plane."""
    r, c = _grid(camera)
    top = pixel_footprint_cm2(r, c, camera, pose.robot_height_cm)
    side = 0.0
    for robot in pose.robots:
        area = pixel_footprint_cm2(r, c, camera, robot.marker_height_cm)
        seen = (area > 0) & (top > 0)
        if seen.any():
            ratio = float(np.sqrt(top[seen] / area[seen]).max())
            side = max(side, robot.marker_side_cm * ratio)
    return side


def marker_boxes(
    row: NDArray[np.float64],
    col: NDArray[np.float64],
    area_px: NDArray[np.float64],
    mu_rr: NDArray[np.float64],
    mu_cc: NDArray[np.float64],
    mu_rc: NDArray[np.float64],
    side_px: tuple[float, float],
    top: tuple[float, NDArray[np.float64]] | None = None,
    holes_px: NDArray[np.float64] | None = None,
    extent: NDArray[np.int64] | None = None,
) -> list[tuple[int, int, int, int]]:
    """Boxes ``row0, row1, col0, col1`` around the blobs that may carry a marker.

    ``top``: :func:`top_side_cm` and each blob's pixel footprint on the robot plane
    (cm²), which give the largest marker's side at each blob (else the largest anywhere
    in the frame, ``side_px[1]``). ``holes_px``: each blob's holes (its filled area less
    its own, px²), when known: a blob whose holes are as large as :data:`MIN_HOLE_SHARE`
    of the smallest marker may carry one whatever its fill (a solid seen from the side
    shows its walls too, which fill its ellipse). ``extent``: each blob's bounding box
    (top, left, height, width), when known: the box then reaches to it (walls seen from
    the side move a solid's centroid off its top, where the marker is)."""
    # a frame's ten or so blobs in plain Python (array calls would cost more than the
    # work). fill < MAX_FILL  ⇔  area² < (MAX_FILL·4π)²·det Σ; and the blob's spread
    # along its wider image axis, _BOX_SIGMAS·√var, at least half the smallest marker side
    holed_below = (MAX_FILL * 4.0 * math.pi) ** 2
    least_var = (0.5 * side_px[0] / _BOX_SIGMAS) ** 2
    footprint = top[1].tolist() if top is not None else [0.0] * row.size
    holes = holes_px.tolist() if holes_px is not None else [0.0] * row.size
    least_hole = MIN_HOLE_SHARE * side_px[0] ** 2
    blobs = (row, col, area_px, mu_rr, mu_cc, mu_rc)
    boxes = []
    reach = extent.tolist() if extent is not None else [None] * row.size
    rows = zip(*(b.tolist() for b in blobs), footprint, holes, reach, strict=True)
    for r, c, a, srr, scc, src, area, hole, bbox in rows:
        var = srr if srr >= scc else scc
        holed = a * a < holed_below * (srr * scc - src * src) or hole >= least_hole
        if not (holed and var >= least_var):
            continue
        largest = top[0] / math.sqrt(area) if top is not None and area > 0 else side_px[1]
        # the marker is centred on its robot: a box round the largest marker (half its
        # diagonal, plus room for the refinement) is enough, whatever the robot's size
        h = min(_BOX_SIGMAS * math.sqrt(var), _MARKER_HALF * largest) + _BOX_PAD_PX
        if bbox is not None:
            t, lf, bh, bw = bbox
            pad = int(_BOX_PAD_PX)
            boxes.append((t - pad, t + bh + pad, lf - pad, lf + bw + pad))
            continue
        boxes.append((int(r - h), int(r + h + 1), int(c - h), int(c + h + 1)))
    return boxes


def marker_search_image(
    gray: NDArray[np.uint8],
    median3: NDArray[np.uint8],
    pose: PoseConfig,
    side_px: tuple[float, float],
) -> NDArray[np.uint8]:
    """The image to search the markers in: the frame's 3×3 median (rid of pepper specks
    that bend a marker's outline), or the frame itself when the markers' cells are too
    small to survive the median (:func:`~ovis.common.vision.markers.median_keeps_cells`;
    e.g. 6×6 markers of 30 px on a real photo)."""
    return median3 if median_keeps_cells(pose.marker_dictionary, side_px) else gray


def search_markers(
    gray: NDArray[np.uint8],
    pose: PoseConfig,
    side_px: tuple[float, float],
    boxes: list[tuple[int, int, int, int]] | None = None,
    *,
    median_done: bool = False,
) -> Markers:
    """The configured dictionary's markers in ``gray`` (in ``boxes``, else everywhere;
    ``median_done``: ``gray`` is :func:`marker_search_image` already); none when no
    robot is configured."""
    if not pose.robots:
        return Markers.none()
    return find_markers(
        gray, pose.marker_dictionary, side_px=side_px, boxes=boxes, median_done=median_done
    )


def markers_around(
    image: NDArray[np.uint8],
    blobs: tuple[NDArray[np.float64], ...],
    pose: PoseConfig,
    side_px: tuple[float, float],
    top: tuple[float, NDArray[np.float64]] | None = None,
    solids: bool = False,
) -> Markers:
    """The robots' markers in a frame's :func:`marker_search_image`, searched for only in
    :func:`marker_boxes` around ``blobs`` (a :class:`ovis.common.world.detection.Blobs`:
    row, col, area, perimeter, compactness, second moments). ``top``:
    :func:`top_side_cm` and each blob's pixel footprint on the robot plane (cm²), which
    size its box to the largest marker as seen at that blob instead of where the frame
    magnifies most. ``solids`` (measured heights): blobs are solids with their walls,
    their holes and bounding boxes say where a marker may be (:func:`marker_boxes`)."""
    filled = getattr(blobs, "filled", None) if solids else None
    holes = None if filled is None else filled[:, 0] - blobs[2]
    extent = getattr(blobs, "box", None) if holes is not None else None
    boxes = marker_boxes(*blobs[:3], *blobs[5:8], side_px, top, holes, extent)
    return search_markers(image, pose, side_px, boxes, median_done=True)


class BlobMarkers:
    """:func:`markers_around` for a stage that follows the calibration (the label
    service): the marker sizes are worked out once per calibration version."""

    def __init__(self) -> None:
        self._version: int | None = None
        self._side_px = (1.0, 1.0)
        self._top_side_cm = 0.0

    def __call__(
        self,
        image: NDArray[np.uint8],
        blobs: tuple[NDArray[np.float64], ...],
        version: int,
        camera: CameraModel,
        pose: PoseConfig,
        top_area_cm2: NDArray[np.float64] | None = None,
    ) -> Markers:
        """The frame's markers in its :meth:`search_image` (none when no robot is
        configured)."""
        if not pose.robots:
            return Markers.none()
        side_px, top_cm = self.sizes(version, camera, pose)
        top = None if top_area_cm2 is None else (top_cm, top_area_cm2)
        return markers_around(image, blobs, pose, side_px, top, pose.heights == "measured")

    def search_image(
        self,
        gray: NDArray[np.uint8],
        median3: NDArray[np.uint8],
        version: int,
        camera: CameraModel,
        pose: PoseConfig,
    ) -> NDArray[np.uint8]:
        """:func:`marker_search_image` with calibration ``version``'s marker sizes."""
        return marker_search_image(gray, median3, pose, self.sizes(version, camera, pose)[0])

    def sizes(
        self, version: int, camera: CameraModel, pose: PoseConfig
    ) -> tuple[tuple[float, float], float]:
        """:func:`marker_side_px` and :func:`top_side_cm` of calibration ``version``
        (worked out on its first call: call it when the calibration comes, so that no
        frame waits for it)."""
        if version != self._version:
            side_px, top_cm = marker_side_px(pose, camera), top_side_cm(pose, camera)
            self._side_px, self._top_side_cm, self._version = side_px, top_cm, version
        return self._side_px, self._top_side_cm
