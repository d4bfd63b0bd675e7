"""A blob's sub-pixel outline carried onto the floor: each edge point back-projected onto
Z = 0, its normal carried through the pixel → floor Jacobian J (a normal m in the image
is ``J⁻ᵀ·m`` on the floor), and the pixels per cm across the outline there
(``1 / |Jᵀ·n|``: a floor distance d along the floor normal n is ``d / |Jᵀ·n|`` pixels
across the image outline), so that residuals measured on the floor count in pixels."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ovis.common.camera.paper_model import PixelJacobian
from ovis.common.camera.plane_table import PlaneTables
from ovis.common.camera.projection import pixel_jacobian
from ovis.common.config import CameraModel
from ovis.common.solids.fit import FloorOutline
from ovis.common.vision.outline import chain_normals

__all__ = ["chain_floor", "floor_outline"]

FloatArray = NDArray[np.float64]


def floor_outline(
    edges: FloatArray,
    normals: FloatArray,
    camera: CameraModel,
    tables: PlaneTables | None = None,
) -> FloorOutline:
    """Edge points (n, 2) frame (col, row) and their image normals (col, row) on the
    floor (read from the camera's floor table when ``tables`` are given); points the
    camera cannot carry onto the floor are left out."""
    if tables is not None:
        j = tables.jacobian(edges[:, 1], edges[:, 0], camera, 0.0)
    else:
        j = pixel_jacobian(edges[:, 1], edges[:, 0], camera, 0.0)
    return _carried(j, normals)


def chain_floor(
    chain: NDArray[np.integer], camera: CameraModel, tables: PlaneTables | None = None
) -> FloorOutline:
    """An outline's pixel chain (n, 2) frame (col, row) itself on the floor, with its
    normals (:func:`~ovis.common.vision.outline.chain_normals`): :func:`floor_outline`
    of its points, the floor table read at whole pixels
    (:meth:`~ovis.common.camera.plane_table.PlaneTables.pixel_jacobian`)."""
    points, normals = chain_normals(chain)
    if tables is not None:
        j = tables.pixel_jacobian(chain[:, 1], chain[:, 0], camera, 0.0)
    else:
        j = pixel_jacobian(points[:, 1], points[:, 0], camera, 0.0)
    return _carried(j, normals)


def _carried(j: PixelJacobian, normals: FloatArray) -> FloorOutline:
    """Points and image normals on the floor by their pixel → floor maps ``j``: with
    J = [[∂x/∂col, ∂x/∂row], [∂y/∂col, ∂y/∂row]], the floor normal is J⁻ᵀ·m (the
    adjugate's transpose times m over det J, normalised) and ``|Jᵀ·n|`` is
    ``|m| · |det J| / |adj(J)ᵀ·m|``: closed forms of a 2 × 2 matrix's inverse (a batch
    of tiny LAPACK solves costs far more)."""
    a, b, c, d = j.dx_dcol, j.dx_drow, j.dy_dcol, j.dy_drow
    m0, m1 = normals[:, 0], normals[:, 1]
    det = a * d - b * c
    size = np.hypot(m0, m1)
    x, y = j.x_cm, j.y_cm
    # a point with no image normal (a flat profile) has no direction to carry across
    ok = j.valid & (np.abs(det) > 1e-12) & (size > 1e-12)
    if not ok.all():
        a, b, c, d, det, m0, m1, size, x, y = (v[ok] for v in (a, b, c, d, det, m0, m1, size, x, y))
    nx, ny = d * m0 - c * m1, a * m1 - b * m0  # adj(J)ᵀ·m
    length = np.hypot(nx, ny)
    along = np.copysign(1.0, det) / length
    normal = np.column_stack([nx * along, ny * along])
    return FloorOutline(np.column_stack([x, y]), normal, length / (size * np.abs(det)))
