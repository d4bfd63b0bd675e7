"""Export a calibrated camera to OpenCV and ROS, and the paper model's pinhole equivalent.

Two files other tools read:

* **OpenCV YAML** (``cv2.FileStorage``): ``image_width``, ``image_height``,
  ``camera_matrix`` (3×3 K), ``distortion_coefficients`` (1×5, ``k1, k2, p1, p2, k3``),
  ``rvec`` and ``tvec`` (3×1, world → camera; ``tvec`` in the world unit,
  ``world_units: cm``), ready for ``cv2.projectPoints`` / ``cv2.undistort``.
* **ROS** ``sensor_msgs/CameraInfo`` **YAML** (the ``camera_calibration_parsers``
  layout): ``image_width``, ``image_height``, ``camera_name``, ``camera_matrix``,
  ``distortion_model: plumb_bob``, ``distortion_coefficients``,
  ``rectification_matrix`` (identity: a monocular camera) and ``projection_matrix``
  ``[K | 0]`` (the rectified image keeps K). The pose is not part of CameraInfo.

OpenCV's pixel x is the column and y the row; ovis's ``row``/``col`` map to OpenCV's
``(y, x)``, and pixel centres are at integer coordinates in both.

**The paper model as a pinhole** (:func:`paper_to_pinhole`). Its eqs. 4–10 are a central
projection through the lens at ``(0, 0, λ)`` of the eq. 4 camera frame, so they have an
exact pinhole equivalent except for the distortion:

* camera frame: with ``q = Rᵀ·(P − C) − (0, 0, λ)`` (cm) the paper's image is
  ``row = c_x − s_x·N_fx/d_x·λ·q_x/q_z``, ``col = c_y − s_y·N_fy/d_y·λ·q_y/q_z``; OpenCV's
  right-handed camera ``(x, y, z) = (−q_y, q_x, q_z)`` gives ``R_cv = M·Rᵀ``,
  ``t_cv = −R_cv·C − (0, 0, λ)`` with ``M = [[0, −1, 0], [1, 0, 0], [0, 0, 1]]``;
* intrinsics: ``fx = s_y·N_fy/d_y·λ`` (columns), ``fy = −s_x·N_fx/d_x·λ`` (rows),
  ``cx = c_y``, ``cy = c_x``. **fy is negative**: the paper's model images the world
  mirror-inverted (row follows world X, column world Y, and both flip through the
  lens: a right-handed world comes out left-handed), which no proper rotation can
  express. ``cv2.projectPoints`` handles a negative focal length; tools that assume
  positive ones (e.g. ROS ``image_proc``) do not;
* distortion: the paper's eqs. 7–8 map *distorted* to *undistorted* (``ρ_u = ρ_d·(1 +
  k1 ρ_d² + k2 ρ_d⁴ + k3 ρ_d⁶)``, ρ in mm on the image plane), Brown–Conrady the other
  way, in normalised units (``r = ρ/λ``) — so the paper's k < 0 (edges of the
  undistorted image pulled in: pincushion) becomes K1 > 0. There is no closed form, so
  ``K1, K2, K3`` are fitted by weighted linear least squares over a grid of pixels
  covering the image (weights turn the radial error into pixels), ``p1 = p2 = 0``; the
  fit's residual is measured end to end (paper back-projection → pinhole projection)
  and reported in px.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np

from ovis.common.camera import paper_model as paper
from ovis.common.camera import pinhole
from ovis.common.camera.distortion import on_rising_branch, undistort_factor
from ovis.common.config import CameraModel, CameraParams, PinholeParams

__all__ = [
    "PinholeEquivalent",
    "as_pinhole",
    "export_note",
    "export_summary",
    "paper_to_pinhole",
    "ros_camera_info",
    "write_opencv_yaml",
    "write_ros_yaml",
]

#: Pixels per image side of the grid the distortion is fitted and checked on.
FIT_GRID = 41


class PinholeEquivalent(NamedTuple):
    """A pinhole camera standing for another model, and how well (px over the image)."""

    camera: PinholeParams
    rms_px: float  # RMS reprojection difference over the image grid (0 if exact)
    max_px: float
    exact: bool  # True for a camera that already is a pinhole


def paper_to_pinhole(cam: CameraParams, *, grid: int = FIT_GRID) -> PinholeEquivalent:
    """The pinhole + Brown–Conrady camera equivalent to a paper-model camera (see the
    module docstring), with the fit residual in pixels over the image."""
    lam_cm = float(cam.lam_mm) / paper.CM_TO_MM
    R = paper.rotation_world_cam(cam.theta_deg)
    C_cm = np.array([float(v) for v in paper.camera_centre_mm(cam)]) / paper.CM_TO_MM
    M = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    R_cv = M @ R.T
    t_cv = -R_cv @ C_cm - np.array([0.0, 0.0, lam_cm])
    rvec = cv2.Rodrigues(R_cv)[0].ravel()
    px_per_mm_row = float(cam.s_x) * float(cam.N_fx) / float(cam.d_x_mm)
    px_per_mm_col = float(cam.s_y) * float(cam.N_fy) / float(cam.d_y_mm)
    lam = float(cam.lam_mm)
    fx = px_per_mm_col * lam
    fy = -px_per_mm_row * lam

    # Radial distortion: samples over the image, distorted radius ρ_d (mm) → undistorted.
    rows, cols = np.meshgrid(
        np.linspace(0.0, cam.rows - 1.0, grid), np.linspace(0.0, cam.cols - 1.0, grid)
    )
    x_d = (rows.ravel() - float(cam.c_x)) / px_per_mm_row
    y_d = (cols.ravel() - float(cam.c_y)) / px_per_mm_col
    rho_d = np.hypot(x_d, y_d)
    ok = on_rising_branch(rho_d, cam.k1, cam.k2, cam.k3) & (rho_d > 0)
    rho_u = rho_d * undistort_factor(rho_d, cam.k1, cam.k2, cam.k3)
    r_u, r_d = rho_u[ok] / lam, rho_d[ok] / lam  # normalised (OpenCV) radii
    # Pixel length of a radial error δr at this direction: δr·|(fx·cos φ, fy·sin φ)|,
    # with (cos φ, sin φ) the normalised (x, y) = (y_d, −x_d)/ρ_d direction.
    w = np.hypot(fx * y_d[ok], fy * x_d[ok]) / rho_d[ok]
    A = w[:, None] * r_u[:, None] * np.stack([r_u**2, r_u**4, r_u**6], axis=1)
    b = w * (r_d - r_u)
    if A.shape[0] >= 3 and np.any(A):
        scale = np.maximum(np.abs(A).max(axis=0), 1e-300)
        k = np.linalg.lstsq(A / scale, b, rcond=None)[0] / scale
    else:
        k = np.zeros(3)
    pitch = float(np.sqrt(float(cam.d_x_mm) * float(cam.d_y_mm)))
    equivalent = PinholeParams(
        rows=cam.rows,
        cols=cam.cols,
        fx=fx,
        fy=fy,
        cx=float(cam.c_y),
        cy=float(cam.c_x),
        k1=float(k[0]),
        k2=float(k[1]),
        p1=0.0,
        p2=0.0,
        k3=float(k[2]),
        rvec=(float(rvec[0]), float(rvec[1]), float(rvec[2])),
        tvec_cm=(float(t_cv[0]), float(t_cv[1]), float(t_cv[2])),
        pixel_pitch_mm=pitch,
    )
    rms, worst = reprojection_difference(cam, equivalent, grid=grid)
    return PinholeEquivalent(equivalent, rms, worst, False)


def reprojection_difference(
    cam: CameraModel, other: CameraModel, *, grid: int = FIT_GRID, z_cm: float = 0.0
) -> tuple[float, float]:
    """RMS and max pixel distance between where ``other`` projects the floor points
    that ``cam`` sees at a grid of pixels over its image (plane Z = ``z_cm``)."""
    from ovis.common.camera.projection import back_project, project

    rows, cols = np.meshgrid(
        np.linspace(0.0, cam.rows - 1.0, grid), np.linspace(0.0, cam.cols - 1.0, grid)
    )
    b = back_project(rows.ravel(), cols.ravel(), cam, z_cm)
    q = project(b.x_cm, b.y_cm, z_cm, other)
    ok = b.valid & q.valid
    if not ok.any():
        return float("inf"), float("inf")
    d = np.hypot(q.row - rows.ravel(), q.col - cols.ravel())[ok]
    return float(np.sqrt(np.mean(d**2))), float(d.max())


def as_pinhole(cam: CameraModel) -> PinholeEquivalent:
    """The camera as a pinhole: itself (exact), or the paper model's equivalent."""
    if isinstance(cam, PinholeParams):
        return PinholeEquivalent(cam, 0.0, 0.0, True)
    return paper_to_pinhole(cam)


