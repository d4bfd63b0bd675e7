"""A camera for the same lens and pose at another image size (the frame resized).

Resizing an image maps pixel coordinates (pixel centres at whole numbers, as ovis and
OpenCV count them) by ``p' = a·(p + ½) − ½`` on each axis, ``a`` = new size / old size.
Both camera models follow this exactly:

* pinhole: ``fx, fy`` scale by the column and row factors, the principal point maps as
  any pixel; distortion acts on normalised coordinates and does not change; the pixel
  pitch (only for errors in mm) shrinks as the pixels do;
* the paper's model: eqs. 9–10 give ``row = s_x·(N_fx/d_x)·x_d + c_x``: the frame memory
  holds ``N_fx`` pixels a line (the frame's rows, as in the presets), so ``N_fx, N_fy``
  scale and ``c_x, c_y`` map as pixels; the lens, its distortion (on the image plane, in
  mm) and the sensor (``d_x, d_y``, ``s_x, s_y``) are those of the camera and do not.

Only sizes of the same aspect ratio are scaled (to the nearest pixel): another ratio
means the camera crops, which no scale undoes.
"""

from __future__ import annotations

import msgspec

from ovis.common.config import CameraModel, PinholeParams

__all__ = ["same_aspect", "scale_camera", "scale_factors"]


def same_aspect(width: int, height: int, new_width: int, new_height: int) -> bool:
    """Whether ``new_width × new_height`` is ``width × height`` resized: the side of one
    scaled by the other side's factor lands on the nearest pixel."""
    return (
        round(width * new_height / height) == new_width
        or round(height * new_width / width) == new_height
    )


def scale_factors(cam: CameraModel, rows: int, cols: int) -> tuple[float, float]:
    """(row factor, column factor) from the camera's image size to ``rows × cols``."""
    return rows / cam.rows, cols / cam.cols


def _pixel(p: float, factor: float) -> float:
    """A pixel coordinate in the resized image (pixel centres at whole numbers)."""
    return factor * (p + 0.5) - 0.5


def scale_camera(cam: CameraModel, rows: int, cols: int) -> CameraModel:
    """``cam`` for frames resized to ``rows × cols`` (any factors: the caller checks
    the aspect ratio); the projection of every world point moves as the pixels do."""
    a_r, a_c = scale_factors(cam, rows, cols)
    if isinstance(cam, PinholeParams):
        pitch = cam.pixel_pitch_mm
        fields = {
            "fx": cam.fx * a_c,
            "fy": cam.fy * a_r,
            "cx": _pixel(cam.cx, a_c),
            "cy": _pixel(cam.cy, a_r),
            "pixel_pitch_mm": None if pitch is None else pitch / (a_r * a_c) ** 0.5,
        }
    else:
        fields = {
            "N_fx": cam.N_fx * a_r,
            "N_fy": cam.N_fy * a_c,
            "c_x": _pixel(cam.c_x, a_r),
            "c_y": _pixel(cam.c_y, a_c),
        }
    return msgspec.structs.replace(cam, rows=rows, cols=cols, **fields)
