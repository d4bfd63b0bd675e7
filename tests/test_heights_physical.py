"""Measured heights in the physical world (issue 36), against MuJoCo's truth on scenes
the method was not tuned on (seeds from 1000; it was tuned on seeds below 1000):
footprints, heights and the robot by one camera; the same through the stages and their
messages; footprints followed over frames of moving solids; the size filter's default."""

from __future__ import annotations

import itertools
import math
import tempfile
import threading
import time
from pathlib import Path

import cv2
import msgspec
import numpy as np
import pytest
from physical_helpers import needs_physical

from ovis.common.analysis.footprints import (
    _detector_config,
    _score,
    evaluate_rig,
    physical_config,
    summarise,
)
from ovis.common.analysis.stated import STATED_CHI2, position_sigma, stated_distance
from ovis.common.calibration.file import calibration_from_config
from ovis.common.config import config_from_dict, load_config
from ovis.common.messages import BinaryFrame, BlobList, Frame, ObstacleFrame, decode, encode
from ovis.common.physical.rigs import rig
from ovis.common.physical.scene import Path as ScenePath
from ovis.common.physical.scene import Solid as SceneSolid
from ovis.common.physical.scene import random_scene
from ovis.common.physical.world import PhysicalWorld
from ovis.common.pipeline.stages import (
    FloorSpots,
    SizeFilter,
    binary_frame,
    blob_list,
    obstacle_frame,
)
from ovis.common.sim.arena import SimObject
from ovis.common.solids.silhouette import Viewpoint, image_moments
from ovis.common.vision.frames import as_gray
from ovis.common.world.detection import DetectedObject, Detector
from ovis.common.world.heights import SolidTracker

pytestmark = needs_physical

UNSEEN = (1000, 1001, 1002)
#: More than this share of an obstacle's silhouette hidden by others: partly hidden.
PARTLY_HIDDEN = 0.2


@pytest.mark.parametrize("rig_name", ["oblique", "overhead"])
def test_footprints_heights_and_the_robot_on_unseen_scenes(rig_name: str) -> None:
    """Issue 36's targets on three unseen scenes per camera: every obstacle found, none
    spurious, none taken for the robot; a measured height within 1 cm of the truth; the
    footprint within 0.5 cm wherever the height is measured and the solid not partly
    hidden (else — near the overhead camera's nadir, short walls seen from above, the
    walls' foot behind another solid — within 1 cm: the footprint then rests on a height
    known only so well), or, where the detection says its position is not measurable
    (its foot wholly hidden behind another solid), within its stated uncertainty (the
    scoring's match, no spurious detection left); the robot found by its size and height
    in every scene, and by its marker."""
    config = load_config()
    for marked in (False, True):
        results = evaluate_rig(config, rig_name, UNSEEN, "measured", marked=marked)
        report = summarise(results, rig_name, "measured", marked=marked)
        assert report.found == report.obstacles > 0
        assert (report.missed, report.as_robot, report.spurious) == (0, 0, 0)
        assert report.robot_scenes == report.scenes
        for s in results:
            for i in range(len(s.found)):
                measured = s.height_source[i] == "one camera"
                if measured:
                    assert abs(s.height_cm[i] - s.true_height_cm[i]) <= 1.0, (s.seed, i)
                if s.position_unmeasurable[i]:
                    continue  # its foot hidden: matched within its stated uncertainty
                # partly hidden (its walls' foot behind another): the footprint rests on
                # the top and the height, as where the height is not measurable
                seen = s.hidden_share[i] <= PARTLY_HIDDEN
                limit = 0.5 if measured and seen else 1.0
                assert s.footprint_error_cm[i] <= limit, (s.seed, i, s.height_source[i])
        if rig_name == "oblique":  # the tripod sees the walls: nearly every height
            assert report.heights_measured >= report.found - 1


def _scene_frames(rig_name: str, seed: int, times: list[float]):
    cfg = physical_config(load_config(), seed)
    camera = rig(rig_name, cfg)
    world = PhysicalWorld(random_scene(cfg, seed, [camera]), cfg, [camera])
    try:
        frames, truths = [], []
        for k, t in enumerate(times):
            world.set_time(t)
            frames.append(world.render(k))
            truths.append(world.truth(k))
        floor = world.clean(solids=False)
    finally:
        world.close()
    return cfg, camera, frames, truths, floor


def _measuring(cfg, floor, folder: Path):
    """The detector's configuration measuring heights against ``floor`` (written into
    ``folder``)."""
    background = folder / "floor.png"
    cv2.imwrite(str(background), floor)
    return _detector_config(cfg, background, "measured")


def _nearest_error(objects, truth) -> list[float]:
    out = []
    for o in objects:
        t = min(truth.objects, key=lambda s: math.hypot(s.x_cm - o.x_cm, s.y_cm - o.y_cm))
        out.append(math.hypot(t.x_cm - o.x_cm, t.y_cm - o.y_cm))
    return out


def _one_frame(world: PhysicalWorld, k: int = 0, t: float = 0.0):
    """The world's frame ``k`` at ``t`` s, its truth and the empty floor (the world then
    closed)."""
    try:
        world.set_time(t)
        return world.render(k), world.truth(k), world.clean(solids=False)
    finally:
        world.close()