def write_opencv_yaml(path: Path | str, cam: PinholeParams, *, note: str = "") -> None:
    """Write the camera as OpenCV YAML (``cv2.FileStorage``; see the module docstring)."""
    path = Path(path)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_YAML)
    if not fs.isOpened():
        raise OSError(f"cannot write {path}")
    try:
        fs.writeComment(
            "ovis camera calibration (pinhole + Brown-Conrady, OpenCV conventions: "
            "x = column, y = row; rvec/tvec map world to camera)"
        )
        if note:
            fs.writeComment(note)
        fs.write("image_width", int(cam.cols))
        fs.write("image_height", int(cam.rows))
        fs.write("camera_matrix", pinhole.camera_matrix(cam))
        fs.write("distortion_coefficients", pinhole.distortion_coefficients(cam)[None, :])
        fs.write("rvec", np.array(cam.rvec, dtype=np.float64).reshape(3, 1))
        fs.write("tvec", np.array(cam.tvec_cm, dtype=np.float64).reshape(3, 1))
        fs.write("world_units", "cm")
    finally:
        fs.release()


def ros_camera_info(cam: PinholeParams, camera_name: str = "ovis_camera") -> dict[str, Any]:
    """The ROS ``camera_info`` YAML mapping (``camera_calibration_parsers`` layout)."""
    K = pinhole.camera_matrix(cam)
    P = np.hstack([K, np.zeros((3, 1))])

    def mat(a: np.ndarray) -> dict[str, Any]:
        a = np.atleast_2d(a)
        return {"rows": a.shape[0], "cols": a.shape[1], "data": [float(v) for v in a.ravel()]}

    return {
        "image_width": int(cam.cols),
        "image_height": int(cam.rows),
        "camera_name": camera_name,
        "camera_matrix": mat(K),
        "distortion_model": "plumb_bob",
        "distortion_coefficients": mat(pinhole.distortion_coefficients(cam)[None, :]),
        "rectification_matrix": mat(np.eye(3)),
        "projection_matrix": mat(P),
    }


