"""Pictures for the browser: a frame (or the binarised frame) downscaled and JPEG-encoded,
with what was detected drawn on it by OpenCV.

Drawn on the camera frame: every size-filtered blob (thin yellow circle of its area),
each object with its label (robot green, obstacles orange) where the camera saw it, or
for a marked robot (whose message has no pixel) where the calibration projects it, each
robot's heading (an arrow to the projection of a point ahead of it on its top plane),
and, on the calibration's own frame only, its control points (magenta: + where the blob
was detected, o where the calibration projects the point).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence

import cv2
import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.calibration.file import Calibration, PointResidual
from ovis.common.camera.projection import project
from ovis.common.config import CameraModel
from ovis.common.messages import BinaryFrame, BlobMeasure
from ovis.common.view.scene import SceneObject, object_label

__all__ = [
    "Mark",
    "binary_image",
    "calibration_frame",
    "control_points",
    "downscale",
    "draw_overlay",
    "object_marks",
    "to_jpeg",
]

ROBOT = (80, 200, 60)  # BGR
OBSTACLE = (0, 150, 255)
BLOB = (0, 230, 230)
POINT = (255, 0, 255)
#: How far ahead of the robot the heading arrow points, cm.
HEADING_CM = 8.0

_FRAME_SOURCE = re.compile(r"^frame (\d+)$")


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


class Mark(msgspec.Struct, kw_only=True):
    """Where an object goes on the full-size frame (row, col) with its label, and the tip
    of its heading arrow (None: no heading, or it does not project)."""

    label: str
    kind: str
    row: float
    col: float
    tip: tuple[float, float] | None = None


def _image_point(x: float, y: float, z: float, cam: CameraModel) -> tuple[float, float] | None:
    p = project(x, y, z, cam)
    if not bool(np.asarray(p.valid)):
        return None
    return float(p.row), float(p.col)


def object_marks(objects: Sequence[SceneObject], camera: CameraModel | None) -> list[Mark]:
    """Each object's place on the frame: the pixel it was measured at, else (a marked
    robot: its message carries no pixel) the projection of its floor position by
    ``camera``; robots get the tip of their heading arrow, ``HEADING_CM`` ahead on their
    top plane. Objects that cannot be placed (no pixel, no camera) are left out."""
    marks = []
    for obj in objects:
        if obj.row is not None and obj.col is not None:
            at: tuple[float, float] | None = (obj.row, obj.col)
        else:
            at = None if camera is None else _image_point(obj.x_cm, obj.y_cm, obj.z_cm, camera)
        if at is None:
            continue
        tip = None
        if camera is not None and obj.kind == "robot" and obj.heading_deg is not None:
            h = math.radians(obj.heading_deg)
            tip = _image_point(
                obj.x_cm + HEADING_CM * math.cos(h),
                obj.y_cm + HEADING_CM * math.sin(h),
                obj.z_cm,
                camera,
            )
        marks.append(Mark(label=object_label(obj), kind=obj.kind, row=at[0], col=at[1], tip=tip))
    return marks


def calibration_frame(calib: Calibration | None) -> int | None:
    """The sequence number of the frame ``calib`` was made on (the calibrator names it
    "frame N"), None when it was made from a file or is not a calibration."""
    if calib is None or calib.version < 1:
        return None
    m = _FRAME_SOURCE.match(calib.source_image)
    return int(m[1]) if m else None


def control_points(calib: Calibration | None, seq: int) -> list[PointResidual]:
    """The control points to draw on frame ``seq``: the calibration's, on the frame it
    was made on only (elsewhere the blobs it matched are not where they were)."""
    if calib is None or calibration_frame(calib) != seq:
        return []
    return list(calib.points)


def draw_overlay(
    image: NDArray[np.uint8],
    scale: float,
    *,
    marks: Sequence[Mark] = (),
    blobs: Sequence[BlobMeasure] = (),
    points: Sequence[PointResidual] = (),
) -> NDArray[np.uint8]:
    """A BGR copy of ``image`` (already downscaled by ``scale``) with blobs, control
    points, and objects with their labels and robot headings drawn on it (image
    coordinates of the full-size frame are multiplied by ``scale``)."""
    out = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    thick = 1 if scale < 0.75 else 2
    for b in blobs:
        radius = max(2, round(math.sqrt(b.area_px / math.pi) * scale))
        cv2.circle(out, _pt(b.row, b.col, scale), radius, BLOB, 1, cv2.LINE_AA)
    for p in points:
        cv2.drawMarker(
            out, _pt(p.detected_row, p.detected_col, scale), POINT, cv2.MARKER_CROSS, 8, 1
        )
        cv2.circle(out, _pt(p.predicted_row, p.predicted_col, scale), 5, POINT, 1, cv2.LINE_AA)
    for mark in marks:  # on top: the robots and their labels stay readable
        colour = ROBOT if mark.kind == "robot" else OBSTACLE
        centre = _pt(mark.row, mark.col, scale)
        cv2.drawMarker(out, centre, colour, cv2.MARKER_CROSS, 10, thick)
        cv2.putText(
            out,
            mark.label,
            (centre[0] + 6, centre[1] - 6),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.45,
            colour,
            thick,
            cv2.LINE_AA,
        )
        if mark.tip is not None:
            tip = _pt(*mark.tip, scale)
            cv2.arrowedLine(out, centre, tip, colour, thick, cv2.LINE_AA, 0, 0.3)
    return out
