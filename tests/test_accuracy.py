"""Honest accuracy (common/calibration/accuracy.py): held-out errors and what the data determine."""

from __future__ import annotations

from pathlib import Path

import msgspec
import numpy as np
import pytest

from ovis.common.calibration.accuracy import (
    arena_world_error,
    assess,
    check_errors,
    floor_error_grid,
    load_checks,
)
from ovis.common.calibration.calibrate import calibrate
from ovis.common.calibration.file import load_calibration, save_calibration
from ovis.common.config import ConfigError, load_config
from ovis.common.sim.arena import Arena, control_points, write_dataset

SEED = 3


@pytest.fixture(scope="module")
def calibrated():
    cfg = load_config()
    cfg = msgspec.structs.replace(cfg, ga=msgspec.structs.replace(cfg.ga, generations=60))
    frame, truth = Arena(cfg, SEED).render()
    points = control_points(truth)
    calib, _ = calibrate(frame, points, cfg)
    report = assess(frame, points, cfg, calib, n_restarts=4)
    return cfg, frame, points, msgspec.structs.replace(calib, accuracy=report)


def test_leave_one_out_is_finite_and_larger_than_in_sample(calibrated) -> None:
    _, _, points, calib = calibrated
    loo = calib.accuracy.leave_one_out
    assert loo.method == "leave-one-out"
    assert [p.name for p in loo.points] == [p.name for p in points]
    px = np.array([p.error_px for p in loo.points])
    cm = np.array([p.error_cm for p in loo.points])
    ins = np.array([p.in_sample_px for p in loo.points])
    assert np.isfinite(px).all() and np.isfinite(cm).all()
    assert px.mean() > ins.mean()  # held out is worse than fitted...
    assert (px >= ins - 1e-9).sum() >= len(points) - 1  # ...for (nearly) every point
    assert loo.mean_px == pytest.approx(px.mean())
    assert 0.0 < loo.mean_cm < 1.0  # still sub-centimetre on the floor
    # A pixel here covers about 0.15 cm of floor: the cm errors follow the px ones.
    assert 0.05 < (cm / px).mean() < 0.4


def test_k_spread_across_restarts_is_large_and_z0_small(calibrated) -> None:
    _, _, _, calib = calibrated
    rep = calib.accuracy
    assert len(rep.restart_seeds) == 4 and all(np.isfinite(rep.restart_dipe_px))
    by = {q.name: q for q in rep.parameters}
    ks = [by[k] for k in ("k1", "k2", "k3")]
    # The k's span a large part of their range across restarts; Z0 stays put.
    assert max(q.restart_spread for q in ks) > 0.5
    assert np.mean([q.restart_spread for q in ks]) > 0.3
    assert by["Z0_cm"].restart_spread < 0.02
    # Sweeping a k over its whole range moves no control point by even 0.01 px.
    assert all(q.sweep_px < 0.01 for q in ks)
    assert not any(q.determined for q in ks) and all(q.standard_error is None for q in ks)
    # Z0 is pinned down to a small fraction of its range.
    assert by["Z0_cm"].determined and by["Z0_cm"].relative_error < 0.02
    assert any("k1, k2, k3: not determined" in n for n in rep.notes)


def test_lambda_trades_off_against_the_scale_factors(calibrated) -> None:
    _, _, _, calib = calibrated
    rep = calib.accuracy
    by = {q.name: q for q in rep.parameters}
    corr = {frozenset((a, b)): c for a, b, c in rep.correlations}
    assert abs(corr[frozenset(("lam_mm", "s_x"))]) > 0.99
    assert abs(corr[frozenset(("lam_mm", "s_y"))]) > 0.99
    # Alone, λ, s_x and s_y are not determined (error larger than their ranges) ...
    for name in ("lam_mm", "s_x", "s_y"):
        assert not by[name].determined and by[name].relative_error > 0.5
    # ... while their sweeps move the points by hundreds of pixels: it is a trade-off.
    assert min(by[n].sweep_px for n in ("lam_mm", "s_x", "s_y")) > 50
    assert rep.condition_all > 1e6 > rep.condition_determined
    assert any("λ trades off against s_x and s_y" in n for n in rep.notes)


def test_accuracy_report_survives_the_calibration_file(calibrated, tmp_path: Path) -> None:
    _, _, _, calib = calibrated
    save_calibration(tmp_path / "c.json", calib)
    back = load_calibration(tmp_path / "c.json")
    assert back.accuracy == calib.accuracy
    assert back.polished == calib.polished and back.ga_dipe_px == calib.ga_dipe_px


def test_check_points_of_a_later_frame(calibrated, tmp_path: Path) -> None:
    cfg, _, _, calib = calibrated
    info = write_dataset(tmp_path, cfg, frames=4, seed=SEED)
    assert info.checks == tmp_path / "checks.toml"
    checks = load_checks(info.checks)
    assert checks.image == tmp_path / "frame_0003.png"
    assert [p.name for p in checks.points] == ["R", "O1", "O2", "O3"]
    frame3, truth3 = list(Arena(cfg, SEED).frames(4))[-1]
    assert [(p.x_cm, p.y_cm) for p in checks.points] == [(o.x_cm, o.y_cm) for o in truth3.objects]
    held = check_errors(frame3, checks.points, calib, source=str(info.checks))
    assert held.missing == [] and len(held.points) == 4
    assert 0.0 < held.mean_px < 2.0 and held.max_cm < 1.0
    # A point where nothing is: reported as missing, not matched to a far blob.
    far = [msgspec.structs.replace(checks.points[0], name="nowhere", x_cm=20.0, y_cm=125.0)]
    assert check_errors(frame3, far, calib).missing == ["nowhere"]
    # One frame: no checks file.
    assert write_dataset(tmp_path / "one", cfg, frames=1, seed=SEED).checks is None


def test_bad_checks_file_is_a_config_error(tmp_path: Path) -> None:
    bad = tmp_path / "c.toml"
    bad.write_text('image = "x.png"\n[[points]]\nname = "A"\nx_cm = 1\n')
    with pytest.raises(ConfigError, match="check-points file"):
        load_checks(bad)
    with pytest.raises(ConfigError, match="does not exist"):
        load_checks(tmp_path / "missing.toml")


def test_world_error_against_the_true_camera() -> None:
    cfg = load_config()
    sim = cfg.simulator
    same = arena_world_error(cfg.camera, cfg.camera, sim.arena_x_cm, sim.arena_y_cm, z_cm=7.0)
    assert same.max() < 1e-9
    off = msgspec.structs.replace(cfg.camera, Z0_cm=cfg.camera.Z0_cm + 1.0)
    err = arena_world_error(off, cfg.camera, sim.arena_x_cm, sim.arena_y_cm, z_cm=7.0)
    assert 0.1 < err.mean() < 5.0
    X, Y, E = floor_error_grid(off, cfg.camera, z_cm=7.0, step_px=16)
    assert X.shape == Y.shape == E.shape == (30, 40)
    assert np.isfinite(E).all() and E.min() > 0