def _measured(cfg, camera, image, floor):
    """Detector.detect's objects on ``image``, heights measured against ``floor``, every
    blob fitted."""
    with tempfile.TemporaryDirectory() as tmp:
        dcfg = _measuring(cfg, floor, Path(tmp))
        return Detector(camera, dcfg.image, dcfg.pose).detect(image, stamp_s=0.0, fit_all=True)


def test_the_stages_over_the_wire_measure_what_one_process_measures() -> None:
    """preprocess → label → pose with measured heights, each message encoded and decoded
    between them (the grey frame, the blobs' patches), gives Detector.detect's objects on
    the same physical frame: the same footprints and heights to the last digit (the same
    outlines fitted: the pose stage leaves the floor's marks out of them as the one
    process does), within 0.5 cm of the truth."""
    cfg, camera, (frame_image,), (truth,), floor = _scene_frames("oblique", 1003, [0.0])
    with tempfile.TemporaryDirectory() as tmp:
        dcfg = _measuring(cfg, floor, Path(tmp))
        pose = msgspec.structs.replace(dcfg.pose, fits_per_frame=0)
        calib = msgspec.structs.replace(
            calibration_from_config(dcfg), camera=camera, pose=pose, version=1
        )
        frame = Frame.from_image(frame_image, seq=3, stamp_ns=time.time_ns())
        binary = decode(
            encode(binary_frame(frame, as_gray(frame.image()), calib, spots=FloorSpots())),
            BinaryFrame,
        )
        assert binary.gray is not None
        blobs = decode(encode(blob_list(binary, calib, SizeFilter().min_area_px(calib))), BlobList)
        assert blobs.patches is not None and len(blobs.patches) == len(blobs.blobs)
        detector = Detector(calib.camera, calib.image, calib.pose)
        out = decode(encode(obstacle_frame(blobs, detector, 1, "a", time.time_ns())), ObstacleFrame)
        alone = Detector(calib.camera, calib.image, calib.pose).detect(
            frame_image, stamp_s=0.0, fit_all=True
        )
    staged = sorted(([out.robot] if out.robot else []) + out.obstacles, key=lambda o: o.x_cm)
    direct = sorted(alone.objects, key=lambda o: o.x_cm)
    assert len(staged) == len(direct) == len(truth.objects)
    for a, b in zip(staged, direct, strict=True):
        assert (a.kind, a.shape, a.z_source) == (b.kind, b.shape, b.z_source)
        assert (a.x_cm, a.y_cm, a.z_cm) == pytest.approx((b.x_cm, b.y_cm, b.z_cm), abs=1e-9)
    assert max(_nearest_error(staged, truth)) < 0.5
    assert all(o.z_source == "one camera" for o in staged)


def test_footprints_follow_moving_solids_with_one_fit_per_frame() -> None:
    """Thirty frames (1 s) of a scene whose obstacles move, one full fit per frame (the
    live stage's default): once each blob has had its fit, every frame's footprints are
    within 0.5 cm of where the solids stand, and the heights within 1 cm."""
    times = [k / 30.0 for k in range(30)]
    cfg, camera, frames, truths, floor = _scene_frames("oblique", 1004, times)
    with tempfile.TemporaryDirectory() as tmp:
        dcfg = _measuring(cfg, floor, Path(tmp))
        assert dcfg.pose.fits_per_frame == 1
        detector = Detector(camera, dcfg.image, dcfg.pose)
        pending = []
        for k, (image, truth) in enumerate(zip(frames, truths, strict=True)):
            det = detector.detect(image, stamp_s=times[k])
            waiting = [o for o in det.objects if o.z_unmeasured == "pending"]
            pending.append(len(waiting))
            if k < len(truth.objects):
                continue
            assert not waiting, k
            errors = _nearest_error(det.objects, truth)
            assert max(errors) < 0.5, (k, errors)
            for o in det.objects:
                t = min(truth.objects, key=lambda s: math.hypot(s.x_cm - o.x_cm, s.y_cm - o.y_cm))
                if o.z_source == "one camera":
                    assert abs(o.z_cm - t.z_cm) <= 1.0
    assert 0 < pending[0] < len(truths[0].objects)  # one blob fitted in the first frame
    assert all(b <= a for a, b in itertools.pairwise(pending))
    assert pending[-1] == 0


