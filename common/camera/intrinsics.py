"""A lens's intrinsics (K and distortion) in OpenCV's calibration file format (CAM.yaml).

The file is what OpenCV's own calibration sample writes and ``cv2.FileStorage`` reads:
``image_width``, ``image_height``, ``camera_matrix`` (3×3), ``distortion_coefficients``
(1×5: k1, k2, p1, p2, k3) and ``avg_reprojection_error`` (px). ovis adds nothing a
reader must know about; extra keys (``rvec``/``tvec`` of ``ovis export``) are ignored.
It is written atomically.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import msgspec
import numpy as np

from ovis.common.atomic import write_atomic
from ovis.common.config import PinholeParams

__all__ = [
    "CameraIntrinsics",
    "IntrinsicsFileError",
    "read_intrinsics",
    "with_pose",
    "write_intrinsics",
]


class IntrinsicsFileError(ValueError):
    """An intrinsics file that cannot be used; the message names the file and the problem."""


class CameraIntrinsics(msgspec.Struct, frozen=True, kw_only=True):
    """K, distortion (OpenCV order) and the image size they belong to."""

    width: int
    height: int
    camera_matrix: tuple[tuple[float, float, float], ...]  # 3×3, x = column, y = row
    dist: tuple[float, ...]  # k1, k2, p1, p2, k3 (longer models are refused)
    rms_px: float | None = None  # calibrateCamera's RMS reprojection error

    @property
    def matrix(self) -> np.ndarray:
        return np.array(self.camera_matrix, dtype=np.float64)

    @property
    def coefficients(self) -> np.ndarray:
        return np.array(self.dist, dtype=np.float64)


def write_intrinsics(path: Path | str, intr: CameraIntrinsics, *, note: str = "") -> None:
    """Write ``intr`` as OpenCV calibration YAML, atomically."""
    fs = cv2.FileStorage(
        ".yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | cv2.FILE_STORAGE_FORMAT_YAML
    )
    fs.writeComment("camera intrinsics (OpenCV calibration format; x = column, y = row)")
    if note:
        fs.writeComment(note)
    fs.write("image_width", int(intr.width))
    fs.write("image_height", int(intr.height))
    fs.write("camera_matrix", intr.matrix)
    fs.write("distortion_coefficients", intr.coefficients[None, :])
    if intr.rms_px is not None:
        fs.write("avg_reprojection_error", float(intr.rms_px))
    text = fs.releaseAndGetString()
    write_atomic(path, (text if text.endswith("\n") else text + "\n").encode("utf-8"))


def read_intrinsics(path: Path | str) -> CameraIntrinsics:
    """Read an OpenCV calibration YAML/XML file (ours, OpenCV's sample's, or ``ovis export``'s)."""
    path = Path(path)
    if not path.is_file():
        raise IntrinsicsFileError(
            f"intrinsics file {path} does not exist; make one with `ovis intrinsics`"
        )
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error:
        fs = None
    if fs is None or not fs.isOpened():
        raise IntrinsicsFileError(f"intrinsics file {path} is not an OpenCV YAML/XML file")
    try:
        K = fs.getNode("camera_matrix").mat()
        D = fs.getNode("distortion_coefficients").mat()
        w, h = fs.getNode("image_width"), fs.getNode("image_height")
        width, height = (int(n.real()) if not n.empty() else 0 for n in (w, h))
        rms_node = fs.getNode("avg_reprojection_error")
        rms = None if rms_node.empty() else float(rms_node.real())
    finally:
        fs.release()
    if K is None or K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise IntrinsicsFileError(
            f"intrinsics file {path}: camera_matrix must be a 3x3 matrix "
            "with positive focal lengths"
        )
    d = np.zeros(5) if D is None else np.asarray(D, np.float64).ravel()
    if d.size > 5 and np.any(d[5:] != 0):
        raise IntrinsicsFileError(
            f"intrinsics file {path}: only 5 distortion coefficients "
            f"(k1, k2, p1, p2, k3) are supported, got {d.size}"
        )
    d = np.concatenate([d, np.zeros(5)])[:5]
    if not np.all(np.isfinite(d)):
        raise IntrinsicsFileError(f"intrinsics file {path}: distortion coefficients must be finite")
    if width < 8 or height < 8:
        raise IntrinsicsFileError(
            f"intrinsics file {path}: image_width and image_height are missing or too small"
        )
    if rms is not None and not math.isfinite(rms):
        rms = None
    return CameraIntrinsics(
        width=width,
        height=height,
        camera_matrix=tuple(tuple(float(v) for v in r) for r in K),
        dist=tuple(float(v) for v in d),
        rms_px=rms,
    )


def with_pose(
    intr: CameraIntrinsics,
    rvec: tuple[float, float, float] = (0.0, 0.0, 0.0),
    tvec_cm: tuple[float, float, float] = (0.0, 0.0, 1.0),
    pixel_pitch_mm: float | None = None,
) -> PinholeParams:
    """An ovis pinhole camera with these intrinsics and a pose (world → camera, cm)."""
    K, d = intr.matrix, intr.coefficients
    return PinholeParams(
        rows=intr.height,
        cols=intr.width,
        fx=float(K[0, 0]),
        fy=float(K[1, 1]),
        cx=float(K[0, 2]),
        cy=float(K[1, 2]),
        k1=float(d[0]),
        k2=float(d[1]),
        p1=float(d[2]),
        p2=float(d[3]),
        k3=float(d[4]),
        rvec=tuple(float(v) for v in rvec),  # type: ignore[arg-type]
        tvec_cm=tuple(float(v) for v in tvec_cm),  # type: ignore[arg-type]
        pixel_pitch_mm=pixel_pitch_mm,
    )
