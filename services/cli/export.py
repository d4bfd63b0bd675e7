"""`ovis export`: a calibration as OpenCV YAML and ROS camera_info YAML."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ovis.services.cli.errors import UserError

__all__ = ["export"]


def export(
    calibration: Annotated[
        Path,
        typer.Argument(
            help="Calibration JSON from `ovis calibrate`, or CAM.yaml from `ovis intrinsics`."
        ),
    ],
    opencv: Annotated[
        Path | None,
        typer.Option(help="Write OpenCV YAML (cv2.FileStorage): K, distortion, rvec, tvec."),
    ] = None,
    ros: Annotated[
        Path | None, typer.Option(help="Write ROS camera_info YAML (plumb_bob).")
    ] = None,
    camera_name: Annotated[str, typer.Option(help="camera_name in the ROS file.")] = (
        "ovis_camera"
    ),
    json: Annotated[bool, typer.Option("--json", help="Print machine-readable JSON.")] = False,
) -> None:
    """Export a calibrated camera for OpenCV and ROS.

    A pinhole calibration is written as it is. A paper-model calibration is converted to
    its equivalent pinhole (K, R, t exactly; the paper's distortion, which maps distorted
    to undistorted in mm, fitted by Brown-Conrady k1..k3) and the fit residual over the
    image is printed in px. Note: the paper model's image is mirror-inverted, so its
    equivalent has a negative fy.
    """
    from ovis.common.camera.export import as_pinhole, write_opencv_yaml, write_ros_yaml
    from ovis.common.camera.pinhole import camera_matrix, distortion_coefficients

    if opencv is None and ros is None:
        raise UserError("give --opencv FILE and/or --ros FILE")
    calib = _load_camera(calibration)
    eq = as_pinhole(calib.camera)
    cam = eq.camera
    if eq.exact:
        note = f"from {calibration} (pinhole model)"
    else:
        note = (
            f"from {calibration}: the paper model's equivalent pinhole; Brown-Conrady fit "
            f"residual over the image RMS {eq.rms_px:.3g} px, max {eq.max_px:.3g} px; "
            "fy < 0: the paper model images the world mirror-inverted"
        )
    for target in (opencv, ros):
        if target is not None and target.is_dir():
            raise UserError(f"{target} is a folder; give a file name")
    if opencv is not None:
        write_opencv_yaml(opencv, cam, note=note)
    if ros is not None:
        write_ros_yaml(ros, cam, camera_name=camera_name, note=note)
    summary = {
        "model": calib.camera.model,
        "exact": eq.exact,
        "fit_rms_px": eq.rms_px,
        "fit_max_px": eq.max_px,
        "camera_matrix": camera_matrix(cam).tolist(),
        "distortion_coefficients": distortion_coefficients(cam).tolist(),
        "rvec": list(cam.rvec),
        "tvec_cm": list(cam.tvec_cm),
        "opencv": str(opencv) if opencv else None,
        "ros": str(ros) if ros else None,
    }
    if json:
        from ovis.services.cli.offline import _emit_json

        _emit_json(summary)
        return
    from rich.console import Console

    con = Console(highlight=False)
    kind = "pinhole (exact)" if eq.exact else "paper model → equivalent pinhole"
    con.print(f"{calibration}: {kind}")
    con.print(f"  fx {cam.fx:.4f}  fy {cam.fy:.4f}  cx {cam.cx:.3f}  cy {cam.cy:.3f} px")
    k = distortion_coefficients(cam)
    con.print("  k1, k2, p1, p2, k3 = " + ", ".join(f"{v:.6g}" for v in k))
    con.print(
        "  rvec "
        + ", ".join(f"{v:.6f}" for v in cam.rvec)
        + " rad; tvec "
        + ", ".join(f"{v:.3f}" for v in cam.tvec_cm)
        + " cm"
    )
    if not eq.exact:
        con.print(
            f"  distortion fit residual over the image: RMS {eq.rms_px:.3g} px, max "
            f"{eq.max_px:.3g} px; fy < 0 (the paper model's image is mirror-inverted)"
        )
    con.print("wrote " + " and ".join(str(p) for p in (opencv, ros) if p is not None))


def _load_camera(path: Path):
    """A calibration JSON, or an OpenCV intrinsics YAML/XML (lens only: identity pose)."""
    from types import SimpleNamespace

    from ovis.common.calibration.file import load_calibration

    if path.suffix.lower() not in (".yaml", ".yml", ".xml"):
        return load_calibration(path)
    from ovis.common.camera.intrinsics import IntrinsicsFileError, read_intrinsics, with_pose

    try:
        return SimpleNamespace(camera=with_pose(read_intrinsics(path)))
    except IntrinsicsFileError as exc:
        raise UserError(str(exc)) from None
