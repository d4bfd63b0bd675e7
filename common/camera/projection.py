"""One interface to every camera model: world (cm) ⇄ pixel (row, col), whichever model.

ovis has two camera models, selected by ``[camera] model``:

* ``"paper"`` — the paper's tripod model, eqs. 4–10 (:mod:`ovis.common.camera.paper_model`,
  :class:`~ovis.common.config.CameraParams`);
* ``"pinhole"`` — a pinhole with 6-DoF pose and Brown–Conrady distortion, OpenCV's
  model (:mod:`ovis.common.camera.pinhole`, :class:`~ovis.common.config.PinholeParams`).

Everything that projects (detection, calibration, the simulator) calls the functions
here; they take the same arguments as :mod:`ovis.common.camera.paper_model` (camera last) and
dispatch on the camera's type, so a population camera (fields holding ``(P, 1)``
arrays) works for both models.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ovis.common.camera import paper_model as paper
from ovis.common.camera import pinhole
from ovis.common.camera.paper_model import BackProjection, PixelJacobian, Projection
from ovis.common.config import CALIBRATED_VARIABLES, CameraModel, CameraParams, PinholeParams

__all__ = [
    "BackProjection",
    "CameraModel",
    "PixelJacobian",
    "Projection",
    "back_project",
    "camera_centre_cm",
    "camera_for_image_size",
    "camera_parameters",
    "disks_in_image",
    "pixel_footprint_cm2",
    "pixel_jacobian",
    "principal_point_rowcol",
    "project",
]

FloatArray = NDArray[np.float64]


def _check(cam: object) -> None:
    if not isinstance(cam, CameraParams | PinholeParams):
        raise TypeError(
            f"expected a camera (CameraParams or PinholeParams), got {type(cam).__name__}"
        )


def project(x_cm: ArrayLike, y_cm: ArrayLike, z_cm: ArrayLike, cam: CameraModel) -> Projection:
    """World point (cm) → pixel (row, col), with a ``valid`` mask, for either model."""
    if isinstance(cam, PinholeParams):
        return pinhole.project(x_cm, y_cm, z_cm, cam)
    _check(cam)
    return paper.project(x_cm, y_cm, z_cm, cam)


def back_project(
    row: ArrayLike, col: ArrayLike, cam: CameraModel, z_cm: ArrayLike = 0.0
) -> BackProjection:
    """Pixel (row, col) → point on the plane Z = ``z_cm`` (cm), for either model."""
    if isinstance(cam, PinholeParams):
        return pinhole.back_project(row, col, cam, z_cm)
    _check(cam)
    return paper.back_project(row, col, cam, z_cm)


def pixel_jacobian(
    row: ArrayLike, col: ArrayLike, cam: CameraModel, z_cm: ArrayLike = 0.0
) -> PixelJacobian:
    """The pixel → plane Z = ``z_cm`` map at (row, col) and its Jacobian (cm per pixel,
    central differences ±½ px), for either model (see
    :func:`ovis.common.camera.paper_model.pixel_jacobian`)."""
    if not isinstance(cam, PinholeParams):
        _check(cam)
        return paper.pixel_jacobian(row, col, cam, z_cm)
    rows, cols = paper.five_points(row, col)
    b = pinhole.back_project(rows, cols, cam, z_cm)
    return paper.jacobian_of(b.x_cm, b.y_cm, b.valid)


def disks_in_image(
    x_cm: ArrayLike,
    y_cm: ArrayLike,
    z_cm: ArrayLike,
    radius_cm: ArrayLike,
    cam: CameraModel,
    margin_px: float = 0.0,
) -> NDArray[np.bool_]:
    """Whether each horizontal disk (centre, height, radius; cm) projects wholly inside the
    image, at least ``margin_px`` from its border: an object whose blob the border cuts
    has a biased centre, and one wholly inside has not."""
    x, y, z, r = np.broadcast_arrays(
        *(np.asarray(v, dtype=np.float64) for v in (x_cm, y_cm, z_cm, radius_cm))
    )
    ang = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
    p = project(
        x[..., None] + r[..., None] * np.cos(ang),
        y[..., None] + r[..., None] * np.sin(ang),
        np.broadcast_to(z[..., None], (*z.shape, ang.size)),
        cam,
    )
    m = float(margin_px)
    ok = (
        p.valid
        & (p.row >= m)
        & (p.row <= cam.rows - 1 - m)
        & (p.col >= m)
        & (p.col <= cam.cols - 1 - m)
    )
    return ok.all(axis=-1)


def pixel_footprint_cm2(
    row: ArrayLike, col: ArrayLike, cam: CameraModel, z_cm: ArrayLike = 0.0
) -> FloatArray:
    """Floor area (cm²) of one pixel at (row, col) on the plane Z = ``z_cm``; 0 where
    the pixel does not see the plane."""
    return pixel_jacobian(row, col, cam, z_cm).area_cm2


def camera_centre_cm(cam: CameraModel) -> tuple[float, float, float]:
    """The camera's centre of projection in world cm.

    Pinhole: ``−Rᵀ·tvec``. Paper model: the lens, at ``(0, 0, λ)`` in the camera frame
    of eq. 4, which is where rays converge (eqs. 5–6).
    """
    if isinstance(cam, PinholeParams):
        return tuple(float(v) for v in pinhole.camera_centre_cm(cam))  # type: ignore[return-value]
    _check(cam)
    R = paper.rotation_world_cam(cam.theta_deg)
    c = np.array([float(v) for v in paper.camera_centre_mm(cam)])
    lens = c + R[:, 2] * float(cam.lam_mm)
    return tuple(float(v) / paper.CM_TO_MM for v in lens)  # type: ignore[return-value]


def principal_point_rowcol(cam: CameraModel) -> tuple[float, float]:
    """(row, col) of the principal point: paper (c_x, c_y); pinhole (cy, cx)."""
    if isinstance(cam, PinholeParams):
        return float(cam.cy), float(cam.cx)
    _check(cam)
    return float(cam.c_x), float(cam.c_y)


def camera_parameters(cam: CameraModel) -> dict[str, float]:
    """The calibrated parameters of a camera by name (for reports and replies).

    Paper: ``Z0_cm, lam_mm, k1, k2, k3, s_x, s_y``; pinhole: ``fx, fy, cx, cy, k1, k2,
    p1, p2, k3, rvec_x..z, tvec_x_cm..z_cm``.
    """
    if isinstance(cam, PinholeParams):
        out = {n: float(getattr(cam, n)) for n in ("fx", "fy", "cx", "cy")}
        out |= {n: float(getattr(cam, n)) for n in ("k1", "k2", "p1", "p2", "k3")}
        out |= {f"rvec_{a}": float(v) for a, v in zip("xyz", cam.rvec, strict=True)}
        out |= {f"tvec_{a}_cm": float(v) for a, v in zip("xyz", cam.tvec_cm, strict=True)}
        return out
    _check(cam)
    return {n: float(getattr(cam, n)) for n in CALIBRATED_VARIABLES[2:]}


def camera_for_image_size(cam: CameraModel, rows: int, cols: int) -> CameraModel:
    """The camera resized to a frame of ``rows`` × ``cols``: the image size comes from the
    image. The principal point (and the paper model's N_fx, N_fy) follow only where
    they were the old frame's centre (and size); a camera configured otherwise cannot
    be resized and raises ``ValueError`` naming the fields to set."""
    import msgspec

    if (cam.rows, cam.cols) == (rows, cols):
        return cam
    # The centre as (rows - 1)/2 (pixel centres) or rows/2 (pixel edges): keep the style.
    pp = principal_point_rowcol(cam)
    styles = {0.5: ((rows - 1) / 2, (cols - 1) / 2), 0.0: (rows / 2, cols / 2)}
    new_centre = next(
        (
            new
            for off, new in styles.items()
            if pp == ((cam.rows - 2 * off) / 2, (cam.cols - 2 * off) / 2)
        ),
        None,
    )
    size = f"{cols}x{rows}"
    if new_centre is None:
        what = "cx, cy" if isinstance(cam, PinholeParams) else "c_x, c_y"
        raise ValueError(
            f"the frame is {size} but the camera is configured for {cam.cols}x{cam.rows} "
            f"with its principal point off-centre; set camera.rows, cols and {what}"
        )
    if isinstance(cam, PinholeParams):
        return msgspec.structs.replace(
            cam, rows=rows, cols=cols, cy=new_centre[0], cx=new_centre[1]
        )
    if (cam.N_fx, cam.N_fy) != (cam.rows, cam.cols):
        raise ValueError(
            f"the frame is {size} but the camera is configured for {cam.cols}x{cam.rows} "
            "with N_fx, N_fy not its size; set camera.rows, cols, N_fx, N_fy, c_x, c_y"
        )
    return msgspec.structs.replace(
        cam, rows=rows, cols=cols, N_fx=float(rows), N_fy=float(cols),
        c_x=new_centre[0], c_y=new_centre[1],
    )  # fmt: skip
