"""Plots (common/analysis/plots.py): residual vectors on the frame, world-error map, and
`ovis calibrate` writing them with its accuracy report."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import msgspec
import numpy as np
import pytest

from ovis.common.analysis.plots import plot_convergence, plot_error_map, plot_residuals
from ovis.common.calibration.accuracy import assess
from ovis.common.calibration.calibrate import calibrate
from ovis.common.config import load_config
from ovis.common.sim.arena import Arena, control_points


@pytest.fixture(scope="module")
def calibrated():
    cfg = load_config()
    cfg = msgspec.structs.replace(cfg, ga=msgspec.structs.replace(cfg.ga, generations=50))
    frame, truth = Arena(cfg, 0).render()
    points = control_points(truth)
    calib, _ = calibrate(frame, points, cfg)
    return cfg, frame, points, calib


def _png(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert image is not None and image.size > 0
    return image


def test_residual_vectors(calibrated, tmp_path: Path) -> None:
    cfg, frame, points, calib = calibrated
    m = plot_residuals(frame, calib, tmp_path / "r.png")
    # Default magnification: a 1-2-5 step making the longest arrow ≤ 1/8 of the width.
    longest = max(p.dipe_px for p in calib.points)
    assert m * longest <= cfg.camera.cols / 8 + 1e-9
    assert m * longest > cfg.camera.cols / 8 / 5
    assert m in {k * 10**e for k in (1, 2, 5) for e in range(6)}
    img = _png(tmp_path / "r.png")
    assert img.shape[1] > 600 and img.std() > 10
    # With the leave-one-out report, the held-out arrows are drawn too (and count
    # for the magnification); an explicit magnification is used as given.
    report = assess(frame, points, cfg, calib, n_restarts=0)
    with_loo = msgspec.structs.replace(calib, accuracy=report)
    m2 = plot_residuals(frame, with_loo, tmp_path / "r2.png")
    longest2 = max(longest, max(p.error_px for p in report.leave_one_out.points))
    assert m2 * longest2 <= cfg.camera.cols / 8 + 1e-9
    assert plot_residuals(frame, with_loo, tmp_path / "r3.png", magnify=7) == 7


def test_error_map(calibrated, tmp_path: Path) -> None:
    cfg, _, _, calib = calibrated
    arena = (cfg.simulator.arena_x_cm, cfg.simulator.arena_y_cm)
    mean, worst = plot_error_map(calib, cfg.camera, tmp_path / "e.png", arena=arena)
    assert 0.0 < mean <= worst < 1.0  # a good calibration: sub-centimetre everywhere
    _png(tmp_path / "e.png")
    perfect = msgspec.structs.replace(calib, camera=cfg.camera)
    _, worst0 = plot_error_map(perfect, cfg.camera, tmp_path / "e0.png", arena=arena)
    assert worst0 < 1e-9
    off = msgspec.structs.replace(calib, camera=msgspec.structs.replace(cfg.camera, s_x=0.125))
    mean1, worst1 = plot_error_map(off, cfg.camera, tmp_path / "e1.png")
    assert worst1 > 1.0 and mean1 > mean


def test_convergence_plot_still_works(calibrated, tmp_path: Path) -> None:
    _, _, _, calib = calibrated
    plot_convergence(calib, tmp_path / "c.png")
    _png(tmp_path / "c.png")


def test_calibrate_cli_reports_accuracy_and_writes_plots(tmp_path: Path) -> None:
    def ovis(*args: str) -> subprocess.CompletedProcess[str]:
        proc = subprocess.run(
            [sys.executable, "-m", "ovis.services.cli", *args],
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert proc.returncode == 0, proc.stdout + proc.stderr
        return proc

    sim = tmp_path / "sim"
    out = ovis("simulate", "--out", str(sim), "--frames", "3", "--seed", "2")
    assert "checks.toml" in out.stdout and (sim / "checks.toml").exists()
    proc = ovis(
        "calibrate", str(sim / "frame_0000.png"), "--points", str(sim / "points.toml"),
        "--out", str(sim / "calib.json"), "--check", str(sim / "checks.toml"),
        "--restarts", "1", "--residuals", str(sim / "res.png"),
        "--error-map", str(sim / "err.png"), "--quiet",
    )  # fmt: skip
    text = proc.stdout
    for needle in (
        "GA alone: DIPE",
        "held-out error: leave-one-out",
        "held-out error: check points",
        "what the control points determine",
        "k1, k2, k3: not determined",
        "λ trades off against s_x and s_y",
        "residual vectors, magnified",
        "floor error against the configuration's camera",
    ):
        assert needle in text, text
    calib = json.loads((sim / "calib.json").read_text())
    acc = calib["accuracy"]
    assert acc["check"]["missing"] == [] and len(acc["check"]["points"]) == 4
    assert acc["check"]["max_cm"] < 1.0 and acc["leave_one_out"]["mean_cm"] < 1.0
    assert calib["polished"] is True and calib["dipe_px"] <= calib["ga_dipe_px"]
    _png(sim / "res.png")
    _png(sim / "err.png")
