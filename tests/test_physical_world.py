"""The physical world (MuJoCo): it renders exactly what ovis's camera models project,
its scenes keep their promises, and its truth is the physics state."""

from __future__ import annotations

import math

import cv2
import msgspec
import numpy as np
import pytest
from physical_helpers import skip_module_without_physical

skip_module_without_physical()  # before MuJoCo is imported: without OpenGL its import fails

import mujoco  # noqa: E402

from ovis.common.camera.projection import project  # noqa: E402
from ovis.common.config import load_config  # noqa: E402
from ovis.common.physical.camera import CM_PER_M, render_camera  # noqa: E402
from ovis.common.physical.model import add_camera  # noqa: E402
from ovis.common.physical.rigs import rig  # noqa: E402
from ovis.common.physical.scene import Path, random_scene  # noqa: E402
from ovis.common.physical.world import PhysicalWorld, grey_frame  # noqa: E402


def _dots_render(camera, points_cm: np.ndarray) -> np.ndarray:
    """Camera's frame of small glowing spheres at ``points_cm`` over a black floor,
    through the same camera mapping the physical world uses."""
    r = render_camera(camera)
    spec = mujoco.MjSpec()
    spec.visual.global_.offwidth, spec.visual.global_.offheight = r.canvas
    spec.visual.quality.offsamples = 4
    spec.visual.headlight.active = 0
    spec.add_material(name="glow", emission=1.0, rgba=[1, 1, 1, 1])
    for p in points_cm:
        spec.worldbody.add_geom(
            type=mujoco.mjtGeom.mjGEOM_SPHERE,
            size=[0.006, 0, 0],
            pos=(p / CM_PER_M).tolist(),
            material="glow",
        )
    add_camera(spec, "c", r)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    with mujoco.Renderer(model, r.canvas[1], r.canvas[0]) as renderer:
        return grey_frame(renderer, data, "c", r)


@pytest.mark.parametrize("which", ["paper", "oblique", "overhead"])
def test_rendered_points_land_where_ovis_projects_them(which: str) -> None:
    """Small spheres at random points 0–25 cm above the floor appear, in the rendered
    frame, where ovis's own camera model projects their centres: the paper model (as its
    pinhole equivalent, mirror-imaged) and two pinhole rigs with lens distortion."""
    config = load_config()
    camera = config.camera if which == "paper" else rig(which, config)
    rng = np.random.default_rng(7)
    (x0, x1), (y0, y1) = config.simulator.arena_x_cm, config.simulator.arena_y_cm
    gx, gy = np.meshgrid(np.linspace(x0 + 5, x1 - 5, 5), np.linspace(y0 + 5, y1 - 5, 5))
    pts = np.column_stack(
        [
            gx.ravel() + rng.uniform(-2, 2, 25),
            gy.ravel() + rng.uniform(-2, 2, 25),
            rng.uniform(0.6, 25.0, 25),
        ]
    )
    frame = _dots_render(camera, pts)
    p = project(pts[:, 0], pts[:, 1], pts[:, 2], camera)
    assert p.valid.all()
    n, labels, _stats, _ = cv2.connectedComponentsWithStats((frame > 10).astype(np.uint8))
    assert n - 1 == len(pts)  # one blob per sphere
    found = []
    for k in range(1, n):
        rows, cols = np.nonzero(labels == k)
        w = frame[rows, cols].astype(np.float64)
        found.append(((rows * w).sum() / w.sum(), (cols * w).sum() / w.sum()))
    found = np.array(found)
    d = np.hypot(found[:, None, 0] - p.row[None], found[:, None, 1] - p.col[None])
    seen = d.min(axis=0)
    assert np.median(seen) < 0.06, np.median(seen)
    assert seen.max() < 0.2, seen.max()


