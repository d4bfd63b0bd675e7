"""Pictures for the browser: a frame (or the binarised frame) downscaled and JPEG-encoded,
with what was detected drawn on it by OpenCV.

Drawn on the camera frame: every size-filtered blob (thin yellow circle of its area),
each object with its id (robot green, obstacles orange) and the robot's heading (an
arrow to the projection of a point ahead of it on its top plane), and the calibration's
control points (magenta: + where the blob was detected, o where the calibration projects
the point).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.calibration.file import PointResidual
from ovis.common.camera.projection import project
from ovis.common.config import CameraModel
from ovis.common.messages import BinaryFrame, BlobMeasure
from ovis.common.view.scene import SceneObject

__all__ = ["binary_image", "downscale", "draw_overlay", "to_jpeg"]

ROBOT = (80, 200, 60)  # BGR
OBSTACLE = (0, 150, 255)
BLOB = (0, 230, 230)
POINT = (255, 0, 255)
#: How far ahead of the robot the heading arrow points, cm.
HEADING_CM = 8.0


def downscale(image: NDArray[np.uint8], max_side: int) -> tuple[NDArray[np.uint8], float]:
    """``image`` shrunk (INTER_AREA) so that its longer side is at most ``max_side``, and
    the scale applied (1.0: unchanged; never enlarged)."""
    if max_side < 1:
        raise ValueError(f"max_side must be at least 1, got {max_side}")
    rows, cols = image.shape[:2]
    scale = min(1.0, max_side / max(rows, cols))
    if scale >= 1.0:
        return image, 1.0
    size = (max(1, round(cols * scale)), max(1, round(rows * scale)))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA), scale


def to_jpeg(image: NDArray[np.uint8], quality: int = 80) -> bytes:
    """JPEG bytes of a grey or BGR image (``quality`` 1–100)."""
    if not 1 <= quality <= 100:
        raise ValueError(f"JPEG quality must be 1-100, got {quality}")
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError(f"OpenCV could not encode a {image.shape} {image.dtype} image as JPEG")
    return buf.tobytes()


def binary_image(binary: BinaryFrame) -> NDArray[np.uint8]:
    """The binarised frame as a 0/255 grey image."""
    return binary.mask() * np.uint8(255)


def _pt(row: float, col: float, scale: float) -> tuple[int, int]:
    return round(col * scale), round(row * scale)


def _heading_tip(obj: SceneObject, cam: CameraModel | None) -> tuple[float, float] | None:
    """(row, col) of the point ``HEADING_CM`` ahead of the object on its top plane."""
    if cam is None or obj.heading_deg is None:
        return None
    h = math.radians(obj.heading_deg)
    p = project(
        obj.x_cm + HEADING_CM * math.cos(h), obj.y_cm + HEADING_CM * math.sin(h), obj.z_cm, cam
    )
    if not bool(np.asarray(p.valid)):
        return None
    return float(p.row), float(p.col)


def draw_overlay(
    image: NDArray[np.uint8],
    scale: float,
    *,
    objects: Sequence[SceneObject] = (),
    blobs: Sequence[BlobMeasure] = (),
    points: Sequence[PointResidual] = (),
    camera: CameraModel | None = None,
) -> NDArray[np.uint8]:
    """A BGR copy of ``image`` (already downscaled by ``scale``) with blobs, objects and
    their ids, robot headings and control points drawn on it (image coordinates of the
    full-size frame are multiplied by ``scale``)."""
    out = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    thick = 1 if scale < 0.75 else 2
    for b in blobs:
        radius = max(2, round(math.sqrt(b.area_px / math.pi) * scale))
        cv2.circle(out, _pt(b.row, b.col, scale), radius, BLOB, 1, cv2.LINE_AA)
    for obj in objects:
        if obj.row is None or obj.col is None:
            continue
        colour = ROBOT if obj.kind == "robot" else OBSTACLE
        centre = _pt(obj.row, obj.col, scale)
        cv2.drawMarker(out, centre, colour, cv2.MARKER_CROSS, 10, thick)
        label = ("R" if obj.kind == "robot" else "O") + str(obj.id)
        cv2.putText(
            out,
            label,
            (centre[0] + 6, centre[1] - 6),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.45,
            colour,
            thick,
            cv2.LINE_AA,
        )
        tip = _heading_tip(obj, camera)
        if tip is not None:
            cv2.arrowedLine(out, centre, _pt(*tip, scale), colour, thick, cv2.LINE_AA, 0, 0.3)
    for p in points:
        cv2.drawMarker(
            out, _pt(p.detected_row, p.detected_col, scale), POINT, cv2.MARKER_CROSS, 8, 1
        )
        cv2.circle(out, _pt(p.predicted_row, p.predicted_col, scale), 5, POINT, 1, cv2.LINE_AA)
    return out