def test_fits_beside_the_frames_measure_what_fits_in_them_measure() -> None:
    """The live stage's fits on a thread of their own (the frames going on meanwhile)
    measure the solids as fits in the frames do (one per frame), the same heights and
    footprints; a blob waiting for its fit is found all the same, its footprint roughly
    (within 4 cm, from its outline's side facing the camera's foot), said pending at the
    configured height, with the covariance of where its footprint may be (the truth
    within its 99 % ellipse)."""
    times = [k / 5.0 for k in range(12)]
    cfg, camera, frames, truths, floor = _scene_frames("oblique", 1005, times)
    with tempfile.TemporaryDirectory() as tmp:
        dcfg = _measuring(cfg, floor, Path(tmp))
        inline = Detector(camera, dcfg.image, dcfg.pose)
        beside = Detector(camera, dcfg.image, dcfg.pose, background_fits=True)
        assert beside.solids is not None
        waited = 0
        try:
            for image, truth, t in zip(frames, truths, times, strict=True):
                a = inline.detect(image, stamp_s=t).objects
                b = beside.detect(image, stamp_s=t).objects
                beside.solids.wait()  # the next frame takes the fit in, as a slow live one
                assert len(a) == len(b) == len(truth.objects)
                rough = [o for o in b if o.z_unmeasured == "pending"]
                waited += len(rough)
                assert all(o.z_source == "configured" for o in rough)
                assert all(o.z_cm == dcfg.pose.obstacle_height_cm for o in rough)
                assert max(_nearest_error(rough, truth), default=0.0) < 4.0
                for o in rough:  # where it may be, stated: the truth within its 99 %
                    t = min(
                        truth.objects, key=lambda s: math.hypot(s.x_cm - o.x_cm, s.y_cm - o.y_cm)
                    )
                    cov = np.array(o.covariance_cm2).reshape(3, 3)
                    e = np.array([t.x_cm - o.x_cm, t.y_cm - o.y_cm])
                    assert e @ np.linalg.solve(cov[:2, :2], e) <= STATED_CHI2
                    assert cov[2, 2] > 5.0**2  # its height: anywhere within a fit's range
        finally:
            beside.close()
    assert waited > 0
    assert not [o for o in a + b if o.z_unmeasured == "pending"]
    for p, q in zip(sorted(a, key=lambda o: o.x_cm), sorted(b, key=lambda o: o.x_cm), strict=True):
        assert (p.kind, p.shape, p.z_source) == (q.kind, q.shape, q.z_source)
        assert math.hypot(p.x_cm - q.x_cm, p.y_cm - q.y_cm) < 0.05
        assert p.z_cm == pytest.approx(q.z_cm, abs=0.05)
    assert max(_nearest_error(b, truths[-1])) < 0.5


def test_new_blobs_fits_queue_at_once_and_join_where_their_blobs_went_meanwhile() -> None:
    """At start-up every new blob's fit is queued on the fitting thread at once (the
    thread goes from one to the next, not one a frame): held back while twelve frames at
    5 frames/s go by (2.4 s, the obstacles moving up to 11 cm), each fit joins the solids
    where its blob stands by then, so that the next frame has nothing pending, every
    obstacle within 0.5 cm and nothing found twice. A new calibration cancels the fits
    still queued."""
    times = [k / 5.0 for k in range(14)]
    cfg, camera, frames, truths, floor = _scene_frames("oblique", 1005, times)
    moved = [
        math.hypot(a.x_cm - b.x_cm, a.y_cm - b.y_cm)
        for a, b in zip(truths[0].objects, truths[12].objects, strict=True)
    ]
    assert max(moved) > 10.0  # the blobs move while their fits wait
    with tempfile.TemporaryDirectory() as tmp:
        dcfg = _measuring(cfg, floor, Path(tmp))
        beside = Detector(camera, dcfg.image, dcfg.pose, background_fits=True)
        assert beside.solids is not None and beside.solids._pool is not None
        hold = threading.Event()
        held = beside.solids._pool.submit(hold.wait)  # the fitting thread busy meanwhile
        try:
            for image, t in zip(frames[:12], times[:12], strict=True):
                objects = beside.detect(image, stamp_s=t).objects
                assert all(o.z_unmeasured == "pending" for o in objects)
            queued = [job.done for job in beside.solids._jobs]
            assert len(queued) == len(truths[0].objects)  # every blob's at once
            hold.set()
            held.result()
            beside.solids.wait()
            beside.detect(frames[12], stamp_s=times[12])  # the fits join
            objects = beside.detect(frames[13], stamp_s=times[13]).objects
            hold.clear()  # a new calibration: the fits queued behind a running one are not run
            held = beside.solids._pool.submit(hold.wait)
            beside.detect(frames[0], stamp_s=times[13] + 0.2)
            queued = [job.done for job in beside.solids._jobs]
            beside.solids.reconfigure(camera, dcfg.image, dcfg.pose)
            assert queued and all(done.cancelled() for done in queued)
        finally:
            hold.set()
            beside.close()
    assert len(objects) == len(truths[13].objects)
    assert not [o for o in objects if o.z_unmeasured == "pending"]
    assert max(_nearest_error(objects, truths[13])) < 0.5


def test_the_default_size_filter_keeps_a_3_cm_cylinder_seen_from_the_tripod() -> None:
    """A 3 cm-radius cylinder, 1 to 25 cm tall, anywhere on issue 36's arena seen from
    the 140 cm tripod: its blob's area on the 7 cm plane (configured heights) and on
    the floor (measured) is above the default presets' size filter."""
    config = load_config()
    camera = rig("oblique", physical_config(config, 0))
    view = Viewpoint.of(camera)
    from ovis.common.camera.projection import pixel_footprint_cm2

    xs, ys = np.meshgrid(np.linspace(5, 145, 8), np.linspace(5, 115, 7))
    for h in (1.0, 7.0, 25.0):
        theta = np.column_stack(
            [xs.ravel(), ys.ravel(), np.full(xs.size, 3.0), np.full(xs.size, h)]
        )
        area, row, col = image_moments("cylinder", theta, view, camera)
        for plane in (7.0, 0.0):
            cm2 = area * pixel_footprint_cm2(row, col, camera, plane)
            assert cm2.min() > config.image.size_filter_cm2, (h, plane, cm2.min())
    assert load_config(preset="pinhole").image.size_filter_cm2 == config.image.size_filter_cm2


