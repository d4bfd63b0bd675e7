"""The shapes of solid objects: upright prisms on the floor, their parameters and their
footprint polygons (world cm, the floor Z = 0, x right and y up, counter-clockwise).

Every shape's parameter vector starts with its footprint centre ``(x, y)`` and ends with
its height ``h``; between them its size (and yaw, for a polygon):

* ``cylinder``: ``(x, y, r, h)``, a disk of radius r;
* ``box``: ``(x, y, length, width, yaw, h)``, a rectangle, its length along the yaw;
* ``prism3``, ``prism5``, ``prism6``: ``(x, y, R, yaw, h)``, a regular polygon whose
  circumradius is R and a corner at the yaw.

Arrays of parameter vectors (a leading batch axis) are handled at once.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "CYLINDER_SIDES",
    "SHAPES",
    "ShapeName",
    "equal_area_radius",
    "footprint_polygon",
    "parameter_count",
    "shape_sides",
    "size_and_yaw",
    "yaw_index",
]

FloatArray = NDArray[np.float64]

ShapeName = Literal["cylinder", "box", "prism3", "prism5", "prism6"]

#: Every shape a fit chooses from, in the order it tries them.
SHAPES: tuple[ShapeName, ...] = ("cylinder", "box", "prism3", "prism5", "prism6")

#: Sides of the polygon a cylinder's footprint is drawn as where a polygon is needed (its
#: area centroid in the image); its area is the disk's.
CYLINDER_SIDES = 48

_SIDES = {"cylinder": CYLINDER_SIDES, "box": 4, "prism3": 3, "prism5": 5, "prism6": 6}
_PARAMETERS = {"cylinder": 4, "box": 6, "prism3": 5, "prism5": 5, "prism6": 5}


def parameter_count(shape: str) -> int:
    """Length of the shape's parameter vector."""
    return _PARAMETERS[shape]


def yaw_index(shape: str) -> int | None:
    """Where a shape's parameter vector holds its yaw (None: a cylinder has none)."""
    return None if shape == "cylinder" else parameter_count(shape) - 2


def shape_sides(shape: str) -> int:
    """Corners of the shape's footprint polygon (a cylinder's: :data:`CYLINDER_SIDES`)."""
    return _SIDES[shape]


def _regular(n: int, circumradius: FloatArray, yaw: FloatArray) -> FloatArray:
    """(..., n, 2) corners of regular n-gons about the origin."""
    a = yaw[..., None] + 2.0 * math.pi * np.arange(n) / n
    return np.stack([np.cos(a), np.sin(a)], -1) * circumradius[..., None, None]


def footprint_polygon(shape: str, theta: FloatArray) -> FloatArray:
    """(..., k, 2) corners of the footprints of parameter vectors ``theta`` (..., P),
    counter-clockwise; a cylinder as a :data:`CYLINDER_SIDES`-gon of the disk's area."""
    theta = np.asarray(theta, dtype=np.float64)
    centre = theta[..., None, 0:2]
    if shape == "cylinder":
        n = CYLINDER_SIDES
        grow = math.sqrt(2.0 * math.pi / (n * math.sin(2.0 * math.pi / n)))
        return centre + _regular(n, theta[..., 2] * grow, np.zeros(theta.shape[:-1]))
    if shape == "box":
        hl, hw, yaw = 0.5 * theta[..., 2], 0.5 * theta[..., 3], theta[..., 4]
        u = np.stack([np.cos(yaw), np.sin(yaw)], -1)
        v = np.stack([-np.sin(yaw), np.cos(yaw)], -1)
        signs = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
        along = signs[:, 0, None] * (hl[..., None, None] * u[..., None, :])
        across = signs[:, 1, None] * (hw[..., None, None] * v[..., None, :])
        return centre + along + across
    return centre + _regular(_SIDES[shape], theta[..., 2], theta[..., 3])


def equal_area_radius(shape: str, theta: FloatArray) -> FloatArray:
    """Radius of the disk as large as each footprint (cm)."""
    theta = np.asarray(theta, dtype=np.float64)
    if shape == "cylinder":
        return theta[..., 2]
    if shape == "box":
        return np.sqrt(theta[..., 2] * theta[..., 3] / math.pi)
    n = _SIDES[shape]
    area = 0.5 * n * theta[..., 2] ** 2 * math.sin(2.0 * math.pi / n)
    return np.sqrt(area / math.pi)


def size_and_yaw(shape: str, theta: FloatArray) -> tuple[float, float, float | None]:
    """Length and width of the footprint's bounding rectangle along its yaw (cm) and the
    yaw in degrees counter-clockwise from +X in (−90, 90] (a box's long axis; a
    prism's corner, modulo its symmetry; None for a cylinder)."""
    theta = np.asarray(theta, dtype=np.float64)
    if shape == "cylinder":
        d = 2.0 * float(theta[2])
        return d, d, None
    if shape == "box":
        length, width, yaw = float(theta[2]), float(theta[3]), float(theta[4])
        if width > length:
            length, width, yaw = width, length, yaw + 0.5 * math.pi
        deg = math.degrees(math.atan2(math.sin(2 * yaw), math.cos(2 * yaw)) / 2.0)
        return length, width, 90.0 if deg == -90.0 else deg
    n = _SIDES[shape]
    period = 360.0 / n
    deg = (math.degrees(float(theta[3])) + 0.5 * period) % period - 0.5 * period
    d = 2.0 * float(theta[2])
    return d, d, deg
