"""Frame → objects with the true camera: positions, radii, kinds, headings, planner."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest

from ovis.common.analysis.evaluation import match_objects
from ovis.common.config import load_config
from ovis.common.sim.arena import Arena
from ovis.common.vision.frames import ImageError
from ovis.common.world.detection import Detector, find_blobs
from ovis.common.world.planner import planner_inputs


@pytest.fixture(scope="module")
def cfg():
    return load_config()


def _detector(cfg) -> Detector:
    image = msgspec.structs.replace(cfg.image, threshold=120, size_filter_cm2=25.0)
    return Detector(cfg.camera, image, cfg.pose)


def test_true_camera_finds_every_object_to_a_few_millimetres(cfg) -> None:
    arena = Arena(cfg, 3)
    det = _detector(cfg)
    for _ in range(5):
        frame, truth = arena.render()
        found = det.detect(frame)
        acc = match_objects(found.objects, truth.objects)
        assert acc.missed == 0 and acc.spurious == 0 and acc.kind_correct.all()
        assert acc.position_error_cm.max() < 0.3
        assert np.abs(acc.radius_error_cm).max() < 0.3
        robot_true = truth.objects[0]
        robot = next(o for o in found.objects if o.kind == "robot")
        assert robot.id == 0
        # The robot's long axis: heading modulo 180°.
        diff = (robot.heading_deg - robot_true.heading_deg + 90.0) % 180.0 - 90.0
        assert abs(diff) < 3.0
        assert all(o.heading_deg is None for o in found.objects if o.kind == "obstacle")
        arena.step()


def test_planner_entries_match_planner_function(cfg) -> None:
    frame, _ = Arena(cfg, 1).render()
    found = _detector(cfg).detect(frame, goal_xy=(65.0, 115.0))
    robot = next(o for o in found.objects if o.kind == "robot")
    obstacles = [o for o in found.objects if o.kind == "obstacle"]
    expected = planner_inputs(
        (robot.x_cm, robot.y_cm),
        [(o.x_cm, o.y_cm, o.radius_cm) for o in obstacles],
        goal_xy=(65.0, 115.0),
    )
    assert [e.obstacle_id for e in found.planner] == [o.id for o in obstacles]
    np.testing.assert_allclose([e.distance_cm for e in found.planner], expected.distance_cm)
    np.testing.assert_allclose([e.angle_deg for e in found.planner], expected.angle_deg)
    # A goal reference line changes the angles, not the distances.
    line = _detector(cfg).detect(frame, goal_angle_deg=90.0)
    np.testing.assert_allclose([e.distance_cm for e in line.planner], expected.distance_cm)


def test_size_filter_removes_clutter_only(cfg) -> None:
    frame, truth = Arena(cfg, 0).render()
    params = msgspec.structs.replace(cfg.image, threshold=110, size_filter_cm2=0.0)
    raw = find_blobs(frame, params, cfg.camera, cfg.pose.obstacle_height_cm)
    filtered = find_blobs(
        frame,
        msgspec.structs.replace(params, size_filter_cm2=20.0),
        cfg.camera,
        cfg.pose.obstacle_height_cm,
    )
    assert raw.row.size > len(truth.objects)  # clutter and noise specks
    assert filtered.row.size == len(truth.objects)


def test_dark_polarity_finds_dark_objects(cfg) -> None:
    frame, truth = Arena(cfg, 2).render()
    inverted = 255 - frame
    image = msgspec.structs.replace(
        cfg.image, threshold=255 - 120, polarity="dark", size_filter_cm2=25.0, median="ordinary"
    )
    found = Detector(cfg.camera, image, cfg.pose).detect(inverted)
    assert len(found.objects) == len(truth.objects)


def test_bad_frames_are_refused(cfg) -> None:
    det = _detector(cfg)
    with pytest.raises(ImageError):
        det.detect(np.zeros((0, 0), np.uint8))
    with pytest.raises(ImageError):
        det.detect(np.zeros((480, 640), np.float32))
    with pytest.raises(ValueError, match="640x480"):
        det.detect(np.zeros((240, 320), np.uint8))
    # An empty arena is not an error: no objects, no planner inputs.
    empty = det.detect(np.full((480, 640), 60, np.uint8))
    assert empty.objects == [] and empty.planner == []


def test_detect_equals_blobs_then_pose_as_the_services_split_it(cfg) -> None:
    # The label service publishes blobs and pose computes their floor map itself;
    # detect() reuses the one the size filter computed. Same objects, field for field.
    arena = Arena(cfg, 2)
    whole, split = _detector(cfg), _detector(cfg)
    for k in range(3):
        frame, _ = arena.render()
        blobs = find_blobs(frame, split.image, cfg.camera, cfg.pose.obstacle_height_cm)
        assert whole.detect(frame, stamp_s=0.1 * k) == split.from_blobs(blobs, stamp_s=0.1 * k)
        arena.step()


def test_velocities_without_capture_times_are_not_flagged_measured(cfg) -> None:
    """Frames without capture times (taken 1 s apart): velocities, none measured; the
    same frames stamped: every object tracked from the first frame is measured."""
    arena = Arena(cfg, 2)
    frames = []
    for _ in range(3):
        frames.append(arena.render()[0])
        arena.step()
    unstamped, stamped = _detector(cfg), _detector(cfg)
    for k, frame in enumerate(frames):
        guessed = unstamped.detect(frame)
        timed = stamped.detect(frame, stamp_s=0.1 * k)
        assert not any(o.velocity_measured for o in guessed.objects)
        assert all(o.velocity_measured for o in timed.objects) == (k > 0)
    assert any(o.vx_cm_s or o.vy_cm_s for o in guessed.objects)  # moving, 1 s apart


def test_the_floor_on_the_object_side_of_the_threshold_is_not_an_object(cfg) -> None:
    """A threshold below the floor's grey: the floor is one blob touching the border and
    covering most of the frame — the background, not an obstacle (it was one before)."""
    frame, _ = Arena(cfg, 3).render()
    for level in (60, 5):
        image = msgspec.structs.replace(cfg.image, threshold=level, size_filter_cm2=25.0)
        assert Detector(cfg.camera, image, cfg.pose).detect(frame).objects == []


def _components(binary: np.ndarray):
    from ovis.common.vision.labeling import label_components

    return label_components(binary.astype(np.uint8))


def test_background_is_a_border_blob_over_half_the_frame() -> None:
    from ovis.common.vision.objects import background

    frame = np.zeros((40, 50), np.uint8)
    frame[:, :26] = 1  # touches the border, 52 % of the frame
    frame[10:20, 35:45] = 1  # an object
    assert background(_components(frame)).tolist() == [True, False]
    frame[:, 25] = 0  # 50 % exactly: not "more than half"
    assert not background(_components(frame)).any()
    inside = np.zeros((40, 50), np.uint8)
    inside[1:39, 1:49] = 1  # 91 % of the frame, not touching the border: an object
    assert not background(_components(inside)).any()


def test_smallest_object_follows_the_objects_not_the_frame() -> None:
    from ovis.common.vision.objects import MIN_OBJECT_PX, smallest_object_px, typical_area_px

    coins = np.array([1000.0] * 10 + [2000.0] * 5)
    specks = np.array([3.0] * 50 + [60.0] * 5)
    assert typical_area_px(np.concatenate([coins, specks])) == 1000.0  # specks hardly count
    assert smallest_object_px(np.concatenate([coins, specks])) == 50.0
    assert smallest_object_px(np.concatenate([coins * 4, specks])) == 200.0  # 2× closer
    assert smallest_object_px(np.array([100.0, 90.0])) == MIN_OBJECT_PX  # small objects
    assert smallest_object_px(np.zeros(0)) == MIN_OBJECT_PX
