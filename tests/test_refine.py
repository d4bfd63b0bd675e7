"""Hybrid refinement (common/calibration/refine.py): the least-squares polish after the GA,
and local least squares / Levenberg–Marquardt from random starts (common/analysis/compare.py)."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest

from ovis.common.analysis.compare import METHODS, compare_methods, summarise_compare, write_compare
from ovis.common.calibration.accuracy import arena_world_error, calibration_values
from ovis.common.calibration.calibrate import calibrate
from ovis.common.calibration.ga import run_ga
from ovis.common.calibration.problem import INFEASIBLE, CalibrationProblem, camera_with
from ovis.common.calibration.refine import (
    CONTINUOUS_SLICE,
    dipe_of,
    fit_camera,
    matched_blobs,
    polish,
    residuals_px,
)
from ovis.common.camera.paper_model import project
from ovis.common.config import CALIBRATED_VARIABLES, load_config
from ovis.common.sim.arena import Arena, control_points

PAPER_DIPE_MM = 0.735214


def _true_values(cfg, threshold: float = 150.0, size_filter: float = 30.0) -> np.ndarray:
    return np.array(
        [threshold, size_filter] + [getattr(cfg.camera, n) for n in CALIBRATED_VARIABLES[2:]]
    )


def _on_ga_grid(problem: CalibrationProblem, values: np.ndarray, bits: int = 10) -> np.ndarray:
    """The values rounded to the GA's 10-bit grid (what a perfect GA would return)."""
    lo, hi = problem.bounds.T
    steps = 2**bits - 1
    return lo + np.rint((values - lo) / (hi - lo) * steps) / steps * (hi - lo)


@pytest.fixture(scope="module")
def arena_problem():
    cfg = load_config()
    frame, truth = Arena(cfg, 1).render()
    return cfg, CalibrationProblem(frame, control_points(truth), cfg)


def test_polish_never_increases_dipe(arena_problem) -> None:
    cfg, problem = arena_problem
    rng = np.random.default_rng(3)
    true = _true_values(cfg)
    starts = [_on_ga_grid(problem, true)]
    for _ in range(5):  # GA-like starts: a few grid steps off in every variable
        v = true.copy()
        lo, hi = problem.bounds[CONTINUOUS_SLICE].T
        v[CONTINUOUS_SLICE] += rng.integers(-3, 4, size=7) * (hi - lo) / 1023
        starts.append(np.clip(v, problem.bounds[:, 0], problem.bounds[:, 1]))
    ga = run_ga(
        problem.fitness,
        problem.bounds,
        msgspec.structs.replace(cfg.ga, generations=30, seed=2),
        feasible_below=INFEASIBLE,
    )
    starts.append(ga.best_values)
    for start in starts:
        result = polish(problem, start)
        assert result.start_dipe_px == pytest.approx(dipe_of(problem, start)[0])
        assert result.dipe_px <= result.start_dipe_px
        assert problem.evaluate(result.values[None, :]).feasible[0]
        # Threshold and size filter are not touched; the camera stays in its ranges.
        assert result.values[0] == start[0] and result.values[1] == start[1]
        assert np.all(result.values >= problem.bounds[:, 0] - 1e-12)
        assert np.all(result.values <= problem.bounds[:, 1] + 1e-12)
    # From the true camera on the GA's grid the polish gains a lot.
    assert polish(problem, starts[0]).dipe_px < 0.6 * dipe_of(problem, starts[0])[0]


def test_polish_reaches_below_0_1_px_on_noise_free_detections(arena_problem) -> None:
    # Noise-free data: the "blobs" are exactly where the true camera images the points.
    cfg, problem = arena_problem
    true = _true_values(cfg)
    pred = project(*problem.points_xyz.T, cfg.camera)
    start = _on_ga_grid(problem, true)
    start_res = residuals_px(problem, start, pred.row, pred.col).reshape(2, -1)
    assert np.hypot(*start_res).mean() > 0.1  # the GA grid alone is not enough
    fit = fit_camera(problem, start, pred.row, pred.col)
    res = residuals_px(problem, fit.values, pred.row, pred.col).reshape(2, -1)
    assert np.hypot(*res).mean() < 0.01
    # ... and the floor is then right everywhere on the arena.
    cam = camera_with(cfg.camera, fit.values)
    sim = cfg.simulator
    err = arena_world_error(cam, cfg.camera, sim.arena_x_cm, sim.arena_y_cm, z_cm=7.0)
    assert err.max() < 0.01


