"""Honest results on real data: sizes from the image, implausible calibrations refused,
no truth lines without truth (`ovis up` refusing a real source without a calibration of
its own, and its exit codes: tests/test_up_start.py)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, ovis
from pipeline_helpers import run_up
from real_photos import opencv_corners, photo_paths
from test_floor_pose import OUTER, write_points

# long: minutes of work, started early so the run ends with both workers busy
pytestmark = pytest.mark.long


def test_image_size_comes_from_the_image(tmp_path: Path) -> None:
    """The default preset is 640x480; a 640x512 photo is calibrated at its own size
    (here with chessboard corners as blob points: no camera explains them, exit 3),
    never refused for its size."""
    photo = photo_paths()[0]
    corners = opencv_corners(photo)
    write_points(tmp_path / "pts.toml", corners, OUTER)
    text = (tmp_path / "pts.toml").read_text()
    blob_points = "\n".join(ln for ln in text.splitlines() if not ln.startswith(("row", "col")))
    (tmp_path / "blobs.toml").write_text(blob_points + "\n")
    out = tmp_path / "calib.json"
    proc = ovis(
        "calibrate",
        str(photo),
        "--points",
        str(tmp_path / "blobs.toml"),
        "--out",
        str(out),
        "--quiet",
        "--restarts",
        "0",
        "--generations",
        "5",
        check=False,
    )
    assert_one_line_error(proc)
    assert proc.returncode == 3 and "640x480" not in proc.stderr and not out.exists()


def sim_calibration(data: Path, calib: Path) -> Path:
    """`ovis calibrate` on the first frame of an `ovis simulate` folder."""
    frame, points = str(data / "frame_0000.png"), str(data / "points.toml")
    ovis("calibrate", frame, "--points", points, "--out", str(calib), "--quiet", "--restarts", "0")
    return calib


def test_detect_refuses_a_calibration_of_another_size(tmp_path: Path) -> None:
    data = tmp_path / "sim"
    ovis("simulate", "--out", str(data), "--frames", "1")
    calib = sim_calibration(data, tmp_path / "calib.json")
    proc = ovis("detect", str(photo_paths()[0]), "--calibration", str(calib), check=False)
    assert_one_line_error(proc, "640x512", "640x480")
    assert proc.returncode == 2


def test_implausible_floor_pose_exits_3_unless_forced(tmp_path: Path) -> None:
    photos = photo_paths()
    cam, out = tmp_path / "CAM.yaml", tmp_path / "calib.json"
    ovis("intrinsics", *map(str, photos[1:]), "--board", "chessboard:9x6", "--out", str(cam))
    corners = opencv_corners(photos[0]).astype(np.float64)
    corners[22] += (30.0, 30.0)  # a mis-clicked point: 42 px off
    write_points(tmp_path / "pts.toml", corners, (0, 8, 45, 53, 22))
    args = [
        "calibrate",
        str(photos[0]),
        "--intrinsics",
        str(cam),
        "--points",
        str(tmp_path / "pts.toml"),
        "--out",
        str(out),
    ]
    proc = ovis(*args, check=False)
    assert_one_line_error(proc, "implausible calibration", "mean DIPE", "--force")
    assert proc.returncode == 3 and not out.exists()
    forced = ovis(*args, "--force")
    assert "WARNING (forced)" in forced.stdout and out.exists()
    assert json.loads(out.read_text())["dipe_px"] > 3.0


def test_up_with_a_calibration_processes_a_folder_without_truth(tmp_path: Path) -> None:
    data = tmp_path / "sim"
    ovis("simulate", "--out", str(data), "--frames", "3")
    calib = sim_calibration(data, tmp_path / "calib.json")
    frames = tmp_path / "frames"
    frames.mkdir()
    for f in data.glob("frame_*.png"):
        shutil.copy(f, frames / f.name)
    args = ("--source", str(frames), "--calibration", str(calib))
    code, summary, err, _ = run_up(tmp_path, "--duration", "12", "--fps", "10", *args)
    assert code == 0, (summary, err)
    assert "stored as version 1" in err
    assert summary["frames_processed"] > 0 and summary["calibration_version"] == 1
    assert summary["truth_frames"] == 0
