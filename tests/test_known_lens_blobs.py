"""`ovis calibrate --intrinsics` with blob control points: the lens stays fixed and the GA
finds the camera's pose over the floor (with the threshold and size filter), as the
paper's single-step GA does; checked against the simulated camera's true pose."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
from zenoh_helpers import ovis_cmd

from ovis.common.camera.intrinsics import CameraIntrinsics, write_intrinsics
from ovis.common.camera.pinhole import camera_matrix, distortion_coefficients
from ovis.common.config import load_points, resolve_config


def test_blob_points_with_a_known_lens_give_the_true_pose(tmp_path: Path) -> None:
    arena = tmp_path / "arena"
    subprocess.run(
        ovis_cmd(
            "simulate", "--out", str(arena), "--frames", "1", "--seed", "5", "--preset", "pinhole"
        ),
        check=True,
        capture_output=True,
    )
    truth = resolve_config(None, None, load_points(arena / "points.toml").config).camera
    lens = tmp_path / "cam.yaml"
    write_intrinsics(
        lens,
        CameraIntrinsics(
            width=truth.cols,
            height=truth.rows,
            camera_matrix=tuple(map(tuple, camera_matrix(truth).tolist())),
            dist=tuple(float(x) for x in distortion_coefficients(truth)),
        ),
    )
    out = tmp_path / "calib.json"
    run = subprocess.run(
        ovis_cmd(
            "calibrate",
            str(arena / "frame_0000.png"),
            "--points",
            str(arena / "points.toml"),
            "--intrinsics",
            str(lens),
            "--out",
            str(out),
            "--json",
        ),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr
    calib = json.loads(out.read_text())
    cam = calib["camera"]
    assert calib["dipe_px"] < 0.5
    # The lens is the one given, untouched; the pose is the simulator's.
    assert np.allclose(camera_matrix_of(cam), camera_matrix(truth), atol=1e-9)
    assert np.allclose(cam["rvec"], truth.rvec, atol=0.01)
    assert np.allclose(cam["tvec_cm"], truth.tvec_cm, atol=0.5)


def camera_matrix_of(cam: dict) -> np.ndarray:
    """K of a calibration file's pinhole camera (fields as the file names them)."""
    return np.array([[cam["fx"], 0.0, cam["cx"]], [0.0, cam["fy"], cam["cy"]], [0, 0, 1.0]])
