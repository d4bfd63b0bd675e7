"""How ovis's floor frame maps to a ROS frame (REP 103), and the accuracy of a pose there.

**Frames.** ovis's floor frame has X and Y on the floor, Z up (the height of a plane),
in cm, headings in degrees counter-clockwise from +X towards +Y, in (−180, 180]. REP 103
wants metres, radians and a right-handed frame (x forward, y left, z up). Whether ovis's
frame is right-handed depends on the camera model, as seen from above with Z up:

* a **pinhole** calibration (``fx·fy > 0``, proper rotation): right-handed. ROS
  ``(x, y, z) = (X, Y, Z) / 100``, ``yaw = heading``;
* the **paper model** images the world mirror-inverted (its pinhole equivalent has
  ``fy < 0``, see :mod:`ovis.common.camera.export`): the floor frame it calibrates is
  left-handed. ROS ``(x, y, z) = (X, −Y, Z) / 100``, ``yaw = −heading``: y is mirrored
  so that the frame is right-handed again and a robot turning left turns by +yaw, as
  its own odometry says. The camera frame is mirrored with it (its y axis, i.e. the
  image rows, keeps pointing down the image: ``fy`` and ``p1`` change sign), so that
  ``/tf_static`` is a proper rotation and CameraInfo has a positive ``fy``.

:func:`ros_floor` decides once per calibration (:attr:`RosFloor.mirrored`).

**Accuracy.** A position's covariance is ovis's accuracy model
(:class:`ovis.common.fusion.accuracy.AccuracyMap`): the calibration's measured pixel
error (its mean DIPE, px) pushed through the back-projection Jacobian at the object
(at the nearest node of a floor grid tabulated once per plane height). A marked
robot's heading comes from its marker's edges (side ``s``): each of the two edge
directions has an angular error ``σ/s`` for a corner position error ``σ`` (per axis),
and their mean ``σ/(s·√2)``. What ovis does not measure (z, roll, pitch;
velocities; everything without a calibration) gets :data:`NOT_MEASURED`.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import NamedTuple, TypeVar

import numpy as np
from numpy.typing import NDArray

from ovis.common.calibration.file import Calibration
from ovis.common.camera.export import as_pinhole
from ovis.common.config import PinholeParams
from ovis.common.fusion.accuracy import AccuracyMap

__all__ = [
    "NOT_MEASURED",
    "RIGHT_HANDED",
    "RosFloor",
    "Terms",
    "last_kept",
    "pinhole_of",
    "ros_floor",
]

T = TypeVar("T")

#: Variance (m², rad², m²/s², rad²/s²) of what ovis does not measure: large enough that
#: a filter (robot_localization, Nav2) gives it no weight.
NOT_MEASURED = 1e6


class RosFloor(NamedTuple):
    """One calibration's floor as ROS sees it: mirrored or not, and what the accuracy of
    a position there is (the camera's :class:`AccuracyMap`, tabulated on a floor grid per
    plane height on first use; None: not calibrated)."""

    mirrored: bool
    accuracy: AccuracyMap | None = None
    marker_side_cm: dict[int, float] = {}  # noqa: RUF012  (a NamedTuple default, never mutated)

    @property
    def y_sign(self) -> float:
        """−1 where ROS y is ovis's −Y (mirrored), else 1."""
        return -1.0 if self.mirrored else 1.0

    def position_m(self, x_cm: float, y_cm: float, z_cm: float) -> tuple[float, float, float]:
        """An ovis floor point (cm) in the ROS frame (m)."""
        return x_cm / 100.0, self.y_sign * y_cm / 100.0, z_cm / 100.0

    def yaw_rad(self, heading_deg: float) -> float:
        """An ovis heading (degrees) as a ROS yaw (radians, counter-clockwise from x)."""
        return self.y_sign * math.radians(heading_deg)

    def planar_covariance(
        self, x_cm: float, y_cm: float, z_cm: float
    ) -> NDArray[np.float64] | None:
        """The 2×2 covariance (m², ROS frame) of a position measured at this point, or
        None when it is not known (no calibration, or the camera does not see it)."""
        terms = self.planar_terms([(x_cm, y_cm, z_cm)])[0]
        if terms is None:
            return None
        xx, xy, yy = terms
        return np.array([[xx, xy], [xy, yy]])

    def planar_terms(self, points_cm: list[tuple[float, float, float]]) -> list[Terms | None]:
        """:meth:`planar_covariance` of each point as its terms ``(xx, xy, yy)``, read
        from the accuracy model's grid (nearest node, as the model does) without numpy
        per point: a frame's robots cost a few look-ups."""
        if self.accuracy is None:
            return [None] * len(points_cm)
        out: list[Terms | None] = []
        for x, y, z in points_cm:
            terms = _grid_terms(self.accuracy, x, y, z)
            if terms is None:  # off the grid: the model computes it
                cov = self.accuracy(x, y, z)[0]
                terms = (float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1]))
            xx, xy, yy = terms
            if not (math.isfinite(xx) and math.isfinite(xy) and math.isfinite(yy)):
                out.append(None)
                continue
            out.append((xx / 1e4, self.y_sign * xy / 1e4, yy / 1e4))
        return out

    def yaw_variance(self, robot_id: int, planar: Terms | None) -> float:
        """The variance (rad²) of a marked robot's heading, from the terms of its
        position's covariance (see the module docstring)."""
        side = self.marker_side_cm.get(robot_id)
        if planar is None or side is None or side <= 0.0:
            return NOT_MEASURED
        sigma_m = math.sqrt((planar[0] + planar[2]) / 2.0)
        return (sigma_m / (side / 100.0 * math.sqrt(2.0))) ** 2