def test_polish_on_a_noise_free_render() -> None:
    # A clean render (no noise, blur, pepper or clutter) still has blob centroids that
    # are not the images of the top-face centres (perspective, anti-aliasing, lighting):
    # even the true camera is ~0.4 px off; the polish fits those centroids to < 0.2 px.
    cfg = load_config()
    frame, truth = Arena(cfg, 4).render(clean=True)
    problem = CalibrationProblem(frame, control_points(truth), cfg)
    true = _true_values(cfg)
    assert dipe_of(problem, true)[0] > 0.3
    start = _on_ga_grid(problem, true)
    result = polish(problem, start)
    assert result.improved
    assert result.dipe_px < 0.2 < result.start_dipe_px


def test_matched_blobs_refuse_infeasible_values(arena_problem) -> None:
    cfg, problem = arena_problem
    blind = _true_values(cfg, threshold=230.0, size_filter=50.0)
    blind[7:] = 1.0  # a camera that sees the objects at the wrong size
    with pytest.raises(ValueError, match="not one per control point"):
        matched_blobs(problem, blind)


def test_local_least_squares_from_random_starts(arena_problem) -> None:
    # The paper's argument (§1, §5.3): a local method from a poor start gets trapped.
    # Unbounded Levenberg-Marquardt on the GA's objective fails on a measurable share of
    # random starts in the ranges; the same starts bounded to the ranges do not.
    cfg, problem = arena_problem
    blobs = matched_blobs(problem, _true_values(cfg))
    rng = np.random.default_rng(11)
    lo, hi = problem.bounds[CONTINUOUS_SLICE].T
    sim = cfg.simulator
    failed = {"lm": 0, "trf": 0}
    n = 8
    for _ in range(n):
        start = _true_values(cfg)
        start[CONTINUOUS_SLICE] = lo + rng.random(7) * (hi - lo)
        for method in failed:
            fit = fit_camera(problem, start, *blobs, method=method, rematch=True, max_nfev=400)
            r = residuals_px(problem, fit.values, *blobs, rematch=True).reshape(2, -1)
            cam = camera_with(cfg.camera, fit.values)
            err = arena_world_error(cam, cfg.camera, sim.arena_x_cm, sim.arena_y_cm, z_cm=7.0)
            ok = np.hypot(*r).mean() * cfg.camera.d_x_mm < PAPER_DIPE_MM and err.max() < 1.0
            failed[method] += not ok
    assert failed["lm"] >= 2, failed
    assert failed["trf"] == 0, failed


def test_calibration_reports_ga_and_polish() -> None:
    frame_cfg = load_config()
    frame, truth = Arena(frame_cfg, 2).render()
    points = control_points(truth)
    short = msgspec.structs.replace(frame_cfg.ga, generations=40)
    on = msgspec.structs.replace(frame_cfg, ga=msgspec.structs.replace(short, polish=True))
    off = msgspec.structs.replace(frame_cfg, ga=msgspec.structs.replace(short, polish=False))
    a, ra = calibrate(frame, points, on)
    b, rb = calibrate(frame, points, off)
    np.testing.assert_array_equal(ra.best_bits, rb.best_bits)  # the same GA run
    # Both numbers are reported whichever camera is kept.
    assert a.ga_dipe_px == pytest.approx(b.ga_dipe_px)
    assert a.polish_dipe_px == pytest.approx(b.polish_dipe_px)
    assert b.polished is False and b.dipe_px == pytest.approx(b.ga_dipe_px)
    assert a.polished is True and a.dipe_px == pytest.approx(a.polish_dipe_px)
    assert a.dipe_px < b.dipe_px
    # The file's camera is the polished one, and its threshold/size filter the GA's.
    problem = CalibrationProblem(frame, points, on)
    assert dipe_of(problem, calibration_values(a))[0] == pytest.approx(a.dipe_px)
    assert a.image.threshold == b.image.threshold


def test_paper_preset_keeps_the_paper_method_and_default_polishes() -> None:
    assert load_config(preset="paper").ga.polish is False
    assert load_config(preset="default").ga.polish is True


def test_compare_methods_tiny(tmp_path) -> None:
    cfg = load_config()
    cfg = msgspec.structs.replace(cfg, ga=msgspec.structs.replace(cfg.ga, generations=50))
    runs = compare_methods(cfg, arena_seeds=[0], lm_starts=2)
    methods = [r.method for r in runs]
    assert methods.count("ga") == 1 and methods.count("ga+polish") == 1
    assert methods.count("lm") == 2 and methods.count("lm-known") == 2
    summary = {s.method: s for s in summarise_compare(runs)}
    assert set(summary) == set(METHODS)
    ga = next(r for r in runs if r.method == "ga")
    pol = next(r for r in runs if r.method == "ga+polish")
    assert pol.dipe_px <= ga.dipe_px
    assert pol.success and pol.world_max_cm < 1.0
    paths = write_compare(tmp_path, runs, d_mm=cfg.camera.d_x_mm)
    assert paths["plot"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(paths["csv"].read_text().splitlines()) == 1 + len(runs)
    md = paths["markdown"].read_text()
    assert "| ga+polish | 1 | 100 % |" in md
