"""Several cameras over one arena (issue 19): the camera list in the configuration, the
simulated camera grid, and the pure fusion logic, scored against ground truth."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest

from ovis.common.analysis.multicam import simulate_grid
from ovis.common.camera.projection import back_project, project
from ovis.common.config import ConfigError, FusionConfig, config_from_dict, load_config
from ovis.common.fusion.accuracy import AccuracyMap, position_covariance
from ovis.common.fusion.matching import FrameMatcher
from ovis.common.fusion.merge import Sighting, fuse
from ovis.common.sim.multiview import GridScene, camera_grid, grid_arena

CELL = (100.0, 75.0)
MS = 1_000_000


def _config_with(cameras: list[dict]) -> dict:
    data = msgspec.to_builtins(load_config())
    data["cameras"] = cameras
    return data


# --- configuration ---------------------------------------------------------------------


def test_cameras_in_the_config_are_validated() -> None:
    cam = msgspec.to_builtins(load_config().camera)
    cfg = config_from_dict(
        _config_with(
            [
                {"name": "north", "source": "camera:0", "camera": cam},
                {"name": "south", "source": "rtsp://h/s", "calibration": "south.toml"},
            ]
        )
    )
    assert [c.name for c in cfg.cameras] == ["north", "south"]
    assert cfg.cameras[0].camera == load_config().camera
    assert load_config().cameras == []  # one camera: unchanged
    bad = {
        "repeated": [{"name": "a", "camera": cam}, {"name": "a", "camera": cam}],
        "key chunk": [{"name": "a/b", "camera": cam}],
        "neither": [{"name": "a"}],
        "both": [{"name": "a", "camera": cam, "calibration": "x.toml"}],
    }
    messages = {}
    for what, cameras in bad.items():
        with pytest.raises(ConfigError) as err:
            config_from_dict(_config_with(cameras))
        messages[what] = str(err.value)
    assert "a repeated" in messages["repeated"]
    assert "$.cameras[0].name" in messages["key chunk"]
    assert "exactly one of camera" in messages["neither"]
    assert "exactly one of camera" in messages["both"]
    data = _config_with([])
    data["fusion"] = {"wait_ms": -1.0}
    with pytest.raises(ConfigError, match=r"fusion.wait_ms"):
        config_from_dict(data)


# --- the simulated grid ----------------------------------------------------------------


def test_camera_grid_covers_every_cell_with_overlaps_and_different_cameras() -> None:
    specs = camera_grid(2, 2, cell_cm=CELL, overlap_cm=15.0, seed=7)
    assert [s.name for s in specs] == ["cam00", "cam10", "cam01", "cam11"]
    cams = [s.camera for s in specs]
    assert len({round(c.fx, 3) for c in cams}) == 4  # lenses differ
    assert len({round(c.k1, 5) for c in cams}) == 4
    assert len({c.rvec for c in cams}) == 4  # poses differ
    # the arena's centre is in all four views, each cell's far corner only in its own
    centre = np.array([CELL[0], CELL[1]])
    for cam in cams:
        p = project(centre[0], centre[1], 0.0, cam)
        assert 0 <= p.row <= cam.rows - 1 and 0 <= p.col <= cam.cols - 1
    views = []
    for cam in cams:
        p = project(
            np.array([1.0, 199.0, 1.0, 199.0]), np.array([1.0, 1.0, 149.0, 149.0]), 0.0, cam
        )
        views.append(
            (p.row >= 0) & (p.row <= cam.rows - 1) & (p.col >= 0) & (p.col <= cam.cols - 1)
        )
    assert np.array_equal(np.array(views), np.eye(4, dtype=bool))
    # the shared floor frame: a pixel of one camera back-projects onto the same floor
    # point another camera sees
    for cam in cams:
        q = project(centre[0] + 3.0, centre[1] - 2.0, 7.0, cam)
        x = back_project(q.row, q.col, cam, 7.0)
        assert math.hypot(float(x.x_cm) - centre[0] - 3.0, float(x.y_cm) - centre[1] + 2.0) < 1e-6
    with pytest.raises(ValueError, match="does not cover its cell"):
        camera_grid(2, 2, cell_cm=CELL, overlap_cm=400.0, height_cm=20.0)


def test_grid_scene_has_robots_crossing_cells_and_separated_obstacles() -> None:
    ax, ay = grid_arena(2, 2, CELL)
    scene = GridScene(ax, ay, robots=4, obstacles=10, seed=3)
    first, later = scene.objects(0), scene.objects(300)
    assert [o.id for o in first[:4]] == [1, 2, 3, 4]
    assert [o.marker_id for o in first[:4]] == [0, 1, 2, 3]
    obstacles = [o for o in first if o.kind == "obstacle"]
    assert len(obstacles) == 10
    xy = np.array([[o.x_cm, o.y_cm] for o in obstacles])
    gaps = np.linalg.norm(xy[:, None] - xy[None], axis=-1) + np.eye(10) * 1e9
    assert gaps.min() > 15.0
    cells = {
        (int(o.x_cm // CELL[0]), int(o.y_cm // CELL[1]))
        for f in range(0, 600, 10)
        for o in scene.objects(f)[:4]
    }
    assert cells == {(0, 0), (1, 0), (0, 1), (1, 1)}
    # 30 cm/s at 30 frames/s: the truth's velocity is its displacement per second
    r0, r1 = scene.objects(0)[0], scene.objects(1)[0]
    assert math.hypot(r0.vx_cm_s, r0.vy_cm_s) == pytest.approx(30.0, rel=0.5)
    assert (r1.x_cm - r0.x_cm) * 30 == pytest.approx(r0.vx_cm_s, abs=0.5)
    assert later[0].x_cm != first[0].x_cm


# --- accuracy --------------------------------------------------------------------------


def test_position_covariance_is_what_noisy_pixels_give() -> None:
    """σ² J Jᵀ against the spread of back-projected noisy pixels (Monte Carlo)."""
    cam = camera_grid(2, 2, cell_cm=CELL, seed=1)[0].camera
    rng = np.random.default_rng(0)
    sigma = 0.5
    for x, y in ((50.0, 40.0), (110.0, 85.0)):
        p = project(x, y, 7.0, cam)
        n = 20000
        b = back_project(p.row + rng.normal(0, sigma, n), p.col + rng.normal(0, sigma, n), cam, 7.0)
        empirical = np.cov(np.stack([b.x_cm, b.y_cm]))
        predicted = position_covariance(x, y, 7.0, cam, sigma)[0]
        assert np.allclose(predicted, empirical, rtol=0.06, atol=0.02 * np.abs(predicted).max())
    # a point farther from the camera's foot is seen less sharply
    near = position_covariance(50.0, 40.0, 7.0, cam, sigma)[0]
    far = position_covariance(110.0, 85.0, 7.0, cam, sigma)[0]
    assert np.trace(far) > np.trace(near)
    # a point behind the camera: no weight
    assert np.isinf(np.diag(position_covariance(50.0, 40.0, 500.0, cam, sigma)[0])).all()


def test_the_accuracy_map_is_the_covariance_within_one_percent() -> None:
    cam = camera_grid(2, 2, cell_cm=CELL, seed=2)[3].camera
    rng = np.random.default_rng(4)
    x, y = rng.uniform(90, 200, 300), rng.uniform(60, 150, 300)
    z = np.where(np.arange(300) % 2 == 0, 5.0, 7.0)
    direct = position_covariance(x, y, z, cam, 0.3)
    seen = np.isfinite(direct).all(axis=(1, 2))
    assert seen.sum() > 200
    tabulated = AccuracyMap(cam, 0.3)(x, y, z)
    scale = np.abs(direct[seen]).max(axis=(1, 2))[:, None, None]
    assert (np.abs(tabulated[seen] - direct[seen]) <= 0.01 * scale).all()
    far = AccuracyMap(cam, 0.3)(np.array([1e4]), np.array([1e4]), np.array([7.0]))
    assert np.array_equal(far, position_covariance(1e4, 1e4, 7.0, cam, 0.3))


# --- merging ---------------------------------------------------------------------------


def _s(camera: str, x: float, y: float, var: float, **kw) -> Sighting:
    kw.setdefault("kind", "obstacle")
    kw.setdefault("radius_cm", 5.0)
    return Sighting(camera=camera, x_cm=x, y_cm=y, z_cm=7.0, cov_cm2=(var, 0.0, var), **kw)


def test_fusion_weights_by_accuracy_and_reports_each_object_once() -> None:
    cfg = FusionConfig()
    out = fuse(
        [
            _s("a", 0.0, 0.0, 0.01, kind="robot", marker_id=3, heading_deg=170.0),
            _s("b", 0.5, 0.0, 0.04, kind="robot", marker_id=3, heading_deg=-170.0),
            _s("a", 50.0, 50.0, 0.01),
            _s("b", 50.5, 50.0, 0.04),
            _s("b", 80.0, 50.0, 0.04),
        ],
        cfg,
    )
    assert len(out) == 3
    robot, first, second = out
    # information weights 100 and 25: 0.5 · 25/125
    assert robot.x_cm == pytest.approx(0.1) and robot.marker_id == 3
    assert robot.cameras == ["a", "b"]
    # weights 4:1 (1/trace) on 170° and 190° (= −170°): about 174°, not 0°
    assert robot.heading_deg == pytest.approx(173.96, abs=0.01)
    assert robot.sigma_cm == pytest.approx(math.sqrt(1 / 125))
    assert first.x_cm == pytest.approx(50.1) and first.cameras == ["a", "b"]
    assert second.x_cm == 80.0 and second.cameras == ["b"]


def test_obstacles_are_gated_by_position_size_and_camera() -> None:
    cfg = FusionConfig(gate_sigmas=5.0, gate_floor_cm=1.0, radius_gate_cm=2.0)
    # 0.1 cm sigma each: gate 5·√0.02 + 1 ≈ 1.71 cm
    assert len(fuse([_s("a", 0, 0, 0.01), _s("b", 1.6, 0, 0.01)], cfg)) == 1
    assert len(fuse([_s("a", 0, 0, 0.01), _s("b", 1.8, 0, 0.01)], cfg)) == 2
    # a blurred camera widens its gate
    assert len(fuse([_s("a", 0, 0, 0.01), _s("b", 3.0, 0, 0.25)], cfg)) == 1
    # size disagrees: two objects
    assert len(fuse([_s("a", 0, 0, 0.01), _s("b", 0.5, 0, 0.01, radius_cm=8.0)], cfg)) == 2
    # one camera never sees one object twice
    assert len(fuse([_s("a", 0, 0, 0.01), _s("a", 0.5, 0, 0.01)], cfg)) == 2
    # three cameras, one object; a fourth sighting near only one of them stays apart
    out = fuse(
        [_s("a", 0, 0, 0.01), _s("b", 0.4, 0, 0.01), _s("c", 0.8, 0, 0.01), _s("d", 2.4, 0, 0.01)],
        cfg,
    )
    assert sorted(len(o.cameras) for o in out) == [1, 3]


# --- matching by capture time ----------------------------------------------------------


def test_frames_are_matched_by_capture_time_with_a_wait_and_a_late_count() -> None:
    m: FrameMatcher[str] = FrameMatcher(
        ["a", "b"], window_ns=10 * MS, wait_ns=20 * MS, stale_ns=500 * MS
    )
    assert m.add("a", 0, "a0", now_ns=1 * MS) == []  # waits for b
    (g,) = m.add("b", 2 * MS, "b0", now_ns=3 * MS)
    assert g.items == {"a": "a0", "b": "b0"} and g.stamp_ns == 0
    assert m.next_due_ns() is None  # nothing open: nothing to wake up for
    assert m.add("a", 33 * MS, "a1", now_ns=34 * MS) == []
    assert m.next_due_ns() == 54 * MS  # the service sleeps until then, unless b speaks
    assert m.due(50 * MS) == []
    (g,) = m.due(54 * MS)  # b is 20 ms late: the world frame leaves without it
    assert g.items == {"a": "a1"}
    assert m.add("b", 34 * MS, "b1", now_ns=60 * MS) == []  # too late: counted, dropped
    assert m.late == {"a": 0, "b": 1}
    # b dies: after stale_ns nobody waits for it
    now = 60 * MS
    for k in range(2, 40):
        now = k * 33 * MS + 1 * MS
        out = m.add("a", k * 33 * MS, f"a{k}", now_ns=now)
    assert m.live(now) == ["a"]
    assert [g.items for g in out] == [{"a": "a39"}]  # leaves at once, no wait
    assert m.add("ghost", now, "x", now_ns=now) == [] and m.unknown == 1


def test_frames_leave_in_stamp_order() -> None:
    m: FrameMatcher[str] = FrameMatcher(
        ["a", "b"], window_ns=10 * MS, wait_ns=20 * MS, stale_ns=500 * MS
    )
    m.add("a", 0, "a0", now_ns=0)
    assert m.add("a", 33 * MS, "a1", now_ns=5 * MS) == []  # stamps by another clock
    out = m.add("b", 33 * MS, "b1", now_ns=6 * MS)  # the newer one is complete
    assert [g.stamp_ns for g in out] == [0, 33 * MS]


# --- the whole: simulated 2×2 arena against ground truth -------------------------------


@pytest.mark.parametrize("seed", [101, 202, 303])
def test_fused_world_on_unseen_seeds_meets_the_issue_numbers(seed: int) -> None:
    run = simulate_grid(2, 2, frames=600, seed=seed)
    score = run.world
    assert score.frames == 600
    assert score.duplicates == 0 and score.phantoms == 0 and score.missed == 0
    assert score.identity_swaps == 0
    assert score.handovers >= 20  # robots did cross between views
    assert score.handover_jump_cm <= 1.0
    assert score.world_error_cm_mean <= 0.5
    assert all(c.captured == c.processed == 600 and c.dropped == 0 for c in run.cameras.values())


def test_a_dead_camera_leaves_its_area_uncovered_and_the_rest_flowing() -> None:
    run = simulate_grid(2, 2, frames=200, seed=404, dead="cam11")
    score = run.world
    assert score.frames == 200  # no world frame lost
    assert score.duplicates == 0 and score.identity_swaps == 0 and score.phantoms == 0
    assert score.missed == 0  # what the others see is still reported
    assert run.cameras["cam11"].captured == 100
    assert run.cameras["cam00"].processed == 200
    with pytest.raises(ValueError, match="no camera 'cam99'"):
        simulate_grid(2, 2, frames=1, seed=1, dead="cam99")


def test_per_camera_topics_and_the_world_topic() -> None:
    from ovis.common.messages import Topics

    one = Topics("lab")
    cam = one.of_camera("cam01")
    assert (one.obstacles, one.world) == ("ovis/lab/obstacles", "ovis/lab/world")
    assert cam.obstacles == "ovis/lab/cam/cam01/obstacles"
    assert cam.status("pose") == "ovis/lab/cam/cam01/status/pose"
    assert cam.world == one.world  # one world, whatever camera
    with pytest.raises(ValueError, match="camera name 'a/b'"):
        one.of_camera("a/b")


def test_a_part_of_a_robot_is_no_obstacle_even_while_its_marker_camera_is_late() -> None:
    """A camera that sees a robot cut by its border reports a blob, not the robot: in the
    frame where another camera finds its marker, and in the next frames too, when that
    camera's frame is late, the blob is not taken for an obstacle."""
    from ovis.common.fusion.merge import Sighting
    from ovis.common.fusion.world import WorldFuser

    def seen(camera: str, kind: str, x: float, marker: int | None = None) -> Sighting:
        return Sighting(camera=camera, kind=kind, x_cm=x, y_cm=50.0, z_cm=5.0, radius_cm=9.0
                        if marker is not None else 4.0, cov_cm2=(0.01, 0.0, 0.01),
                        marker_id=marker)  # fmt: skip

    fuser = WorldFuser(["a", "b"], FusionConfig(), stale_ns=10**10)
    ms = 1_000_000
    both = fuser.add("a", 0, [seen("a", "robot", 100.0, marker=2)], 0)
    both += fuser.add("b", 0, [seen("b", "obstacle", 103.0), seen("b", "obstacle", 150.0)], ms)
    late = fuser.add("b", 33 * ms, [seen("b", "obstacle", 104.0), seen("b", "obstacle", 150.0)],
                     34 * ms)  # fmt: skip
    late += fuser.due(34 * ms + 10**9)  # camera a's frame never came
    assert [len(w.objects) for w in both] == [2] and [len(w.objects) for w in late] == [1]
    assert [(t.obj.kind, t.obj.x_cm) for t in both[0].objects] == [
        ("robot", 100.0),
        ("obstacle", 150.0),
    ]
    assert [(t.obj.kind, t.obj.x_cm) for t in late[0].objects] == [("obstacle", 150.0)]
    assert late[0].missing == ["a"] or late[0].cameras == ["b"]