def test_a_scene_keeps_every_solid_in_view_apart_and_the_truth_is_the_physics_state() -> None:
    config = load_config()
    camera = rig("oblique", config)
    scene = random_scene(config, 11, [camera])
    assert len([s for s in scene.solids if s.kind == "obstacle"]) == config.physical.n_obstacles
    assert random_scene(config, 11, [camera]) == scene  # deterministic per seed
    assert random_scene(config, 12, [camera]) != scene
    world = PhysicalWorld(scene, config, [camera])
    try:
        for t in np.linspace(0.0, scene.period_s, 9):
            world.set_time(float(t))
            truth = world.truth(0)
            by_id = {o.id: o for o in truth.objects}
            for solid in scene.solids:
                o = by_id[solid.id]
                x, y = solid.path.at(float(t), scene.period_s)
                assert math.hypot(o.x_cm - float(x), o.y_cm - float(y)) < 1e-6
                vx, vy = solid.path.velocity(float(t), scene.period_s)
                assert math.hypot(o.vx_cm_s - float(vx), o.vy_cm_s - float(vy)) < 1e-6
                assert o.z_cm == solid.height_cm
            xy = np.array([[o.x_cm, o.y_cm] for o in truth.objects])
            bound = np.array([s.bound_cm for s in sorted(scene.solids, key=lambda s: s.id)])
            gaps = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1)) - (
                bound[:, None] + bound[None]
            )
            np.fill_diagonal(gaps, np.inf)
            assert gaps.min() >= config.physical.gap_cm - 1e-9
    finally:
        world.close()


def test_frames_are_deterministic_per_seed_and_show_solids_brighter_than_the_floor() -> None:
    config = load_config()
    camera = rig("overhead", config)
    scene = random_scene(config, 5, [camera])
    a = PhysicalWorld(scene, config, [camera])
    b = PhysicalWorld(scene, config, [camera])
    try:
        a.set_time(1.5)
        b.set_time(1.5)
        frame = a.render(45)
        assert np.array_equal(frame, b.render(45))
        assert not np.array_equal(frame, a.render(46))  # another frame's noise
        floor = a.clean(solids=False)
        truth = a.truth(45)
        for o in truth.objects:
            p = project(o.x_cm, o.y_cm, o.z_cm, camera)  # the top face's centre
            r, c = round(float(p.row)), round(float(p.col))
            assert int(frame[r, c]) > int(floor[r, c]) + 40
        visible = a.visible_px()
        assert all(v > 100 for v in visible.values())
        alone = a.alone_px()
        assert alone.keys() == visible.keys()
        assert all(alone[k] >= visible[k] for k in alone)  # others can only hide a solid
        assert np.array_equal(a.render(45), frame)  # and the world is as it was
    finally:
        a.close()
        b.close()


def test_a_still_path_stands_and_a_moving_one_laps_once_per_period() -> None:
    still = Path(cx_cm=10.0, cy_cm=20.0)
    assert still.at(3.0, 20.0) == (10.0, 20.0)
    lap = Path(cx_cm=0.0, cy_cm=0.0, a_cm=5.0, b_cm=3.0, alpha_deg=30.0, phase_deg=40.0)
    x0, y0 = lap.at(0.0, 20.0)
    x1, y1 = lap.at(20.0, 20.0)
    assert math.hypot(float(x1 - x0), float(y1 - y0)) < 1e-9
    # velocity is the derivative of position
    h = 1e-5
    xa, ya = lap.at(7.0 - h, 20.0)
    xb, yb = lap.at(7.0 + h, 20.0)
    vx, vy = lap.velocity(7.0, 20.0)
    assert abs((xb - xa) / (2 * h) - vx) < 1e-6 and abs((yb - ya) / (2 * h) - vy) < 1e-6


def test_a_camera_whose_lens_folds_over_cannot_be_rendered() -> None:
    config = load_config()
    camera = msgspec.structs.replace(rig("oblique", config), k1=-2.0)
    with pytest.raises(ValueError, match="not one-to-one"):
        render_camera(camera)
