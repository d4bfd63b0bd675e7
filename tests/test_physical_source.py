"""The physical world as a source and as data: the live source renders each frame from
the physics state at the instant it is stamped with (a frame whose instant passed is
not rendered), the floor marks measured in the empty floor calibrate the camera to
within 0.2 cm anywhere on the floor, the data set is the same for the same seed, and the
grid's cameras see one world. Seeds here were not used to tune anything."""

from __future__ import annotations

import json
import math

import msgspec
import numpy as np
import pytest
from physical_helpers import skip_module_without_physical

skip_module_without_physical()  # before MuJoCo is imported: without OpenGL its import fails

from ovis.common.calibration.floor import solve_floor_pose  # noqa: E402
from ovis.common.camera.projection import back_project, project  # noqa: E402
from ovis.common.capture.physical import PhysicalSource  # noqa: E402
from ovis.common.capture.sources import NoFrameError  # noqa: E402
from ovis.common.config import ControlPoint, OvisConfig, load_config  # noqa: E402
from ovis.common.physical.dataset import write_physical_dataset  # noqa: E402
from ovis.common.physical.grid import PhysicalGridCamera, calibrate_grid_camera  # noqa: E402
from ovis.common.physical.marks import (  # noqa: E402
    calibrate_on_marks,
    empty_floor,
    lens_of,
    measure_marks,
)
from ovis.common.physical.rigs import rig  # noqa: E402
from ovis.common.physical.scene import random_scene  # noqa: E402
from ovis.common.physical.world import PhysicalWorld  # noqa: E402
from ovis.common.pipeline.floor_marks import FloorMarksCalibration, marks_problem  # noqa: E402
from ovis.common.sim.gridview import grid_specs  # noqa: E402


def _config(**physical: object) -> OvisConfig:
    """The physical preset, shadows off unless asked (a render costs less)."""
    cfg = load_config(preset="physical")
    phys = msgspec.structs.replace(cfg.physical, **{"shadows": False, **physical})
    return msgspec.structs.replace(cfg, physical=phys)


def _with(cfg: OvisConfig, *, camera=None, seed: int | None = None, fps: float | None = None):
    service = cfg.service
    if seed is not None:
        service = msgspec.structs.replace(service, seed=seed)
    if fps is not None:
        service = msgspec.structs.replace(service, fps=fps)
    return msgspec.structs.replace(cfg, camera=camera or cfg.camera, service=service)


class _Clock:
    """A capture clock that moves only when slept on, or when told."""

    def __init__(self, start_ns: int) -> None:
        self.now = start_ns

    def __call__(self) -> int:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += round(seconds * 1e9)


def test_the_live_source_shows_each_frame_at_its_stamp_and_misses_the_ones_it_is_late_for():
    cfg = _with(_config(), seed=23, fps=5.0)
    clock = _Clock(1_000_000_000_000)
    start = clock.now
    source = PhysicalSource(cfg, 23, clock=clock, sleep=clock.sleep)
    twin = PhysicalWorld(source.scene, cfg, [cfg.camera])  # renders the same instants
    try:
        shown = []
        for late_s in (0.0, 0.05, 0.3, 0.0):  # rendering took this long after each frame
            image, truth = source.read()
            assert truth is not None and truth.stamp_ns == clock.now
            shown.append(truth.index)
            t = truth.index / 5.0
            assert truth.stamp_ns == start + round(t * 1e9)  # the instant it shows
            for obj, solid in zip(
                sorted(truth.objects, key=lambda o: o.id),
                sorted(source.scene.solids, key=lambda s: s.id),
                strict=True,
            ):
                x, y = solid.path.at(t, source.scene.period_s)
                assert math.hypot(obj.x_cm - float(x), obj.y_cm - float(y)) < 1e-6
                assert obj.z_cm == solid.height_cm
            twin.set_time(t)
            assert np.array_equal(image, twin.render(truth.index))
            clock.sleep(late_s)
        # 0.3 s after frame 2 the instant of frame 3 (0.2 s later) had passed: not rendered
        assert shown == [0, 1, 2, 4]
        assert source.missed == 1
    finally:
        source.close()
        twin.close()


@pytest.mark.parametrize(("which", "seed"), [("oblique", 31), ("overhead", 32)])
def test_the_floor_marks_calibrate_the_camera_to_within_a_fifth_of_a_millimetre_per_cm(
    which: str, seed: int
) -> None:
    """Marks measured in the empty floor, the pose solved with the lens known: floor
    points all over the arena (not the marks) and points 20 cm up are located within
    0.2 cm; the measured pixels are within 0.15 px of where the true camera projects."""
    base = _config()
    cfg = _with(base, camera=rig(which, base), seed=seed)
    floor = empty_floor(cfg)
    points = measure_marks(floor.image, floor.marks, cfg.camera)
    assert len(points) == len(floor.marks) == cfg.physical.floor_marks
    xyz = np.array([[p.x_cm, p.y_cm, p.z_cm] for p in points])
    truth = project(*xyz.T, cfg.camera)
    measured = np.array([[p.row, p.col] for p in points])
    assert np.hypot(truth.row - measured[:, 0], truth.col - measured[:, 1]).max() < 0.15
    calib = calibrate_on_marks(points, cfg.camera, cfg, source="test")
    (x0, x1), (y0, y1) = cfg.simulator.arena_x_cm, cfg.simulator.arena_y_cm
    gx, gy = np.meshgrid(np.linspace(x0 + 5, x1 - 5, 12), np.linspace(y0 + 5, y1 - 5, 10))
    for z in (0.0, 20.0):
        p = project(gx.ravel(), gy.ravel(), np.full(gx.size, z), cfg.camera)
        seen = p.valid & (p.row >= 0) & (p.row <= 479) & (p.col >= 0) & (p.col <= 639)
        b = back_project(p.row[seen], p.col[seen], calib.camera, z)
        err = np.hypot(b.x_cm - gx.ravel()[seen], b.y_cm - gy.ravel()[seen])
        assert seen.sum() > 60 and err.max() < 0.2, (z, err.max())


