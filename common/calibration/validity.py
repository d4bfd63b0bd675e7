"""Is a calibration physically possible for this arena? The one check that the
calibrator runs before it publishes and every stage runs before it adopts one.

A calibration is refused when a field is not finite, when it is for another image size,
when the camera is not above the floor and the objects' top planes, or when the image's
footprint is not finite and bounded: the image border, back-projected on the floor and
on the highest top plane (eqs. 5–10 for the paper model, OpenCV's for the pinhole),
must land on those planes and within :data:`MAX_FOOTPRINT_CM` of the world origin.
"""

from __future__ import annotations

import hashlib
import math
from typing import Any

import msgspec
import numpy as np

from ovis.common.calibration.file import Calibration
from ovis.common.camera.projection import back_project, camera_centre_cm
from ovis.common.config import OvisConfig

__all__ = [
    "BORDER_SAMPLES",
    "MAX_FOOTPRINT_CM",
    "border_pixels",
    "calibration_problem",
    "setup_problem",
    "simulated_setup",
]

#: The footprint of the image on the floor must lie within this distance (cm) of the
#: world origin on each axis: 100 m, far beyond any arena a ceiling camera sees.
MAX_FOOTPRINT_CM = 1e4
#: Points per image side that are back-projected (corners included).
BORDER_SAMPLES = 9


def border_pixels(rows: int, cols: int, n: int = BORDER_SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """(row, col) of ``n`` points on each side of a ``rows × cols`` image's border."""
    r = np.linspace(0.0, rows - 1.0, n)
    c = np.linspace(0.0, cols - 1.0, n)
    zeros, last_r, last_c = np.zeros(n), np.full(n, rows - 1.0), np.full(n, cols - 1.0)
    return np.concatenate([zeros, last_r, r, r]), np.concatenate([c, c, zeros, last_c])


def _not_finite(value: Any, path: str) -> str | None:
    """The path of the first non-finite number in a decoded structure, or None."""
    if isinstance(value, float):
        return None if math.isfinite(value) else path
    if isinstance(value, dict):
        items = value.items()
    elif isinstance(value, list | tuple):
        items = enumerate(value)
    else:
        return None
    for key, item in items:
        found = _not_finite(item, f"{path}.{key}")
        if found:
            return found
    return None


def calibration_problem(calib: Calibration, config: OvisConfig) -> str | None:
    """Why ``calib`` must not be used with ``config``'s arena (one line), or None."""
    name = f"calibration v{calib.version}"
    for part in ("camera", "image", "pose"):
        bad = _not_finite(msgspec.to_builtins(getattr(calib, part)), part)
        if bad:
            return f"{name} refused: {bad} is not a finite number"
    cam, want = calib.camera, config.camera
    if (cam.rows, cam.cols) != (want.rows, want.cols):
        return (
            f"{name} refused: it is for {cam.cols}x{cam.rows} images, this arena's camera "
            f"is {want.cols}x{want.rows}"
        )
    top = max(calib.pose.obstacle_height_cm, calib.pose.robot_height_cm, 0.0)
    try:
        centre_z = camera_centre_cm(cam)[2]
    except (ArithmeticError, ValueError) as exc:
        return f"{name} refused: the camera's position cannot be computed ({exc})"
    if not math.isfinite(centre_z) or centre_z <= top:
        return (
            f"{name} refused: the camera is at Z = {centre_z:.1f} cm, not above the floor "
            f"and the objects' tops ({top:g} cm)"
        )
    rows, cols = border_pixels(cam.rows, cam.cols)
    for plane in sorted({0.0, top}):
        with np.errstate(all="ignore"):
            hit = back_project(rows, cols, cam, plane)
            x, y = np.asarray(hit.x_cm, dtype=float), np.asarray(hit.y_cm, dtype=float)
        seen = np.asarray(hit.valid, dtype=bool) & np.isfinite(x) & np.isfinite(y)
        if not seen.all():
            return (
                f"{name} refused: {int((~seen).sum())} of {seen.size} image border points "
                f"do not see the plane Z = {plane:g} cm (the footprint is unbounded)"
            )
        extent = float(max(np.abs(x).max(), np.abs(y).max()))
        if extent > MAX_FOOTPRINT_CM:
            return (
                f"{name} refused: the image's footprint on Z = {plane:g} cm reaches "
                f"{extent:.0f} cm from the origin (limit {MAX_FOOTPRINT_CM:g} cm)"
            )
    return None


def simulated_setup(config: OvisConfig) -> str:
    """The simulated set-up a calibrator run on ``config`` calibrates: its world and a
    digest of the camera that renders it and of the scene's seed ("light:3f2a…"; the
    physical world's empty floor, which a calibration names as its background, and its
    floor marks are the seed's)."""
    made = msgspec.json.encode([config.camera, config.service.seed])
    return f"{config.simulator.world}:{hashlib.sha256(made).hexdigest()[:16]}"


def setup_problem(calib: Calibration, config: OvisConfig) -> str | None:
    """Why a calibration made on the simulator (``simulated``) is not this simulated run's
    (one line), or None: made on another world or another simulated camera (a state
    folder shared by runs of the light and the physical world). Calibrations of a real
    camera, and any for a real source, pass: that check is :func:`calibration_problem`'s."""
    if not (calib.simulated and config.service.simulated_source):
        return None
    here = simulated_setup(config)
    if calib.simulated_for == here:
        return None
    world = calib.simulated_for.partition(":")[0]
    made = f"the {world} world's" if world else "an earlier run's"
    return (
        f"calibration v{calib.version} is not this run's: made on {made} simulated camera "
        f"or scene, this run renders the {config.simulator.world} world's ({here})"
    )
