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
    chain: NDArray[np.integer],
    camera: CameraModel,
    tables: PlaneTables | None = None,
    *,
    closed_form: bool = False,
) -> FloorOutline:
    """An outline's pixel chain (n, 2) frame (col, row) itself on the floor, with its
    normals (:func:`~ovis.common.vision.outline.chain_normals`): :func:`floor_outline`
    of its points, the floor table read at whole pixels
    (:meth:`~ovis.common.camera.plane_table.PlaneTables.pixel_jacobian`).
    ``closed_form``: the normals carried by :func:`_carried_closed_form` (a follow's,
    each frame), else as the fits were tuned with."""
    points, normals = chain_normals(chain)
    if tables is not None:
        j = tables.pixel_jacobian(chain[:, 1], chain[:, 0], camera, 0.0)
    else:
        j = pixel_jacobian(points[:, 1], points[:, 0], camera, 0.0)
    return _carried_closed_form(j, normals) if closed_form else _carried(j, normals)


def _carried(j: PixelJacobian, normals: FloatArray) -> FloorOutline:
    """Points and image normals on the floor by their pixel → floor maps ``j``: with
    J = [[∂x/∂col, ∂x/∂row], [∂y/∂col, ∂y/∂row]], the floor normal is J⁻ᵀ·m (normalised)
    and a pixel across the edge is ``|Jᵀ·n|`` cm. The inverse is LAPACK's, as the fits
    were tuned with: a closed form differs in the last bits, and a fit's choices (a
    shape, a cut) can turn on them."""
    jac = np.empty((len(normals), 2, 2))  # (x, y) by (col, row)
    jac[:, 0, 0], jac[:, 0, 1] = j.dx_dcol, j.dx_drow
    jac[:, 1, 0], jac[:, 1, 1] = j.dy_dcol, j.dy_drow
    det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
    # a point with no image normal (a flat profile) has no direction to carry across
    ok = j.valid & (np.abs(det) > 1e-12) & (np.hypot(normals[:, 0], normals[:, 1]) > 1e-12)
    jac, normals = jac[ok], normals[ok]
    inv_t = np.linalg.inv(jac).transpose(0, 2, 1)
    n = np.einsum("nij,nj->ni", inv_t, normals)
    n /= np.linalg.norm(n, axis=1)[:, None]
    across = np.linalg.norm(np.einsum("nji,nj->ni", jac, n), axis=1)
    points = np.column_stack([j.x_cm[ok], j.y_cm[ok]])
    return FloorOutline(points, n, 1.0 / across)


def _carried_closed_form(j: PixelJacobian, normals: FloatArray) -> FloorOutline:
    """:func:`_carried` with J⁻ᵀ·m in closed form, [d·m₀ − c·m₁, a·m₁ − b·m₀] / det J
    for J = [[a, b], [c, d]]: a fraction of LAPACK's cost on a chain's few hundred
    points, the same but in the last bits (where a fit's choices may turn on them: only
    follows, which move solids a little, use it)."""
    a, b, c, d = j.dx_dcol, j.dx_drow, j.dy_dcol, j.dy_drow
    det = a * d - b * c
    m0, m1 = normals[:, 0], normals[:, 1]
    ok = j.valid & (np.abs(det) > 1e-12) & (np.hypot(m0, m1) > 1e-12)
    x, y = j.x_cm, j.y_cm
    if not ok.all():
        a, b, c, d, det, m0, m1, x, y = (v[ok] for v in (a, b, c, d, det, m0, m1, x, y))
    n = np.empty((len(det), 2))
    n[:, 0] = (d * m0 - c * m1) / det
    n[:, 1] = (a * m1 - b * m0) / det
    n /= np.hypot(n[:, 0], n[:, 1])[:, None]
    across = np.hypot(a * n[:, 0] + c * n[:, 1], b * n[:, 0] + d * n[:, 1])
    points = np.empty((len(det), 2))
    points[:, 0], points[:, 1] = x, y
    return FloorOutline(points, n, 1.0 / across)
