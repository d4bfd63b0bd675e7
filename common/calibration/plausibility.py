"""Is a calibration believable? Flags the signs of a wrong camera that still "converged".

A GA run (or a pose fit) always returns its best answer, even when the data cannot be
explained: the wrong blobs matched, a lens model that does not fit, a range that holds
no real camera. Three signs are checked:

* the mean DIPE (eq. 14) above :data:`MAX_MEAN_DIPE_PX`: a camera that fits its control
  points misses them by a fraction of a pixel to a pixel or two (the paper's is below
  one), never by tens;
* a calibrated camera parameter at an end of its search range (within
  :data:`EDGE_FRACTION` of the range): the optimum was cut off by the range, so the
  true camera may lie outside it. With a mean DIPE above :data:`LIMIT_DIPE_PX` this
  makes the calibration implausible; below, the points are still fitted well (a
  parameter the data hardly determine often ends at a limit) and it is a warning;
* the camera not above the control points (z up): floor axes given left-handed;
* with a known lens, residuals the lens and the points' precision do not explain, or a
  lens file that cannot be trusted (``accuracy.lens``, see
  :mod:`ovis.common.calibration.lens_check`).
"""

from __future__ import annotations

from ovis.common.calibration.file import Calibration
from ovis.common.camera.projection import camera_centre_cm
from ovis.common.config import PINHOLE_VARIABLES, PinholeParams

__all__ = ["EDGE_FRACTION", "MAX_MEAN_DIPE_PX", "implausible_reasons", "plausibility"]

#: Largest believable mean DIPE, px.
MAX_MEAN_DIPE_PX = 3.0
#: A parameter at a range limit makes a calibration implausible above this mean DIPE, px.
LIMIT_DIPE_PX = 1.0
#: A parameter this close to an end of its range (fraction of the range) is "at the limit".
EDGE_FRACTION = 1e-3
#: The paper model's geometric parameters checked against their ranges (the distortion
#: coefficients' ranges are tight on purpose, and often end where the value is ~0).
PAPER_CHECKED = ("Z0_cm", "lam_mm", "s_x", "s_y")


def _value(cam: PinholeParams, name: str) -> float:
    if name.startswith("rvec_"):
        return float(cam.rvec["xyz".index(name[-1])])
    if name.startswith("tvec_"):
        return float(cam.tvec_cm["xyz".index(name[5])])
    return float(getattr(cam, name))


def _at_limits(calib: Calibration) -> list[str]:
    ranges = calib.ranges
    if ranges is None:
        return []
    cam = calib.camera
    found: list[str] = []
    if isinstance(cam, PinholeParams):
        pin = ranges.pinhole
        pairs = [(n, getattr(pin, n)) for n in PINHOLE_VARIABLES] if pin is not None else []
        pairs = [(n, p) for n, p in pairs if p is not None and p[1] > p[0]]
        values = {n: _value(cam, n) for n, _ in pairs}
    else:
        pairs = [(n, getattr(ranges, n)) for n in PAPER_CHECKED]
        values = {n: float(getattr(cam, n)) for n, _ in pairs}
    for name, (lo, hi) in pairs:
        edge = EDGE_FRACTION * (hi - lo)
        v = values[name]
        if v <= lo + edge or v >= hi - edge:
            found.append(f"{name} = {v:.6g} is at the limit of its range [{lo:g}, {hi:g}]")
    return found


def implausible_reasons(calib: Calibration) -> list[str]:
    """Why ``calib`` is not believable (empty: nothing found)."""
    return plausibility(calib)[0]


def plausibility(calib: Calibration) -> tuple[list[str], list[str]]:
    """(why ``calib`` is not believable, what is only suspicious) — see the module docstring."""
    reasons = []
    top = max((p.z_cm for p in calib.points), default=0.0)
    height = camera_centre_cm(calib.camera)[2]
    if height <= top:
        reasons.append(
            f"the camera is at z = {height:.3g} cm, not above the control points: the floor "
            "axes x, y, z (up) must be right-handed (swap x and y, or negate one)"
        )
    if calib.dipe_px > MAX_MEAN_DIPE_PX:
        reasons.append(
            f"mean DIPE {calib.dipe_px:.3g} px is above {MAX_MEAN_DIPE_PX:g} px: the camera "
            "does not explain the control points"
        )
    if calib.accuracy is not None and calib.accuracy.lens is not None:
        reasons += calib.accuracy.lens.problems
    limits = _at_limits(calib)
    if calib.dipe_px > LIMIT_DIPE_PX:
        return reasons + limits, []
    return reasons, limits