def test_a_refit_after_the_robot_turned_finds_it_where_it_stands() -> None:
    """A known solid is fitted again every so often; the robot turns as it drives, so a
    refit started from its old yaw alone can settle in a wrong valley, and a fresh one
    can leave its height free (seed 52's robot, frames as two live runs kept them: a
    loaded one, its refit landing at 13.8 s, and one from the third frame on, its refit
    on the 62nd frame, where the turned robot's fresh fit is a thin wall 15 cm tall that
    explains the outline better than the robot does, and held at the configured 7 cm
    it stood 1 cm off, an obstacle). After that refit its footprint is still within
    0.5 cm of the truth, and it is still the robot."""
    runs = {
        "loaded": sorted(set(range(78)) - {1, 3, 6, 8, 10, 12, 15, 17, 35}),
        "late start": list(range(2, 75)),
    }
    cfg = load_config(preset="physical")
    world = PhysicalWorld(random_scene(cfg, 52, [cfg.camera]), cfg, [cfg.camera])
    yaws: dict[str, list[float]] = {name: [] for name in runs}
    errors: dict[str, list[float]] = {name: [] for name in runs}
    kinds: dict[str, list[str]] = {name: [] for name in runs}
    try:
        floor = world.clean(solids=False)
        with tempfile.TemporaryDirectory() as tmp:
            dcfg = _measuring(cfg, floor, Path(tmp))
            # as the pose stage fits: one blob at a time beside the frames (each fit
            # waited for here, so that the order of the fits is the same every run)
            detectors = {
                name: Detector(cfg.camera, dcfg.image, dcfg.pose, background_fits=True)
                for name in runs
            }
            for k in sorted(set().union(*runs.values())):
                t = k / 5.0
                world.set_time(t)
                image, truth = world.render(k), world.truth(k)
                robot = next(o for o in truth.objects if o.kind == "robot")
                for name, detector in detectors.items():
                    if k not in runs[name]:
                        continue
                    det = detector.detect(image, stamp_s=t)
                    detector.solids.wait()
                    yaws[name].append(robot.heading_deg)
                    found = [o for o in det.objects if o.z_source == "one camera"]
                    near = [math.hypot(o.x_cm - robot.x_cm, o.y_cm - robot.y_cm) for o in found]
                    errors[name].append(min(near, default=math.inf))
                    kinds[name].append(found[int(np.argmin(near))].kind if near else "")
            for detector in detectors.values():
                detector.close()
    finally:
        world.close()
    for name in runs:
        turned = abs((yaws[name][-1] - yaws[name][0] + 90.0) % 180.0 - 90.0)
        assert turned > 20.0  # the robot did turn (a box's yaw, modulo its half turn)
        # from the refit (the 60th frame) on
        assert max(errors[name][59:]) < 0.5, (name, errors[name][59:])
        assert set(kinds[name][59:]) == {"robot"}, (name, kinds[name][59:])


@pytest.mark.parametrize("rig_name", ["oblique", "overhead"])
def test_the_blob_most_like_the_robot_is_fitted_first(rig_name: str) -> None:
    """One fit per frame (the live stage's default): the first frame's one fit goes to
    the blob the configured robot's box fits best, so the unmarked robot is reported as
    the robot from the first frame on, not as an obstacle until its turn (largest blob
    first left it pending on these scenes)."""
    for seed in (1008, 1009):
        cfg, camera, (image,), (truth,), floor = _scene_frames(rig_name, seed, [0.0])
        with tempfile.TemporaryDirectory() as tmp:
            dcfg = _measuring(cfg, floor, Path(tmp))
            assert dcfg.pose.fits_per_frame == 1
            objects = Detector(camera, dcfg.image, dcfg.pose).detect(image, stamp_s=0.0).objects
        assert sum(o.z_unmeasured == "pending" for o in objects) == len(objects) - 1
        (robot,) = [o for o in objects if o.kind == "robot"]
        (true,) = [o for o in truth.objects if o.kind == "robot"]
        assert math.hypot(robot.x_cm - true.x_cm, robot.y_cm - true.y_cm) < 0.5, seed


def test_a_marked_robot_whose_marker_is_not_read_is_found_by_its_size() -> None:
    """A marked robot whose marker cannot be read (here: it carries another marker than
    the one configured, so its own is an unknown one) is still the robot: the one box
    of the configured robot's size and height, reported with the configured robot's id
    at its footprint."""
    seed = 1000
    cfg = physical_config(load_config(), seed, marked=True)
    camera = rig("oblique", cfg)
    world = PhysicalWorld(random_scene(cfg, seed, [camera]), cfg, [camera])
    image, truth, floor = _one_frame(world)
    with tempfile.TemporaryDirectory() as tmp:
        data = msgspec.to_builtins(_measuring(cfg, floor, Path(tmp)))
        (spec,) = data["pose"]["robots"]
        shown, spec["marker_id"] = spec["marker_id"], spec["marker_id"] + 2
        dcfg = config_from_dict(data, "marker not the robot's")
        det = Detector(camera, dcfg.image, dcfg.pose).detect(image, stamp_s=0.0, fit_all=True)
    assert [u.marker_id for u in det.unknown_markers] == [shown]
    (robot,) = [o for o in det.objects if o.kind == "robot"]
    (true,) = [o for o in truth.objects if o.kind == "robot"]
    assert robot.id == spec["id"]
    assert math.hypot(robot.x_cm - true.x_cm, robot.y_cm - true.y_cm) < 0.5
    assert len(det.objects) == len(truth.objects)