def test_a_pose_from_points_on_a_plane_above_the_floor() -> None:
    """solvePnP's IPPE takes its plane as z = 0: points all on a plane 3 cm up (a layer
    of marks, a table top) still give the camera (this grid camera's pose was found
    behind its points when they were handed over as they are)."""
    specs = grid_specs(2, 2, load_config(preset="physical"), 0)
    cam = next(s.camera for s in specs if s.name == "cam01")
    rows, cols = np.meshgrid(np.linspace(60, 420, 3), np.linspace(60, 580, 4))
    b = back_project(rows.ravel(), cols.ravel(), cam, 3.0)
    points = [
        ControlPoint(name=f"P{i}", x_cm=x, y_cm=y, z_cm=3.0, row=r, col=c)
        for i, (x, y, r, c) in enumerate(
            zip(b.x_cm, b.y_cm, rows.ravel(), cols.ravel(), strict=True)
        )
    ]
    calib = solve_floor_pose(lens_of(cam), points, image_size=(640, 480))
    assert calib.dipe_max_px < 1e-3
    assert np.allclose(calib.camera.tvec_cm, cam.tvec_cm, atol=1e-3)


def test_the_data_set_is_the_same_for_the_same_seed(tmp_path) -> None:
    cfg = _config()
    a = write_physical_dataset(tmp_path / "a", cfg, 2, 41)
    b = write_physical_dataset(tmp_path / "b", cfg, 2, 41)
    c = write_physical_dataset(tmp_path / "c", cfg, 1, 42)
    for fa, fb in zip(a.frames, b.frames, strict=True):
        assert fa.read_bytes() == fb.read_bytes()
    assert a.frames[0].read_bytes() != c.frames[0].read_bytes()
    assert a.background.read_bytes() == b.background.read_bytes()
    ta, tb = (json.loads(p.read_text()) for p in (a.truth, b.truth))
    assert ta == tb
    scene = random_scene(cfg, 41, [cfg.camera])
    frame = ta["frames"][1]
    assert frame["t_s"] == 1 / cfg.simulator.fps
    assert {o["id"] for o in frame["objects"]} == {s.id for s in scene.solids}
    assert {v["id"] for v in frame["views"]} == {s.id for s in scene.solids}
    assert all(0 < v["visible_share"] <= 1 for v in frame["views"])
    assert len(ta["marks"]) == cfg.physical.floor_marks == a.marks_measured
    assert a.lens is not None and a.lens.is_file()


def test_the_grid_cameras_see_one_world_and_calibrate_on_the_marks_each_sees() -> None:
    cfg = _with(_config(), fps=2.0)
    a = PhysicalGridCamera(cfg, 2, 2, "cam00", 43)
    b = PhysicalGridCamera(cfg, 2, 2, "cam11", 43)
    try:
        assert a.scene == b.scene
        assert a.period == b.period == round(a.scene.period_s * 2.0)
        assert a._truth(7) == b._truth(7)
        calib, floor = calibrate_grid_camera(b)
        assert floor.shape == (480, 640) and len(calib.points) >= 6
        rows, cols = np.mgrid[40:440:40, 40:600:40]  # floor points all over its view
        truth = back_project(rows.ravel(), cols.ravel(), b.cam, 0.0)
        found = back_project(rows.ravel(), cols.ravel(), calib.camera, 0.0)
        assert np.hypot(found.x_cm - truth.x_cm, found.y_cm - truth.y_cm).max() < 0.2
    finally:
        a.close()
        b.close()


def test_the_calibrator_calibrates_a_pinhole_camera_on_the_marks_and_says_why_not_another():
    cfg = _with(_config(), seed=44)
    calib = FloorMarksCalibration(cfg)()
    assert calib.simulated and "floor marks" in calib.source_image
    assert calib.image == cfg.image and calib.dipe_max_px < 0.2
    assert marks_problem(cfg) is None
    paper = msgspec.structs.replace(cfg, camera=load_config().camera)
    assert "pinhole" in (marks_problem(paper) or "")
    with pytest.raises(ValueError, match="pinhole"):
        FloorMarksCalibration(paper)()


def test_the_unplugged_camera_gives_no_frame_while_the_driven_world_runs_on() -> None:
    """The camera's source lost mid-drive: each frame due while unplugged is a
    NoFrameError, the robot's watchdog runs on the world's clock (it stops, and says
    why), and the frame after it is plugged back shows the instant it is due at."""
    cfg = _with(_config(), seed=3, fps=10.0)
    cfg = msgspec.structs.replace(
        cfg, navigation=msgspec.structs.replace(cfg.navigation, drive=True)
    )
    clock = _Clock(1_000_000_000_000)
    source = PhysicalSource(cfg, 3, clock=clock, sleep=clock.sleep)
    try:
        (task,) = source.tasks
        _, truth = source.read()
        source.command(task.id, 15.0, 0.0, truth.stamp_ns)
        _, truth = source.read()
        source.command(task.id, 15.0, 0.0, truth.stamp_ns)
        source.unplugged = True
        for k in range(2, 7):
            with pytest.raises(NoFrameError, match="unplugged"):
                source.read()
            (report,) = source.drives()
            assert report["t_s"] == pytest.approx(k / 10.0)  # the world ran on
        assert report["v_cm_s"] == 0.0 and report["stopped"].startswith("no command for")
        source.unplugged = False
        _, truth = source.read()
        assert truth.index == 7 and truth.stamp_ns == clock.now
    finally:
        source.close()
