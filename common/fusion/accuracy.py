"""A camera's expected position error at a floor point: its pixel error pushed through
the back-projection Jacobian (cm per px there, see
:func:`ovis.common.camera.projection.pixel_jacobian`). Far from the camera, or seen
obliquely, one pixel covers more floor, so that camera's sighting weighs less."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ovis.common.camera.projection import pixel_jacobian, project
from ovis.common.config import CameraModel
from ovis.common.fusion.merge import Sighting

__all__ = ["position_covariance", "sightings_of"]

FloatArray = NDArray[np.float64]


def position_covariance(
    x_cm: ArrayLike, y_cm: ArrayLike, z_cm: ArrayLike, cam: CameraModel, pixel_sigma_px: float
) -> FloatArray:
    """``(n, 2, 2)`` covariance (cm²) of the floor position ``cam`` measures at the
    points ``(x, y)`` on the plane ``z``, for an isotropic pixel error of
    ``pixel_sigma_px``: ``σ² J Jᵀ`` with ``J = ∂(X, Y)/∂(row, col)``. Points the camera
    does not see get an infinite covariance (no weight)."""
    x, y, z = np.broadcast_arrays(
        *(np.atleast_1d(np.asarray(v, float)) for v in (x_cm, y_cm, z_cm))
    )
    p = project(x, y, z, cam)
    jac = pixel_jacobian(p.row, p.col, cam, z)
    J = np.stack(
        [
            np.stack([jac.dx_drow, jac.dx_dcol], axis=-1),
            np.stack([jac.dy_drow, jac.dy_dcol], axis=-1),
        ],
        axis=-2,
    ).reshape(-1, 2, 2)
    cov = pixel_sigma_px**2 * J @ np.swapaxes(J, -1, -2)
    ok = (np.asarray(p.valid) & np.asarray(jac.valid)).reshape(-1) & np.isfinite(cov).all((1, 2))
    cov[~ok] = np.diag([np.inf, np.inf])
    return cov


def sightings_of(
    camera: str,
    cam: CameraModel,
    objects: list[dict[str, Any]],
    pixel_sigma_px: float,
) -> list[Sighting]:
    """One camera's detections (mappings with ``kind, x_cm, y_cm, z_cm, radius_cm`` and
    optionally ``marker_id``, ``heading_deg``) as sightings with that camera's position
    covariance at each (see :func:`position_covariance`)."""
    if not objects:
        return []
    cov = position_covariance(
        [o["x_cm"] for o in objects],
        [o["y_cm"] for o in objects],
        [o["z_cm"] for o in objects],
        cam,
        pixel_sigma_px,
    )
    return [
        Sighting(
            camera=camera,
            kind=o["kind"],
            x_cm=float(o["x_cm"]),
            y_cm=float(o["y_cm"]),
            z_cm=float(o["z_cm"]),
            radius_cm=float(o["radius_cm"]),
            cov_cm2=(float(c[0, 0]), float(c[0, 1]), float(c[1, 1])),
            marker_id=o.get("marker_id"),
            heading_deg=o.get("heading_deg"),
        )
        for o, c in zip(objects, cov, strict=True)
        if np.isfinite(c).all()
    ]
