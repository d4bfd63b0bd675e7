"""Where to look for the robots' markers in a frame, and how big they can be there.

Searching the whole frame costs the marker detector several times what the rest of a
frame's pipeline costs, so :class:`ovis.common.world.detection.Detector` searches only
boxes around the blobs that may carry a marker: a marker's black square is a hole in
its robot's bright top, so such a blob fills less of its own second-moment ellipse
than a solid shape does (:data:`MAX_FILL`), and is at least as large as the smallest
marker. :func:`marker_side_px` gives the range of marker sides in pixels anywhere in the
frame (through the camera, on each robot's marker plane), which also keeps the
detector from examining outlines of other sizes.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ovis.common.camera.projection import pixel_footprint_cm2
from ovis.common.config import CameraModel, PoseConfig
from ovis.common.vision.markers import Markers, find_markers

__all__ = ["MAX_FILL", "FrameMarkers", "marker_boxes", "marker_side_px", "search_markers"]

#: A blob filling more than this share of its second-moment ellipse (4π·√det Σ; a
#: solid disk fills 1, a solid rectangle 0.95) has no hole, hence no marker.
MAX_FILL = 0.85
#: Box half-size in standard deviations of the blob along its wider image axis, plus px.
_BOX_SIGMAS = 2.4
_BOX_PAD_PX = 6.0
#: Half the diagonal of a square, in sides (a marker seen at any angle fits this far).
_MARKER_HALF = 0.75


def marker_side_px(pose: PoseConfig, camera: CameraModel) -> tuple[float, float]:
    """(smallest, largest) side of a configured marker in the frame, pixels (sampled on
    a 9×9 grid of the image, on each robot's marker plane)."""
    r, c = np.meshgrid(np.linspace(0, camera.rows - 1, 9), np.linspace(0, camera.cols - 1, 9))
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


def marker_boxes(
    row: NDArray[np.float64],
    col: NDArray[np.float64],
    area_px: NDArray[np.float64],
    mu_rr: NDArray[np.float64],
    mu_cc: NDArray[np.float64],
    mu_rc: NDArray[np.float64],
    side_px: tuple[float, float],
) -> NDArray[np.int64]:
    """Boxes ``(k, 4)`` = row0, row1, col0, col1 around the blobs that may carry a marker."""
    # fill < MAX_FILL  ⇔  area² < (MAX_FILL·4π)²·det Σ (no square root, no division)
    det = mu_rr * mu_cc - mu_rc * mu_rc
    spread = _BOX_SIGMAS * np.sqrt(np.maximum(mu_rr, mu_cc))
    pick = (area_px * area_px < (MAX_FILL * 4.0 * np.pi) ** 2 * det) & (
        spread >= 0.5 * side_px[0]
    )
    # the marker is centred on its robot: a box round the largest marker (half its
    # diagonal, plus room for the refinement) is enough, whatever the robot's size
    r, c, s = row[pick], col[pick], spread[pick]
    h = np.minimum(s, _MARKER_HALF * side_px[1]) + _BOX_PAD_PX
    return np.column_stack([r - h, r + h + 1, c - h, c + h + 1]).astype(np.int64)


def search_markers(
    gray: NDArray[np.uint8],
    pose: PoseConfig,
    side_px: tuple[float, float],
    boxes: NDArray[np.int64] | None = None,
    *,
    median_done: bool = False,
) -> Markers:
    """The configured dictionary's markers in ``gray`` (in ``boxes``, else everywhere;
    ``median_done``: ``gray`` is the frame's 3×3 median already); none when no robot is
    configured."""
    if not pose.robots:
        return Markers.none()
    return find_markers(
        gray, pose.marker_dictionary, side_px=side_px, boxes=boxes, median_done=median_done
    )


class FrameMarkers:
    """Whole-frame marker search for a stage that has the grey frame but no blobs yet
    (the preprocess service): the marker sizes are worked out once per calibration."""

    def __init__(self) -> None:
        self._version: int | None = None
        self._side_px = (1.0, 1.0)

    def __call__(
        self, gray: NDArray[np.uint8], version: int, camera: CameraModel, pose: PoseConfig
    ) -> Markers | None:
        """The frame's markers, or None when no robot is configured."""
        if not pose.robots:
            return None
        if version != self._version:
            self._version, self._side_px = version, marker_side_px(pose, camera)
        return search_markers(gray, pose, self._side_px)
