"""`ovis export`: a calibration as OpenCV YAML and ROS camera_info YAML."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ovis.services.cli.errors import UserError
from ovis.services.cli.options import JsonOpt
from ovis.services.cli.ui import console, emit_json

__all__ = ["export", "register"]


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
    json: JsonOpt = False,
) -> None:
    """Export a calibrated camera for OpenCV and ROS.

    A pinhole calibration is written as it is. A paper-model calibration is converted to
    its equivalent pinhole (K, R, t exactly; the paper's distortion, which maps distorted
    to undistorted in mm, fitted by Brown-Conrady k1..k3) and the fit residual over the
    image is printed in px. Note: the paper model's image is mirror-inverted, so its
    equivalent has a negative fy.
    """
    from ovis.common.camera.export import (
        as_pinhole,
        export_note,
        export_summary,
        write_opencv_yaml,
        write_ros_yaml,
    )
    from ovis.common.camera.pinhole import distortion_coefficients

    if opencv is None and ros is None:
        raise UserError("give --opencv FILE and/or --ros FILE")
    calib = _load_camera(calibration)
    eq = as_pinhole(calib.camera)
    cam = eq.camera
    note = export_note(eq, str(calibration))
    for target in (opencv, ros):
        if target is not None and target.is_dir():
            raise UserError(f"{target} is a folder; give a file name")
    if opencv is not None:
        write_opencv_yaml(opencv, cam, note=note)
    if ros is not None:
        write_ros_yaml(ros, cam, camera_name=camera_name, note=note)
    summary = export_summary(calib.camera.model, eq, opencv=opencv, ros=ros)
    if json:
        emit_json(summary)
        return
    con = console()
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


def register(app: typer.Typer) -> None:
    """Add `ovis export` to the `ovis` app."""
    app.command()(export)


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
