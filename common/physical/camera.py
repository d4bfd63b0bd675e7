"""A calibrated camera as MuJoCo renders it: the same pixels ovis's own model projects to.

MuJoCo renders an ideal pinhole: its camera takes a focal length and a principal point
in pixels (``focal_pixel``, ``principal_pixel``; the principal point is given as the
offset of the image centre ``((W − 1)/2, (H − 1)/2)`` from it, pixel centres at
integers as in OpenCV) and looks along its −z axis with +y up, where OpenCV's camera
looks along +z with +y down. So an OpenCV pose ``(R, t)`` (world → camera) becomes a
MuJoCo camera at ``C = −Rᵀ·t`` whose axes in the world are ``(R₀, −R₁, −R₂)`` (the rows
of R).

What an ideal pinhole cannot show is rendered on a larger canvas and resampled
(:class:`RenderCamera`, ``lens_map``): lens distortion (Brown–Conrady, through
:func:`ovis.common.camera.pinhole.undistort_normalised`, so every output pixel shows
exactly the ray ovis's model gives it) and a negative focal length (the paper model's
pinhole equivalent images the world mirror-inverted, :mod:`ovis.common.camera.export`).
A paper-model camera is rendered as that equivalent (its distortion fitted, the
residual said by :attr:`RenderCamera.model_residual_px`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.camera import pinhole
from ovis.common.camera.export import as_pinhole
from ovis.common.config import CameraModel, PinholeParams

__all__ = ["CM_PER_M", "RenderCamera", "render_camera"]

#: MuJoCo's world unit is the metre; ovis's is the centimetre.
CM_PER_M = 100.0

#: Canvas pixels kept beyond the rays the output needs (bilinear resampling reads 2×2).
CANVAS_MARGIN_PX = 4


class RenderCamera(NamedTuple):
    """Where MuJoCo's camera stands and what it renders, for one calibrated camera.

    ``pos_m``/``quat``: the MuJoCo camera's position (m) and orientation (w, x, y, z);
    ``focal_px``/``principal_px``: its intrinsics as MuJoCo takes them; ``canvas``:
    (width, height) it renders; ``lens_map``: (map_x, map_y) float32 for
    :func:`cv2.remap` from the canvas to the camera's frame of ``out_size`` (None: the
    canvas is the frame); ``model_residual_px``: how far the rendered camera is from the
    calibrated one's own projection (0 for a pinhole camera).
    """

    pos_m: NDArray[np.float64]
    quat: NDArray[np.float64]
    focal_px: tuple[float, float]
    principal_px: tuple[float, float]
    canvas: tuple[int, int]
    lens_map: tuple[NDArray[np.float32], NDArray[np.float32]] | None
    out_size: tuple[int, int]
    model_residual_px: float

    def finish(self, canvas: NDArray, interpolation: int = cv2.INTER_LINEAR) -> NDArray:
        """The camera's frame from a rendered canvas (resampled through the lens; labels,
        such as a segmentation's, with ``cv2.INTER_NEAREST``)."""
        if self.lens_map is None:
            return canvas
        return cv2.remap(
            canvas, self.lens_map[0], self.lens_map[1], interpolation, cv2.BORDER_REPLICATE
        )


def _mujoco_quat(R: NDArray[np.float64]) -> NDArray[np.float64]:
    """MuJoCo camera orientation (w, x, y, z) for an OpenCV world → camera rotation."""
    frame = np.stack([R[0], -R[1], -R[2]], axis=1)  # columns: the camera's axes in the world
    w = math.sqrt(max(0.0, 1.0 + np.trace(frame))) / 2.0
    if w > 1e-6:
        return np.array(
            [
                w,
                (frame[2, 1] - frame[1, 2]) / (4 * w),
                (frame[0, 2] - frame[2, 0]) / (4 * w),
                (frame[1, 0] - frame[0, 1]) / (4 * w),
            ]
        )
    # a half turn: the axis from the largest diagonal element
    k = int(np.argmax(np.diag(frame)))
    i, j = (k + 1) % 3, (k + 2) % 3
    s = math.sqrt(max(0.0, 1.0 + frame[k, k] - frame[i, i] - frame[j, j])) * 2.0
    q = np.zeros(4)
    q[0] = (frame[j, i] - frame[i, j]) / s
    q[1 + k] = s / 4.0
    q[1 + i] = (frame[i, k] + frame[k, i]) / s
    q[1 + j] = (frame[j, k] + frame[k, j]) / s
    return q


def _ideal(cam: PinholeParams) -> bool:
    """A camera MuJoCo renders as it is: no distortion, positive focal lengths."""
    lens = (cam.k1, cam.k2, cam.p1, cam.p2, cam.k3)
    return all(float(v) == 0.0 for v in lens) and float(cam.fx) > 0 and float(cam.fy) > 0


def render_camera(camera: CameraModel) -> RenderCamera:
    """The MuJoCo camera (and lens resampling) that renders what ``camera`` sees.

    Raises ValueError when some pixel of the frame has no ray (a distortion that is not
    one-to-one over the frame).
    """
    eq = as_pinhole(camera)
    cam = eq.camera
    R = pinhole.rodrigues(np.asarray(cam.rvec, dtype=np.float64))
    centre_cm = -R.T @ np.asarray(cam.tvec_cm, dtype=np.float64)
    W, H = int(cam.cols), int(cam.rows)
    fx, fy = abs(float(cam.fx)), abs(float(cam.fy))
    pos, quat = centre_cm / CM_PER_M, _mujoco_quat(R)
    if _ideal(cam):
        principal = ((W - 1) / 2.0 - float(cam.cx), (H - 1) / 2.0 - float(cam.cy))
        return RenderCamera(pos, quat, (fx, fy), principal, (W, H), None, (W, H), eq.max_px)
    # Every output pixel's ray, as normalised (x', y') of the OpenCV camera frame.
    rows, cols = np.mgrid[0:H, 0:W].astype(np.float64)
    und = pinhole.undistort_normalised(rows, cols, cam)
    if not und.valid.all():
        raise ValueError(
            f"the camera's distortion (k1 {cam.k1}, k2 {cam.k2}, k3 {cam.k3}) is not "
            "one-to-one over its frame: some pixels see no ray, so it cannot be rendered"
        )
    u, v = fx * und.x, fy * und.y  # canvas pixels, before the principal point
    m = CANVAS_MARGIN_PX
    cxc, cyc = m - float(u.min()), m - float(v.min())
    Wc = math.ceil(float(u.max()) + cxc) + m
    Hc = math.ceil(float(v.max()) + cyc) + m
    lens = ((u + cxc).astype(np.float32), (v + cyc).astype(np.float32))
    principal = ((Wc - 1) / 2.0 - cxc, (Hc - 1) / 2.0 - cyc)
    return RenderCamera(pos, quat, (fx, fy), principal, (Wc, Hc), lens, (W, H), eq.max_px)