#: Boxes lower than the tripod can see walls of, each with a face toward it (x, y, height,
#: length, width, yaw), placed in seed LOW_SEED's room.
LOW_SEED = 4100
LOW_BOXES = [
    (40.0, 75.0, 1.2, 10.7, 5.8, 8.0),
    (100.0, 80.0, 1.1, 11.0, 5.0, -6.0),
    (70.0, 105.0, 1.3, 12.0, 6.0, 4.0),
]


def test_low_boxes_seen_side_on_are_held_no_taller_than_their_walls_show() -> None:
    """Boxes 1–1.6 cm tall, a face toward the tripod: their walls are too thin in the
    frame for their tops' edges to show, so the outline alone leaves the height free
    (not measurable). Held at the configured 7 cm their footprints slid centimetres
    toward the camera; at that height their tops' edges would show and do not, so they
    are held no taller than walls too thin to show: footprints within 0.5 cm, heights
    said not measurable (the configured one reported) or measured within 1 cm."""
    cfg = physical_config(load_config(), LOW_SEED)
    camera = rig("oblique", cfg)
    room = random_scene(cfg, LOW_SEED, [camera])
    boxes = [
        SceneSolid(
            id=k + 1,
            kind="obstacle",
            shape="box",
            height_cm=h,
            radius_cm=math.sqrt(length * width / math.pi),
            length_cm=length,
            width_cm=width,
            yaw_deg=yaw,
            path=ScenePath(cx_cm=x, cy_cm=y),
        )
        for k, (x, y, h, length, width, yaw) in enumerate(LOW_BOXES)
    ]
    world = PhysicalWorld(msgspec.structs.replace(room, solids=boxes), cfg, [camera])
    image, truth, floor = _one_frame(world)
    objects = _measured(cfg, camera, image, floor)
    assert len(objects.objects) == len(boxes)
    for o in objects.objects:
        t = min(truth.objects, key=lambda s: math.hypot(s.x_cm - o.x_cm, s.y_cm - o.y_cm))
        assert math.hypot(o.x_cm - t.x_cm, o.y_cm - t.y_cm) < 0.5, (t.z_cm, o.z_source)
        if o.z_source == "one camera":
            assert abs(o.z_cm - t.z_cm) <= 1.0
        else:
            assert (o.z_unmeasured, o.z_cm) == ("not measurable", cfg.pose.obstacle_height_cm)


def test_a_box_seen_at_a_corner_is_fitted_as_a_box_where_its_radial_sides_mislead() -> None:
    """The physical preset's seed 52 at 2.6 s (frame 13 of `ovis up`'s 5 frames/s): a box
    seen at a corner, whose outline's radial sides give a height far under its own, so
    every shape started there lands in a wrong valley (it was fitted as a six-sided
    prism, many edge points off its silhouette). Fitted again from every height start,
    it is a box: every solid of the frame measured within 1 cm, its footprint within
    0.5 cm."""
    cfg = load_config(preset="physical")
    scene = random_scene(cfg, 52, [cfg.camera])
    world = PhysicalWorld(scene, cfg, [cfg.camera])
    image, truth, floor = _one_frame(world, 13, 13 / cfg.service.fps)
    objects = _measured(cfg, cfg.camera, image, floor)
    assert len(objects.objects) == len(truth.objects)
    for o in objects.objects:
        t = min(truth.objects, key=lambda s: math.hypot(s.x_cm - o.x_cm, s.y_cm - o.y_cm))
        assert o.z_source == "one camera" and abs(o.z_cm - t.z_cm) <= 1.0, (t.id, o.shape)
        assert math.hypot(o.x_cm - t.x_cm, o.y_cm - t.y_cm) < 0.5, t.id

    def boxes(solids) -> int:
        return sum(1 for s in solids if s.kind == "obstacle" and s.shape == "box")

    assert boxes(objects.objects) == boxes(scene.solids) > 0


def _pair_alone(seed: int, ids: tuple[int, int]):
    """Seed ``seed``'s two solids ``ids`` alone in its room (one blob to fit), seen by
    the tripod: the detections (heights measured) and the truth."""
    cfg = physical_config(load_config(), seed)
    camera = rig("oblique", cfg)
    room = random_scene(cfg, seed, [camera])
    pair = [s for s in room.solids if s.id in ids]
    world = PhysicalWorld(msgspec.structs.replace(room, solids=pair), cfg, [camera])
    image, truth, floor = _one_frame(world)
    return _measured(cfg, camera, image, floor).objects, truth.objects


