"""Rendered frames of the simulated camera grid (issue 19): each camera renders the shared
periodic scene through its own model; the real detector finds the objects where the
truth has them; the capture source loops one period on a trigger shared by the grid's
cameras, and keeps the period between runs."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from ovis.common.camera.projection import disks_in_image
from ovis.common.capture.sources import GridSource, SourceError, open_source
from ovis.common.config import load_config
from ovis.common.sim.gridview import PERIOD_FRAMES, GridCamera, grid_scene, parse_grid_source
from ovis.common.sim.scenes import marked_scene
from ovis.common.world.detection import Detector

SEED = 31


@pytest.fixture(scope="module")
def config():
    cfg = marked_scene(load_config(), 4, 10)
    return cfg


def test_the_grid_scene_repeats_exactly_every_period(config) -> None:
    scene = grid_scene(2, 2, config, SEED)
    for f in (0, 17, 299):
        now, later = scene.objects(f), scene.objects(f + PERIOD_FRAMES)
        for a, b in zip(now, later, strict=True):
            assert (a.id, a.marker_id) == (b.id, b.marker_id)
            assert a.x_cm == pytest.approx(b.x_cm, abs=1e-9)
            assert a.y_cm == pytest.approx(b.y_cm, abs=1e-9)
    # and the robots move: one frame apart they are somewhere else
    a, b = scene.objects(0)[0], scene.objects(1)[0]
    assert 0.3 < np.hypot(a.x_cm - b.x_cm, a.y_cm - b.y_cm) < 3.0


@pytest.mark.parametrize("name", ["cam00", "cam11"])
def test_a_grid_camera_renders_what_the_real_detector_finds_where_the_truth_is(
    config, name: str
) -> None:
    cam = GridCamera(config, 2, 2, name, SEED)
    detector = Detector(cam.cam, config.image, config.pose)
    robots_found = obstacles_found = 0
    for f in range(0, PERIOD_FRAMES, 25):
        image, truth = cam.render(f)
        assert image.shape == (480, 640) and image.dtype == np.uint8
        det = detector.detect(image, stamp_s=f / 30)
        by_id = {o.id: o for o in truth.objects}
        for r in det.robots:
            if r.age_s == 0.0:  # seen in this frame
                t = by_id[r.id]
                assert r.marker_id == t.marker_id
                assert np.hypot(r.x_cm - t.x_cm, r.y_cm - t.y_cm) < 0.2
                robots_found += 1
        for o in det.objects:
            whole = disks_in_image(o.x_cm, o.y_cm, o.z_cm, o.radius_cm, cam.cam, 0.5)
            if o.kind != "obstacle" or not whole:
                continue
            err = min(np.hypot(o.x_cm - t.x_cm, o.y_cm - t.y_cm) for t in truth.objects)
            robot_part = min(
                np.hypot(o.x_cm - t.x_cm, o.y_cm - t.y_cm)
                for t in truth.objects
                if t.kind == "robot"
            )
            assert err < 0.2 or robot_part < 9.0  # an obstacle, or part of a robot
            obstacles_found += err < 0.2
    assert robots_found >= 5 and obstacles_found >= 10


def test_bad_grid_sources_say_what_is_expected(config) -> None:
    assert parse_grid_source("grid:2x2:cam01") == (2, 2, "cam01")
    for spec, says in (
        ("grid:2x2", "grid:<columns>x<rows>:cam<i><j>"),
        ("grid:2x2:cam22", "cameras cam00 to cam11"),
        ("grid:9x2:cam00", "1 to 8 each way"),
    ):
        with pytest.raises(SourceError, match=says):
            open_source(spec, config)


def test_grid_sources_share_a_trigger_and_keep_the_period_between_runs(
    config, tmp_path: Path, monkeypatch
) -> None:
    monkeypatch.setenv("OVIS_CACHE", str(tmp_path))
    seen: list[tuple[int, int]] = []
    first = GridSource(config, "grid:2x2:cam10", progress=lambda d, n: seen.append((d, n)))
    assert seen[-1] == (PERIOD_FRAMES, PERIOD_FRAMES) and len(seen) == PERIOD_FRAMES
    assert len(list((tmp_path / "grid").glob("grid-cam10-*.npy"))) == 1
    t0 = time.perf_counter()
    again = GridSource(config, "grid:2x2:cam10")  # from the cache
    from_cache_s = time.perf_counter() - t0
    for (a, ta), (b, tb) in zip(first._frames, again._frames, strict=True):
        assert np.array_equal(a, b) and ta == tb
    assert from_cache_s < 2.0, from_cache_s  # a file read, not 300 renders
    period_ns = round(1e9 / config.service.fps)
    stamps = []
    for _ in range(4):
        image, truth = first.read()
        assert truth.stamp_ns % period_ns == 0  # on the shared trigger
        assert truth.index == (truth.stamp_ns // period_ns) % PERIOD_FRAMES
        assert np.array_equal(image, first._frames[truth.index][0])
        stamps.append(truth.stamp_ns)
    steps = np.diff(stamps) // period_ns
    assert (
        steps >= 1
    ).all() and steps.sum() <= 6  # consecutive triggers (a loaded host may skip one)