def write_ros_yaml(
    path: Path | str, cam: PinholeParams, *, camera_name: str = "ovis_camera", note: str = ""
) -> None:
    """Write the ROS ``camera_info`` YAML file."""
    import yaml

    from ovis.common.atomic import write_atomic

    header = "# ovis camera calibration as ROS sensor_msgs/CameraInfo\n"
    if note:
        header += "".join(f"# {line}\n" for line in note.splitlines())
    text = header + yaml.safe_dump(
        ros_camera_info(cam, camera_name), sort_keys=False, default_flow_style=None
    )
    write_atomic(path, text.encode("utf-8"))


def export_note(eq: PinholeEquivalent, source: str) -> str:
    """The comment written into the exported files: where the camera comes from and,
    for a paper-model camera, how well its pinhole equivalent fits."""
    if eq.exact:
        return f"from {source} (pinhole model)"
    return (
        f"from {source}: the paper model's equivalent pinhole; Brown-Conrady fit "
        f"residual over the image RMS {eq.rms_px:.3g} px, max {eq.max_px:.3g} px; "
        "fy < 0: the paper model images the world mirror-inverted"
    )


def export_summary(
    model: str, eq: PinholeEquivalent, *, opencv: Path | None, ros: Path | None
) -> dict[str, Any]:
    """What an export wrote, as plain data (``ovis export --json``)."""
    cam = eq.camera
    return {
        "model": model,
        "exact": eq.exact,
        "fit_rms_px": eq.rms_px,
        "fit_max_px": eq.max_px,
        "camera_matrix": pinhole.camera_matrix(cam).tolist(),
        "distortion_coefficients": pinhole.distortion_coefficients(cam).tolist(),
        "rvec": list(cam.rvec),
        "tvec_cm": list(cam.tvec_cm),
        "opencv": str(opencv) if opencv else None,
        "ros": str(ros) if ros else None,
    }
