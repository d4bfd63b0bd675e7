"""Whether a calibration fits a source's frames, and the one that does.

The frame size comes from the source. A calibration of that size is used as it is; one
of another size with the same aspect ratio is scaled to it exactly
(:mod:`ovis.common.camera.scaling`); any other size is refused with both sizes named.
And a calibration the calibrator made on the simulator's ground truth is the simulated
camera's: it never stands for a real camera.
"""

from __future__ import annotations

import re

import msgspec

from ovis.common.calibration.file import Calibration
from ovis.common.camera.scaling import same_aspect, scale_camera, scale_factors
from ovis.common.config import CameraParams, load_config

__all__ = ["HOW_TO_CALIBRATE", "FrameSizeError", "fit_to_frames", "made_on_simulator"]

#: What to do when a real camera has no calibration of its own (one line).
HOW_TO_CALIBRATE = (
    "make one with `ovis intrinsics photos/ --board chessboard:9x6 --square-cm S --out CAM.yaml` "
    "and `ovis calibrate floor.jpg --intrinsics CAM.yaml --board chessboard:9x6 --square-cm S "
    "--out calib.json` (S: a printed square's side in cm; docs/real-camera.md), then give "
    "--calibration calib.json"
)


class FrameSizeError(ValueError):
    """A calibration that cannot be used for frames of this size; the message names
    both sizes and what to do."""


def _size(calib: Calibration) -> str:
    return f"{calib.camera.cols}x{calib.camera.rows}"


def fit_to_frames(
    calib: Calibration, width: int, height: int, *, source: str, name: str
) -> tuple[Calibration, str]:
    """``calib`` for ``width × height`` frames of ``source`` (``name``: how to call the
    calibration in messages), and a sentence saying it was scaled ("" when it fits as
    it is); :class:`FrameSizeError` when it cannot fit."""
    cam = calib.camera
    if (cam.cols, cam.rows) == (width, height):
        return calib, ""
    frames = f"{source} delivers {width}x{height} frames but {name} is for {_size(calib)}"
    if not same_aspect(cam.cols, cam.rows, width, height):
        raise FrameSizeError(
            f"{frames} (another aspect ratio: the camera crops); calibrate on frames of "
            f"this source, or set the camera to {_size(calib)} ([service] camera_width, "
            "camera_height)"
        )
    image = calib.image
    fixed = [n for n in ("background", "roi") if getattr(image, n)]
    if fixed:
        raise FrameSizeError(
            f"{frames}, and its [image] {' and '.join(fixed)} image is made for "
            f"{_size(calib)}: it cannot be scaled; calibrate on frames of this source"
        )
    a_r, a_c = scale_factors(cam, height, width)
    if image.block_px:
        block = max(3, round(image.block_px * (a_r * a_c) ** 0.5) | 1)
        image = msgspec.structs.replace(image, block_px=block)
    scaled = msgspec.structs.replace(
        calib,
        camera=scale_camera(cam, height, width),
        image=image,
        source_image=f"{calib.source_image} (scaled from {_size(calib)} to {width}x{height})",
    )
    what = "fx, fy, cx, cy" if cam.model == "pinhole" else "N_fx, N_fy, c_x, c_y"
    factor = f"{a_c:g}" if a_r == a_c else f"{a_c:g} (columns) and {a_r:g} (rows)"
    return scaled, (
        f"{name} is for {_size(calib)}, {source} delivers {width}x{height}: "
        f"its intrinsics ({what}) are scaled by {factor}"
    )


#: Fields of the paper model the calibrator does not tune: the set-up's constants.
_SETUP = ("d_x_mm", "d_y_mm", "X0_cm", "Y0_cm", "L_cm", "r1_cm", "r2_cm", "r3_cm", "theta_deg")


def made_on_simulator(calib: Calibration) -> bool:
    """Whether ``calib`` is the simulated camera's: made by the calibrator on the
    simulator's truth (``simulated``), or, in a file from before that was recorded, made
    by the calibrator ("frame N") on the default preset's simulated set-up."""
    if calib.simulated:
        return True
    cam = calib.camera
    if not re.fullmatch(r"frame \d+", calib.source_image) or not isinstance(cam, CameraParams):
        return False
    preset = load_config().camera
    return all(getattr(cam, n) == getattr(preset, n) for n in _SETUP)