#: A covariance's terms (xx, xy, yy).
Terms = tuple[float, float, float]


class _FlatGrid(NamedTuple):
    """One plane's covariance grid as Python floats (see AccuracyMap.cov_grid)."""

    x0: float
    y0: float
    step: float
    nx: int
    ny: int
    terms: list[Terms]


@functools.lru_cache(maxsize=16)
def _flat_grid(accuracy: AccuracyMap, z_cm: float) -> _FlatGrid | None:
    grid = accuracy.cov_grid(z_cm)
    if grid is None:
        return None
    x0, y0, step, nx, ny, flat = grid
    return _FlatGrid(x0, y0, step, nx, ny, [tuple(t) for t in flat.tolist()])


def _grid_terms(accuracy: AccuracyMap, x: float, y: float, z: float) -> Terms | None:
    """The covariance terms (cm²) at the grid node nearest (x, y) on plane z, or None
    off the grid."""
    grid = _flat_grid(accuracy, round(float(z), 1))
    if grid is None:
        return None
    i, j = round((x - grid.x0) / grid.step), round((y - grid.y0) / grid.step)
    if 0 <= i < grid.nx and 0 <= j < grid.ny:
        return grid.terms[i * grid.ny + j]
    return None


#: A right-handed floor without accuracy: what a caller gets without a calibration.
RIGHT_HANDED = RosFloor(False)


def last_kept(compute: Callable[[Calibration], T]) -> Callable[[Calibration], T]:
    """``compute`` remembering its last calibration and answer: a caller that asks once
    per frame with the calibration in use gets the answer worked out once."""
    last: list[tuple[Calibration, T]] = []  # one pair, replaced whole

    def kept(calib: Calibration) -> T:
        for seen, answer in last[:1]:
            if seen is calib or seen == calib:
                return answer
        answer = compute(calib)
        last[:] = [(calib, answer)]
        return answer

    return functools.wraps(compute)(kept)


@last_kept
def pinhole_of(calib: Calibration) -> PinholeParams:
    """``calib``'s camera as OpenCV's pinhole model (:func:`as_pinhole`: a fit for the
    paper's model)."""
    return as_pinhole(calib.camera).camera


@last_kept
def ros_floor(calib: Calibration) -> RosFloor:
    """The ROS view of ``calib``'s floor: mirrored for a camera model that images the
    world mirror-inverted, and the calibration's measured pixel error (None for the
    configured, uncalibrated camera of version 0). Its accuracy grids are built once
    per calibration (:func:`last_kept`)."""
    return _ros_floor(calib)


def _ros_floor(calib: Calibration) -> RosFloor:
    camera = pinhole_of(calib)
    mirrored = camera.fx * camera.fy < 0.0
    sides = {r.id: float(r.marker_side_cm) for r in calib.pose.robots}
    if calib.version == 0:
        return RosFloor(mirrored, None, sides)
    return RosFloor(mirrored, AccuracyMap(calib.camera, float(calib.dipe_px)), sides)