def test_a_solid_behind_another_in_line_with_the_tripod_is_told_apart() -> None:
    """Solids behind others in line with the tripod, from seeds not tuned on. Seed
    3109's 25 cm box with a 22 cm box behind it, their sides in line, the near one's top
    hiding the far one's foot: the outline does not turn inward, and one long box was
    fitted to both (many edge points off it; the near box missed). Cut across the line
    of sight, the near box is found within 0.5 cm, its height measured within 1 cm; the
    far one, its foot hidden, is not measurable. Seed 3104's 19.5 cm cylinder whose foot
    is hidden behind a 24 cm box shows only its top (its height free along the line of
    sight): it was said measured, too low, pinned by the blurred corner where its wall
    meets the box's edge; now not measurable, the box measured."""
    found, truth = _pair_alone(3109, (6, 8))
    near, far = truth
    assert (near.z_cm, far.z_cm) == pytest.approx((25.0, 22.02), abs=0.01)
    assert len(found) == 2
    box = min(found, key=lambda o: math.hypot(o.x_cm - near.x_cm, o.y_cm - near.y_cm))
    assert math.hypot(box.x_cm - near.x_cm, box.y_cm - near.y_cm) <= 0.5
    assert box.z_source == "one camera" and abs(box.z_cm - near.z_cm) <= 1.0
    (behind,) = [o for o in found if o is not box]
    assert behind.z_unmeasured == "not measurable"
    _within_its_bounds(behind, far)

    found, truth = _pair_alone(3104, (4, 6))
    front, cylinder = truth
    assert (front.z_cm, cylinder.z_cm) == pytest.approx((24.08, 19.46), abs=0.01)
    assert len(found) == 2
    for o in found:
        t = min(truth, key=lambda s: math.hypot(s.x_cm - o.x_cm, s.y_cm - o.y_cm))
        if t is front:
            assert o.z_source == "one camera" and abs(o.z_cm - t.z_cm) <= 1.0
        else:
            assert o.z_unmeasured == "not measurable"
            _within_its_bounds(o, cylinder)


def _within_its_bounds(found: DetectedObject, truth: SimObject) -> None:
    """A solid whose foot is hidden behind another is placed between the bounds the other
    sets (its footprint clear of the other's, its foot within the other's silhouette),
    its stated covariance spread over them: the truth within it (99 %), and a stated 1σ
    no wider than such a stretch allows (stretch / √12; a 25 cm solid 150 cm from the
    camera's foot, 140 cm up, has a silhouette reaching 33 cm beyond its footprint: at
    most 10 cm). It used to stay where the joint fit's start put it, its stated σ
    far wider than the stretch."""
    assert stated_distance(found, truth.x_cm, truth.y_cm) <= STATED_CHI2
    assert position_sigma(found) <= 10.0


def test_a_position_not_measurable_is_scored_within_its_stated_uncertainty() -> None:
    """The sweep's scoring: a detection whose stated footprint uncertainty is wide (a
    solid whose foot is hidden behind another) and that lies beyond the 5 cm gate is
    matched to the true object its covariance covers (99 %, at most 20 cm off), counted
    in a row of its own, not spurious; one that states a narrow uncertainty, whose truth
    lies beyond the cap, or that states a 1σ over 10 cm, is still spurious."""

    def detection(k: int, x: float, y: float, sx: float, sy: float) -> DetectedObject:
        cov = [sx * sx, 0.0, 0.0, 0.0, sy * sy, 0.0, 0.0, 0.0, 1.0]
        return DetectedObject(
            k, "obstacle", 0.0, 0.0, 100.0, 40.0, 1.0, x, y, 7.0, 3.0, 28.0, covariance_cm2=cov
        )

    def solid(k: int, x: float, y: float) -> SimObject:
        return SimObject(
            id=k, kind="obstacle", x_cm=x, y_cm=y, z_cm=20.0, radius_cm=3.0,
            heading_deg=0.0, shape="disk", length_cm=6.0, width_cm=6.0,
        )  # fmt: skip

    truth = [solid(1, 10, 10), solid(2, 50, 50), solid(3, 90, 90), solid(4, 120, 20)]
    truth.append(solid(5, 20, 120))
    found = [
        detection(0, 10.1, 10.0, 0.2, 0.2),  # within the gate
        detection(1, 50.0, 62.0, 0.3, 8.0),  # 12 cm off, 1.5 σ along its wide axis
        detection(2, 90.0, 102.0, 0.3, 0.3),  # 12 cm off, saying 0.3 cm
        detection(3, 120.0, 45.0, 0.3, 30.0),  # within 1 σ, but 25 cm off
        detection(4, 20.0, 112.0, 0.3, 12.0),  # 8 cm off, saying 12 cm: too vague
    ]
    everyone = {k: 100 for k in range(1, 6)}
    scene = _score(0, found, truth, everyone, everyone, 0.0)
    assert scene.found == [True, True, False, False, False]
    assert (scene.spurious, scene.unmeasurable, scene.unmeasurable_within) == (3, 3, 1)
    assert scene.position_unmeasurable == [False, True, False, False, False]
    report = summarise([scene], "oblique", "measured")
    assert report.footprint_max_cm == pytest.approx(0.1)  # the 12 cm one kept apart
    assert report.unmeasurable_error_max_cm == pytest.approx(12.0)
    assert (report.positions_unmeasurable, report.positions_within_stated) == (3, 1)


def test_a_footprint_on_a_height_not_measured_is_within_what_it_states() -> None:
    """Unseen straight-down scenes whose solids' heights are not measurable there: low
    solids far from the nadir (seeds 1025, 1033: a look for a tall one's top edge finds
    edges inside the top face, which a fit that no longer explains the outline must not
    take) and a tall cylinder near the nadir held at the configured height (seed 1038).
    Each such footprint is within 0.5 cm of the truth, or within the 99 % bound of the
    uncertainty it states (the step from its fitted height to the one held included)."""
    config = load_config()
    worst = 0.0
    for s in evaluate_rig(config, "overhead", (1025, 1033, 1038), "measured"):
        for i in range(len(s.found)):
            if not s.found[i] or s.height_source[i] != "not measurable":
                continue
            error, sigma = s.footprint_error_cm[i], s.position_sigma_cm[i]
            assert error <= 0.5 or error <= math.sqrt(STATED_CHI2) * sigma, (s.seed, i, sigma)
            worst = max(worst, error / sigma)
    assert worst > 1.0  # one held well off its fitted height: its stated σ is what covers it


