"""The one validity check of a calibration (common/calibration/validity.py), and how a
stage follows the calibrator with it (common/pipeline/following.py)."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest

from ovis.common.calibration import validity
from ovis.common.calibration.file import Calibration, calibration_from_config
from ovis.common.calibration.store import CalibrationStore
from ovis.common.calibration.validity import border_pixels, calibration_problem
from ovis.common.camera.projection import back_project
from ovis.common.config import load_config
from ovis.common.pipeline.following import CalibrationFollower, identity, label

PAPER = load_config(preset="paper")
PINHOLE = load_config(preset="pinhole")


def _with_camera(cfg, version: int = 7, epoch: str = "", **camera) -> Calibration:
    calib = calibration_from_config(cfg)
    cam = msgspec.structs.replace(calib.camera, **camera)
    return msgspec.structs.replace(calib, camera=cam, version=version, epoch=epoch)


def test_border_pixels_walk_the_four_sides() -> None:
    rows, cols = border_pixels(5, 9, n=3)
    pairs = set(zip(rows.tolist(), cols.tolist(), strict=True))
    assert pairs == {
        (0.0, 0.0), (0.0, 4.0), (0.0, 8.0), (4.0, 0.0), (4.0, 4.0), (4.0, 8.0),
        (2.0, 0.0), (2.0, 8.0),
    }  # fmt: skip


@pytest.mark.parametrize(
    "cfg", [PAPER, PINHOLE, load_config()], ids=["paper", "pinhole", "default"]
)
def test_the_presets_nominal_cameras_are_valid(cfg) -> None:
    assert calibration_problem(calibration_from_config(cfg), cfg) is None


def test_a_camera_below_the_floor_is_refused() -> None:
    # the attack: Z0 = -500 cm was adopted and then pose failed on every frame
    problem = calibration_problem(_with_camera(PAPER, Z0_cm=-500.0), PAPER)
    assert problem == (
        "calibration v7 refused: the camera is at Z = -500.3 cm, not above the floor and "
        "the objects' tops (7 cm)"
    )
    pinhole = _with_camera(PINHOLE, tvec_cm=(0.0, 0.0, -100.0))
    assert "not above the floor" in calibration_problem(pinhole, PINHOLE)


def test_a_camera_below_the_objects_tops_is_refused() -> None:
    # 5 cm above the floor is above the floor but below the 7 cm obstacles
    low = _with_camera(PAPER, Z0_cm=5.0 - 0.338)  # the lens sits 0.338 cm above Z0
    problem = calibration_problem(low, PAPER)
    assert problem is not None and "objects' tops (7 cm)" in problem


def test_a_camera_that_sees_the_horizon_is_refused() -> None:
    # tilted 20 degrees from the horizontal, the top of the image sees the sky
    problem = calibration_problem(_with_camera(PAPER, theta_deg=20.0), PAPER)
    assert problem == (
        "calibration v7 refused: 11 of 36 image border points do not see the plane Z = 0 cm "
        "(the footprint is unbounded)"
    )
    # the same count, computed independently with the projection module
    cam = _with_camera(PAPER, theta_deg=20.0).camera
    rows, cols = border_pixels(cam.rows, cam.cols)
    assert int((~back_project(rows, cols, cam, 0.0).valid).sum()) == 11


def test_a_footprint_beyond_the_bound_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    calib = calibration_from_config(PAPER)
    cam = calib.camera
    rows, cols = border_pixels(cam.rows, cam.cols)
    hit = back_project(rows, cols, cam, 0.0)
    extent = max(np.abs(hit.x_cm).max(), np.abs(hit.y_cm).max())
    monkeypatch.setattr(validity, "MAX_FOOTPRINT_CM", extent - 1.0)
    assert calibration_problem(calib, PAPER) == (
        f"calibration v0 refused: the image's footprint on Z = 0 cm reaches {extent:.0f} cm "
        f"from the origin (limit {extent - 1.0:g} cm)"
    )
    monkeypatch.setattr(validity, "MAX_FOOTPRINT_CM", extent + 1.0)
    assert calibration_problem(calib, PAPER) is None


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_a_field_that_is_not_finite_is_refused(value: float) -> None:
    assert calibration_problem(_with_camera(PAPER, k1=value), PAPER) == (
        "calibration v7 refused: camera.k1 is not a finite number"
    )
    calib = calibration_from_config(PAPER)
    pose = msgspec.structs.replace(calib.pose, track_gate_cm=value)
    bad = msgspec.structs.replace(calib, pose=pose)
    assert calibration_problem(bad, PAPER) == (
        "calibration v0 refused: pose.track_gate_cm is not a finite number"
    )


def test_a_calibration_for_another_image_size_is_refused() -> None:
    assert "640x480" in calibration_problem(calibration_from_config(PINHOLE), PAPER)


# --- following the calibrator ------------------------------------------------------------


def test_the_calibrators_answer_is_taken_even_with_a_lower_version() -> None:
    start = calibration_from_config(PAPER)
    follower = CalibrationFollower(PAPER, start)
    forged = _with_camera(PAPER, version=2**63 - 1, epoch="f" * 16)
    genuine = _with_camera(PAPER, version=6, epoch="0123456789abcdef", Z0_cm=150.0)
    assert follower.offer(forged) == (True, None)  # (were it the calibrator's answer)
    assert follower.offer(genuine) == (True, None)
    assert identity(follower.current) == ("0123456789abcdef", 6)
    assert follower.offer(genuine) == (False, None)  # the same: nothing to do
    assert label(genuine) == "v6@01234567"


def test_an_invalid_answer_is_refused_once_and_reported() -> None:
    start = calibration_from_config(PAPER)
    follower = CalibrationFollower(PAPER, start)
    bad = _with_camera(PAPER, version=9, epoch="a" * 16, Z0_cm=-500.0)
    adopted, problem = follower.offer(bad)
    assert not adopted and problem is not None and "not above the floor" in problem
    assert follower.offer(bad) == (False, None)  # said once
    assert follower.current is start
    assert follower.problem() == problem  # the stage's status: degraded, and why


def test_a_calibration_that_fails_on_a_frame_is_rolled_back_and_not_taken_again() -> None:
    start = calibration_from_config(PAPER)
    follower = CalibrationFollower(PAPER, start)
    good = _with_camera(PAPER, version=3, epoch="b" * 16)
    assert follower.offer(good)[0]
    follower.worked(good)
    failing = _with_camera(PAPER, version=4, epoch="b" * 16, Z0_cm=120.0)
    assert follower.offer(failing)[0]
    assert follower.failed(failing, "TypeError: boom") is good
    assert follower.current is good
    assert follower.offer(failing) == (False, None)
    assert follower.problem() == "calibration v4@bbbbbbbb failed on a frame here: TypeError: boom"
    # a calibration that has worked is not rolled back by one failure (a bad frame)
    assert follower.failed(good, "ValueError: one bad frame") is None
    # the calibrator moves on: the stage follows
    newer = _with_camera(PAPER, version=5, epoch="b" * 16)
    assert follower.offer(newer)[0] and follower.problem() is None


def test_the_store_keeps_one_epoch_and_stamps_every_version(tmp_path) -> None:
    store = CalibrationStore(tmp_path)
    epoch = store.epoch()
    assert len(epoch) == 16 and int(epoch, 16) >= 0
    assert CalibrationStore(tmp_path).epoch() == epoch  # persisted
    saved = store.save(calibration_from_config(PAPER))
    assert (saved.version, saved.epoch) == (1, epoch)
    assert store.latest()[0].epoch == epoch
    (tmp_path / "epoch").write_text("garbage")
    assert CalibrationStore(tmp_path).epoch() != epoch  # a broken id is replaced
    assert CalibrationStore(tmp_path / "other").epoch() != epoch


def test_a_calibration_of_another_simulated_set_up_is_not_taken_from_the_store(tmp_path) -> None:
    """A state folder shared by runs of the light and the physical world: the light
    world's calibration (made on its simulated camera) is refused by a physical run's
    calibrator, which calibrates anew, as is one made on another seed's scene (its empty
    floor and marks); the same set-up's is taken; one saved before the set-up was
    recorded is another run's; a real camera's run never asks."""
    light = load_config()
    physical = load_config(preset="physical")
    calib = msgspec.structs.replace(
        calibration_from_config(light),
        simulated=True,
        simulated_for=validity.simulated_setup(light),
    )
    assert validity.setup_problem(calib, light) is None
    problem = validity.setup_problem(calib, physical)
    assert problem is not None and "the light world's" in problem and "physical" in problem
    older = msgspec.structs.replace(calib, simulated_for="")
    assert "an earlier run's" in (validity.setup_problem(older, light) or "")
    other_seed = msgspec.structs.replace(
        physical, service=msgspec.structs.replace(physical.service, seed=physical.service.seed + 1)
    )
    ours = msgspec.structs.replace(calib, simulated_for=validity.simulated_setup(physical))
    assert validity.setup_problem(ours, physical) is None
    assert validity.setup_problem(ours, other_seed) is not None  # another floor, its marks
    real = msgspec.structs.replace(
        light, service=msgspec.structs.replace(light.service, source="0")
    )
    assert validity.setup_problem(older, real) is None
    assert validity.setup_problem(msgspec.structs.replace(older, simulated=False), light) is None
    store = CalibrationStore(tmp_path)
    store.save(calib)
    saved, problems = store.latest(lambda c: validity.setup_problem(c, physical))
    assert saved is None and len(problems) == 1 and "light" in problems[0]
    saved, problems = store.latest(lambda c: validity.setup_problem(c, light))
    assert saved is not None and saved.simulated_for == calib.simulated_for and not problems
