"""Cameras a lab puts over an arena, as calibrated pinhole cameras: a tripod at the side
looking obliquely down at the arena, and a camera on the ceiling looking straight down.

:func:`aimed_camera` is the general form (a camera at a point, aimed at another, with a
horizontal field of view and Brown–Conrady distortion); :data:`RIGS` names the two the
physical world's studies use (:func:`rig`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from ovis.common.config import OvisConfig, PinholeParams

__all__ = ["RIGS", "aimed_camera", "rig"]

#: (height above the floor, horizontal distance back from the arena's centre towards −Y)
#: (cm), or None for straight down over the arena's centre.
RIGS: dict[str, tuple[float, float] | None] = {
    "oblique": (140.0, 120.0),
    "overhead": None,
}
#: The overhead rig's height (cm).
OVERHEAD_HEIGHT_CM = 200.0
#: Horizontal field of view of the rigs (deg) and their lens.
RIG_HFOV_DEG = 50.0
RIG_DISTORTION = (-0.08, 0.03, 0.0, 0.0, 0.0)


def aimed_camera(
    position_cm: Sequence[float],
    target_cm: Sequence[float],
    *,
    rows: int = 480,
    cols: int = 640,
    hfov_deg: float = RIG_HFOV_DEG,
    distortion: Sequence[float] = (0.0, 0.0, 0.0, 0.0, 0.0),
    up: Sequence[float] = (0.0, 0.0, 1.0),
) -> PinholeParams:
    """A pinhole camera at ``position_cm`` looking at ``target_cm`` (world cm), square
    pixels, principal point at the frame's centre, its image's up towards ``up`` (for a
    camera looking straight down, give a horizontal ``up``)."""
    c = np.asarray(position_cm, dtype=np.float64)
    forward = np.asarray(target_cm, dtype=np.float64) - c
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(right) < 1e-9:
        raise ValueError("the camera looks along its up direction: give another up")
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])
    rvec = cv2.Rodrigues(R)[0].ravel()
    tvec = -R @ c
    f = (cols / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    k1, k2, p1, p2, k3 = (float(v) for v in distortion)
    return PinholeParams(
        rows=rows,
        cols=cols,
        fx=f,
        fy=f,
        cx=(cols - 1) / 2.0,
        cy=(rows - 1) / 2.0,
        k1=k1,
        k2=k2,
        p1=p1,
        p2=p2,
        k3=k3,
        rvec=(float(rvec[0]), float(rvec[1]), float(rvec[2])),
        tvec_cm=(float(tvec[0]), float(tvec[1]), float(tvec[2])),
    )


def rig(name: str, config: OvisConfig) -> PinholeParams:
    """The named rig (:data:`RIGS`) over ``config``'s arena, at ``config.camera``'s frame
    size: "oblique" stands on a tripod ``height`` cm up and ``back`` cm from the arena's
    centre towards −Y, aimed at the centre; "overhead" hangs over the centre looking
    down, its image's up along +Y."""
    if name not in RIGS:
        raise ValueError(f"unknown camera rig {name!r}; choose one of {', '.join(RIGS)}")
    (x0, x1), (y0, y1) = config.simulator.arena_x_cm, config.simulator.arena_y_cm
    centre = (0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.0)
    size = {"rows": int(config.camera.rows), "cols": int(config.camera.cols)}
    place = RIGS[name]
    if place is None:
        above = (centre[0], centre[1], OVERHEAD_HEIGHT_CM)
        return aimed_camera(above, centre, up=(0.0, 1.0, 0.0), distortion=RIG_DISTORTION, **size)
    height, back = place
    return aimed_camera(
        (centre[0], centre[1] - back, height), centre, distortion=RIG_DISTORTION, **size
    )