def test_a_top_edge_is_taken_only_where_it_is_found_and_pins_the_height() -> None:
    """Unseen scenes whose one-frame fits took the wrong edge for a top's. Straight down,
    low boxes far from the nadir (seed 1039's #7, seed 1057's #1), walls a pixel or two
    wide: a look for the top's edge where a tall start puts it ended at the end of its
    reach, short of the edge, and was taken for it (the height measured too tall); their
    walls too thin for that look, their tops' edges are found where the wall shows at
    the silhouette as a level of its own. From the tripod, a box seen square-on (seed
    1084's #7): a tall start shrank to a sliver whose few edge points fit anything, and
    its look, not pinning the height, was chosen over one that did (its footprint then
    off by more than it stated). A low box from the tripod (seed 1132's #5) whose walls
    show along too little of its side facing the camera is not measured by them (they
    put it too low, its footprint off by more than it stated). Every measured height
    within 1 cm
    of the truth, every footprint within 0.5 cm (or, its position not measurable,
    within the 99 % bound of the uncertainty it states), and those three boxes
    measured."""
    config = load_config()
    scenes = [
        *evaluate_rig(config, "overhead", (1039, 1057), "measured"),
        *evaluate_rig(config, "oblique", (1084, 1132), "measured"),
    ]
    for s in scenes:
        assert all(s.found), s.seed
        for i in range(len(s.found)):
            if s.height_source[i] == "one camera":
                assert abs(s.height_cm[i] - s.true_height_cm[i]) <= 1.0, (s.seed, i)
            error, sigma = s.footprint_error_cm[i], s.position_sigma_cm[i]
            if s.position_unmeasurable[i]:
                assert error <= math.sqrt(STATED_CHI2) * sigma, (s.seed, i, error, sigma)
            else:
                assert error <= 0.5, (s.seed, i, error)
    measured = [s.height_source[i] for s, i in zip(scenes, (7, 1, 7), strict=False)]
    assert measured == ["one camera"] * 3


def test_an_obstacle_merged_with_a_marked_robots_silhouette_is_found() -> None:
    """Unseen scenes where, seen from the tripod, an obstacle's silhouette runs into the
    marked robot's (seed 1213: a 3 cm cylinder behind it; seed 1218: a 17 cm box in
    front): the robot's blob is fitted too, the solid standing where its marker says is
    the robot, and the other is reported as the obstacle it is, within 0.5 cm."""
    results = evaluate_rig(load_config(), "oblique", (1213, 1218), "measured", marked=True)
    report = summarise(results, "oblique", "measured", marked=True)
    assert report.found == report.obstacles and report.spurious == 0
    assert report.robot_scenes == report.scenes == 2
    assert report.footprint_max_cm <= 0.5


def test_unseen_tripod_scenes_whose_fits_turn_on_fine_choices() -> None:
    """Unseen tripod scenes where a fit's choices once went wrong: seed 1024's 8 cm box
    (cut into three prisms when the outline's normals were carried to the floor by a
    closed form differing in the last bits), seeds 1126 and 1134 (partly hidden solids,
    lost, or measured far off at a narrow stated σ, with one-step far-side edges), seed
    1124 (wrong shapes fitted to a partly hidden box, once stating no uncertainty; then
    a flat wide box spread under its two boxes, the two fitted low: a solid too many,
    dropped where the two fitted again without it explain the outline). Every obstacle
    found; every measured height within 1 cm; every footprint within 0.5 cm or within
    the 99 % bound of the uncertainty it states, which every fitted solid states;
    nothing spurious; seed 1124's two boxes measured."""
    bound = math.sqrt(STATED_CHI2)
    for s in evaluate_rig(load_config(), "oblique", (1024, 1124, 1126, 1134), "measured"):
        assert all(s.found), s.seed
        assert s.spurious == 0, s.seed
        if s.seed == 1124:  # its 14 cm box (obstacle 2) and 21 cm box (obstacle 8)
            assert [s.height_source[i] for i in (1, 7)] == ["one camera"] * 2
        for i in range(len(s.found)):
            if s.height_source[i] == "one camera":
                assert abs(s.height_cm[i] - s.true_height_cm[i]) <= 1.0, (s.seed, i)
            error, sigma = s.footprint_error_cm[i], s.position_sigma_cm[i]
            assert math.isfinite(sigma), (s.seed, i)
            assert error <= 0.5 or error <= bound * sigma, (s.seed, i, error, sigma)


def test_solids_that_meet_or_part_in_the_frame_are_followed_without_waiting_for_a_fit() -> None:
    """Eight seconds of the tripod's view of seed 1003 at 5 frames/s, the fits beside the
    frames (each done by the next frame, as a live stage's): blobs merge where solids
    meet in the frame (two boxes; the robot passing behind a 19 cm prism, turning as it
    drives) and part again. Once every blob has had its fit, no frame has a blob waiting
    for one: the known solids are carried into the merged blob and followed there, the
    robot turned with its path; every obstacle and the robot are found within 0.5 cm
    in every frame, and the robot's heading (its long axis) within 2° of where it
    faces, alone or in a merged blob."""
    times = [k / 5.0 for k in range(58, 100)]
    cfg, camera, frames, truths, floor = _scene_frames("oblique", 1003, times)
    with tempfile.TemporaryDirectory() as tmp:
        dcfg = _measuring(cfg, floor, Path(tmp))
        detector = Detector(camera, dcfg.image, dcfg.pose, background_fits=True)
        assert detector.solids is not None
        carried = settled = 0
        try:
            for k, (image, truth, t) in enumerate(zip(frames, truths, times, strict=True)):
                det = detector.detect(image, stamp_s=t)
                carried += any(g.carried for g in detector.solids.groups)
                detector.solids.wait()
                waiting = [o for o in det.objects if o.z_unmeasured == "pending"]
                if k < len(truth.objects):
                    continue
                settled += 1
                assert not waiting, (k, [(o.x_cm, o.y_cm) for o in waiting])
                assert len(det.objects) == len(truth.objects), k
                errors = _nearest_error(det.objects, truth)
                assert max(errors) < 0.5, (k, errors)
                (robot,) = [o for o in det.objects if o.kind == "robot"]
                (true_robot,) = [o for o in truth.objects if o.kind == "robot"]
                assert robot.heading_deg is not None
                off = (robot.heading_deg - true_robot.heading_deg + 90.0) % 180.0 - 90.0
                assert abs(off) < 2.0, (k, robot.heading_deg, true_robot.heading_deg)
        finally:
            detector.close()
    assert settled >= 30
    assert carried >= 2


def test_the_robot_alone_turns_with_its_blobs_axis_at_a_high_frame_rate() -> None:
    """Three seconds of the tripod's view of seed 1012 at 30 frames/s: the unmarked robot,
    alone in its blob, drives and turns. Where its blob's axis tells its yaw it is
    turned by that axis (its pose map), elsewhere every other frame at its last turn
    rate, and to its outline at most every other frame: its heading is within 1° and
    its footprint within 0.5 cm in every frame after its fit."""
    times = [k / 30.0 for k in range(90)]
    cfg, camera, frames, truths, floor = _scene_frames("oblique", 1012, times)
    outlines = 0
    follow = SolidTracker._follow_group

    def counted(self, group, *args):
        nonlocal outlines
        outlines += len(group.solids) == 1
        return follow(self, group, *args)

    with tempfile.TemporaryDirectory() as tmp, pytest.MonkeyPatch.context() as patch:
        patch.setattr(SolidTracker, "_follow_group", counted)
        dcfg = _measuring(cfg, floor, Path(tmp))
        detector = Detector(camera, dcfg.image, dcfg.pose)
        headings, errors = [], []
        for k, (image, truth, t) in enumerate(zip(frames, truths, times, strict=True)):
            det = detector.detect(image, stamp_s=t, fit_all=k == 0)
            (robot,) = [o for o in det.objects if o.kind == "robot"]
            (true_robot,) = [o for o in truth.objects if o.kind == "robot"]
            assert robot.heading_deg is not None
            headings.append((robot.heading_deg - true_robot.heading_deg + 90.0) % 180.0 - 90.0)
            errors.append(math.hypot(robot.x_cm - true_robot.x_cm, robot.y_cm - true_robot.y_cm))
        detector.close()
    true_yaws = [next(o for o in t.objects if o.kind == "robot").heading_deg for t in truths]
    assert abs((true_yaws[-1] - true_yaws[0] + 90.0) % 180.0 - 90.0) > 10.0  # it turned
    assert max(np.abs(headings)) < 1.0, headings
    assert max(errors) < 0.5, errors
    assert outlines <= len(times) // 2, outlines


def test_a_refit_that_explains_a_merged_blob_worse_than_its_followed_solids_is_not_taken() -> None:
    """Seed 1011, tripod, frames 82–94 at 5 frames/s, one fit a frame: the robot drives
    into a blob with a cylinder, and that blob's refit stalls with the robot's box where
    it stood a frame before (much of the outline left unexplained). The solids followed
    onto the outline explain it: they are kept and followed, and the robot stays within
    0.5 cm and 1.5° of the truth in every frame."""
    times = [k / 5.0 for k in range(82, 95)]
    cfg, camera, frames, truths, floor = _scene_frames("oblique", 1011, times)
    with tempfile.TemporaryDirectory() as tmp:
        dcfg = _measuring(cfg, floor, Path(tmp))
        detector = Detector(camera, dcfg.image, dcfg.pose)
        merged = 0
        for k, (image, truth, t) in enumerate(zip(frames, truths, times, strict=True)):
            det = detector.detect(image, stamp_s=t, fit_all=k == 0)
            assert detector.solids is not None
            merged += any(len(g.solids) > 1 for g in detector.solids.groups)
            (robot,) = [o for o in det.objects if o.kind == "robot"]
            (true_robot,) = [o for o in truth.objects if o.kind == "robot"]
            error = math.hypot(robot.x_cm - true_robot.x_cm, robot.y_cm - true_robot.y_cm)
            assert error < 0.5, (k, error)
            assert robot.heading_deg is not None
            off = (robot.heading_deg - true_robot.heading_deg + 90.0) % 180.0 - 90.0
            assert abs(off) < 1.5, (k, off)
        detector.close()
    assert merged >= 5
