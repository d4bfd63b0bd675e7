"""The general camera (pinhole + Brown–Conrady, OpenCV's model): agreement with OpenCV,
round trips, the shared projection interface, GA + least-squares calibration checked
against cv2.solvePnP / cv2.calibrateCamera, and the OpenCV / ROS exports."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import cv2
import msgspec
import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ovis.common.calibration.calibrate import calibrate
from ovis.common.calibration.file import Calibration, load_calibration, save_calibration
from ovis.common.camera import paper_model as paper
from ovis.common.camera import pinhole, projection
from ovis.common.camera.export import (
    paper_to_pinhole,
    reprojection_difference,
    ros_camera_info,
    write_opencv_yaml,
    write_ros_yaml,
)
from ovis.common.config import (
    ConfigError,
    ControlPoint,
    PinholeParams,
    PinholeRanges,
    config_from_dict,
    load_config,
)
from ovis.common.sim.arena import Arena, control_points
from ovis.common.world.detection import Detector

PINHOLE = load_config(preset="pinhole")
TRUTH = PINHOLE.camera


def look_at(
    centre: np.ndarray, target: np.ndarray, roll: float = 0.0
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """(rvec, tvec) of a camera at ``centre`` looking at ``target`` (world Z up)."""
    z = (target - centre) / np.linalg.norm(target - centre)
    up = np.array([0.0, 0.0, 1.0])
    y = -(up - (up @ z) * z)
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    R = np.vstack([x, y, z])
    c, s = math.cos(roll), math.sin(roll)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ R
    rvec = cv2.Rodrigues(R)[0].ravel()
    t = -R @ centre
    return tuple(float(v) for v in rvec), tuple(float(v) for v in t)  # type: ignore[return-value]


def random_camera(rng: np.random.Generator, *, distortion: float = 1.0) -> PinholeParams:
    centre = np.array([rng.uniform(20, 110), rng.uniform(120, 200), rng.uniform(90, 200)])
    target = np.array([rng.uniform(40, 90), rng.uniform(50, 100), 0.0])
    rvec, tvec = look_at(centre, target, rng.uniform(-0.5, 0.5))
    return PinholeParams(
        rows=480,
        cols=640,
        fx=float(rng.uniform(400, 900)),
        fy=float(rng.uniform(400, 900)) * float(rng.choice([1.0, -1.0])),
        cx=float(rng.uniform(300, 340)),
        cy=float(rng.uniform(220, 260)),
        k1=float(rng.uniform(-0.3, 0.2)) * distortion,
        k2=float(rng.uniform(-0.1, 0.1)) * distortion,
        p1=float(rng.uniform(-0.003, 0.003)) * distortion,
        p2=float(rng.uniform(-0.003, 0.003)) * distortion,
        k3=float(rng.uniform(-0.02, 0.02)) * distortion,
        rvec=rvec,
        tvec_cm=tvec,
    )


def cv_project(cam: PinholeParams, xyz: np.ndarray) -> np.ndarray:
    """cv2.projectPoints → (N, 2) of (row, col) (OpenCV gives (x, y) = (col, row))."""
    xy, _ = cv2.projectPoints(
        xyz.astype(np.float64),
        np.array(cam.rvec, dtype=np.float64),
        np.array(cam.tvec_cm, dtype=np.float64),
        pinhole.camera_matrix(cam),
        pinhole.distortion_coefficients(cam),
    )
    return xy[:, 0, ::-1]


# --------------------------------------------------------------------------- model
@pytest.mark.parametrize("seed", range(8))
def test_project_agrees_with_cv2_project_points(seed: int) -> None:
    rng = np.random.default_rng(seed)
    cam = random_camera(rng)
    xyz = np.column_stack(
        [rng.uniform(0, 130, 300), rng.uniform(0, 150, 300), rng.uniform(0, 40, 300)]
    )
    q = pinhole.project(*xyz.T, cam)
    ref = cv_project(cam, xyz)
    assert q.valid.sum() > 50
    np.testing.assert_allclose(q.row[q.valid], ref[q.valid, 0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(q.col[q.valid], ref[q.valid, 1], rtol=0, atol=1e-9)


def test_rodrigues_matches_cv2_including_small_and_half_turn_angles() -> None:
    rng = np.random.default_rng(0)
    vecs = [rng.normal(size=3) for _ in range(20)]
    vecs += [np.array([1e-9, -2e-9, 0.0]), np.zeros(3), np.array([0.0, math.pi, 0.0])]
    vecs += [np.array([3e-5, 1e-5, -2e-5]), np.array([math.pi - 1e-7, 0.0, 0.0])]
    for v in vecs:
        np.testing.assert_allclose(pinhole.rodrigues(v), cv2.Rodrigues(v)[0], atol=1e-14)
    batch = pinhole.rodrigues(np.array(vecs))
    assert batch.shape == (len(vecs), 3, 3)


def test_undistortion_agrees_with_cv2_undistort_points() -> None:
    rng = np.random.default_rng(3)
    cam = random_camera(rng, distortion=0.5)
    row, col = rng.uniform(0, 479, 200), rng.uniform(0, 639, 200)
    und = pinhole.undistort_normalised(row, col, cam)
    pts = np.column_stack([col, row])[:, None, :]
    ref = cv2.undistortPointsIter(  # type: ignore[attr-defined]
        pts, pinhole.camera_matrix(cam), pinhole.distortion_coefficients(cam), None, None,
        (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15),
    )[:, 0] if hasattr(cv2, "undistortPointsIter") else cv2.undistortPoints(
        pts, pinhole.camera_matrix(cam), pinhole.distortion_coefficients(cam),
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15),
    )[:, 0]  # fmt: skip
    assert und.valid.all()
    np.testing.assert_allclose(und.x, ref[:, 0], atol=1e-9)
    np.testing.assert_allclose(und.y, ref[:, 1], atol=1e-9)


cameras = st.integers(min_value=0, max_value=2**32 - 1).map(
    lambda s: random_camera(np.random.default_rng(s))
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    cam=cameras,
    row=st.floats(0.0, 479.0),
    col=st.floats(0.0, 639.0),
    h=st.floats(0.0, 30.0),
)
def test_pixel_plane_pixel_round_trip(cam: PinholeParams, row: float, col: float, h: float):
    b = pinhole.back_project(row, col, cam, h)
    centre = pinhole.back_project(cam.cy, cam.cx, cam, h)
    assert bool(centre.valid)  # the principal ray of a camera looking down meets the plane
    assert np.isfinite(b.x_cm) and np.isfinite(b.y_cm)
    if b.valid:
        q = pinhole.project(b.x_cm, b.y_cm, h, cam)
        assert q.valid
        assert abs(q.row - row) < 1e-6 and abs(q.col - col) < 1e-6
    else:
        assert b.x_cm == 0.0 and b.y_cm == 0.0


@settings(max_examples=60, deadline=None)
@given(cam=cameras, x=st.floats(20.0, 110.0), y=st.floats(20.0, 130.0), h=st.floats(0.0, 30.0))
def test_plane_pixel_plane_round_trip(cam: PinholeParams, x: float, y: float, h: float):
    q = pinhole.project(x, y, h, cam)
    if not q.valid:
        return
    b = pinhole.back_project(q.row, q.col, cam, h)
    assert b.valid
    assert abs(b.x_cm - x) < 1e-6 and abs(b.y_cm - y) < 1e-6


def test_non_projectable_points_are_flagged_never_nan() -> None:
    cam = TRUTH
    C = np.array(pinhole.camera_centre_cm(cam))
    # Behind the camera: the centre minus the viewing direction.
    R = pinhole.rodrigues(np.array(cam.rvec))
    behind = C - 50.0 * R[2]
    q = pinhole.project(*behind, cam)
    assert not q.valid and q.row == 0.0 and q.col == 0.0
    q = pinhole.project(*C, cam)  # the centre itself
    assert not q.valid and np.isfinite(q.row)
    # A ray that goes above the horizon never meets the floor.
    strong = msgspec.structs.replace(cam, k1=0.0, k2=0.0, p1=0.0, p2=0.0)
    far = pinhole.back_project(-5000.0, cam.cx, strong, 0.0)
    assert not far.valid and far.x_cm == 0.0
    # Strong barrel distortion folds back beyond some radius: such points are invalid.
    folded = msgspec.structs.replace(cam, k1=-1.2, k2=0.0, k3=0.0, p1=0.0, p2=0.0)
    xyz = np.column_stack([np.linspace(-400, 500, 400), np.full(400, 80.0), np.zeros(400)])
    q = pinhole.project(*xyz.T, folded)
    xc, yc, zc = pinhole.world_to_camera(*xyz.T, folded)
    r2 = (xc / zc) ** 2 + (yc / zc) ** 2
    assert (~q.valid).any() and q.valid.any()
    assert (r2[~q.valid & (zc > 0)] > 1.0 / (3 * 1.2) - 1e-9).all()  # beyond the fold
    assert np.isfinite(q.row).all() and np.isfinite(q.col).all()
    b = pinhole.back_project(np.array([0.0, 240.0]), np.array([0.0, 320.0]), folded, 0.0)
    assert np.isfinite(b.x_cm).all()


def test_population_cameras_broadcast() -> None:
    from ovis.common.calibration.pinhole import pinhole_values, pinhole_with

    values = np.repeat(pinhole_values(TRUTH)[None, :], 5, axis=0)
    values[:, 0] += np.arange(5)  # five focal lengths
    pop = pinhole_with(TRUTH, values)
    X = np.array([40.0, 60.0, 90.0])
    q = pinhole.project(X, X, 0.0, pop)
    assert q.row.shape == (5, 3) and q.valid.all()
    for i in range(5):
        one = pinhole_with(TRUTH, values[i])
        qi = pinhole.project(X, X, 0.0, one)
        np.testing.assert_allclose(q.col[i], qi.col, atol=1e-12)
    b = projection.pixel_footprint_cm2(q.row, q.col, pop, 0.0)
    assert b.shape == (5, 3) and (b > 0).all()


@settings(max_examples=300, deadline=None)
@given(
    k=st.tuples(
        *[st.floats(-50.0, 50.0).filter(lambda v: abs(v) > 1e-6) | st.just(0.0) for _ in "abc"]
    ),
    r2=st.lists(st.floats(0.0, 20.0), min_size=1, max_size=40),
)
def test_one_cameras_one_to_one_bound_is_the_general_test(k, r2) -> None:
    """One camera's radius bound (cached, a cubic's smallest positive root) says the
    same as the exact test that a GA population's broadcast cameras go through."""
    one = msgspec.structs.replace(TRUTH, k1=k[0], k2=k[1], k3=k[2])
    as_arrays = msgspec.structs.replace(
        TRUTH, k1=np.array([k[0]]), k2=np.array([k[1]]), k3=np.array([k[2]])
    )
    r2 = np.array(r2)
    limit = pinhole._one_to_one_limit(k[0], k[1], k[2])
    near = np.abs(r2 - limit) <= 1e-9 * max(1.0, limit)  # at the root itself: rounding
    got = pinhole._monotonic_radius2(one, r2)
    want = pinhole._monotonic_radius2(as_arrays, r2)
    assert (got == want)[~near].all()
    # and one camera's rotation (cached, read-only) is OpenCV's
    R = pinhole._rotation(one)
    np.testing.assert_allclose(R, cv2.Rodrigues(np.array(one.rvec))[0], atol=1e-12)
    assert not R.flags.writeable


# --------------------------------------------------------------------------- config
def test_pinhole_preset_and_model_switch_over_another_preset() -> None:
    assert PINHOLE.camera.model == "pinhole" and isinstance(PINHOLE.camera, PinholeParams)
    data = {
        "preset": "default",
        "camera": {**msgspec.to_builtins(TRUTH), "fx": 700.0},
    }
    cfg = config_from_dict(data)
    assert isinstance(cfg.camera, PinholeParams) and cfg.camera.fx == 700.0
    assert cfg.image == load_config().image  # the rest of the preset still applies
    with pytest.raises(ConfigError, match=r"missing required field `fx` - at `\$.camera`"):
        config_from_dict({"camera": {"model": "pinhole", "rows": 480, "cols": 640}})
    with pytest.raises(ConfigError, match=r"camera\.fy must not be 0"):
        config_from_dict({"preset": "pinhole", "camera": {"fy": 0.0}})
    with pytest.raises(ConfigError, match=r"Invalid value 'fisheye' - at `\$.camera.model`"):
        config_from_dict({"camera": {"model": "fisheye"}})
    assert load_config().camera.model == "paper"  # the paper model stays the default


def test_calibration_file_round_trip_with_a_pinhole(tmp_path: Path) -> None:
    calib = Calibration(
        dipe_px=0.1, dipe_mm=0.001, dipe_max_px=0.2, dipe_max_mm=0.002,
        camera=TRUTH, image=PINHOLE.image, pose=PINHOLE.pose,
    )  # fmt: skip
    save_calibration(tmp_path / "c.json", calib)
    back = load_calibration(tmp_path / "c.json")
    assert back.camera == TRUTH and back == calib


# --------------------------------------------------------------------------- interface
def test_shared_interface_dispatches_on_the_model() -> None:
    cam = load_config().camera
    X, Y = np.array([40.0, 70.0]), np.array([60.0, 100.0])
    a, b = projection.project(X, Y, 7.0, cam), paper.project(X, Y, 7.0, cam)
    np.testing.assert_array_equal(a.row, b.row)
    a, b = projection.project(X, Y, 7.0, TRUTH), pinhole.project(X, Y, 7.0, TRUTH)
    np.testing.assert_array_equal(a.col, b.col)
    j = projection.pixel_jacobian(a.row, a.col, TRUTH, 7.0)
    np.testing.assert_allclose(j.x_cm, X, atol=1e-9)
    assert projection.principal_point_rowcol(TRUTH) == (TRUTH.cy, TRUTH.cx)
    np.testing.assert_allclose(projection.camera_centre_cm(TRUTH), (65.0, 165.0, 135.0), atol=0.01)
    assert set(projection.camera_parameters(TRUTH)) >= {"fx", "rvec_x", "tvec_z_cm"}
    with pytest.raises(TypeError, match="expected a camera"):
        projection.project(X, Y, 0.0, object())  # type: ignore[arg-type]


# --------------------------------------------------------------------------- calibration
# Eight non-planar control points (heights 0–30 cm) spread over the arena.
POINTS_XYZ = np.array(
    [[35, 45, 0], [95, 42, 25], [40, 115, 12], [98, 118, 3], [65, 80, 30], [50, 65, 8],
     [82, 95, 18], [70, 50, 5]], dtype=np.float64,
)  # fmt: skip
POSE_RANGES = PinholeRanges(
    rvec_x=(-0.08, 0.12),
    rvec_y=(2.93, 3.10),
    rvec_z=(-0.95, -0.80),
    tvec_x_cm=(55.0, 80.0),
    tvec_y_cm=(-75.0, -55.0),
    tvec_z_cm=(190.0, 215.0),
)


def drawn_frame(cam: PinholeParams, xyz: np.ndarray) -> np.ndarray:
    """A frame with a bright disc (radius 9 px) drawn by cv2.circle at each projection."""
    q = pinhole.project(*xyz.T, cam)
    assert q.valid.all()
    img = np.full((cam.rows, cam.cols), 40, np.uint8)
    s = 256  # cv2.circle with 8 fractional bits: sub-pixel centres
    for r, c in zip(q.row, q.col, strict=True):
        cv2.circle(img, (round(c * s), round(r * s)), 9 * s, 220, -1, cv2.LINE_8, 8)
    return img


def synthetic_calibration(
    ranges: PinholeRanges, n: int = 8, xyz: np.ndarray = POINTS_XYZ
) -> tuple[Calibration, np.ndarray]:
    cfg = msgspec.structs.replace(
        PINHOLE,
        calibration=msgspec.structs.replace(
            PINHOLE.calibration, threshold=(100.0, 200.0), size_filter_cm2=(0.1, 2.0),
            pinhole=ranges,
        ),
    )  # fmt: skip
    xyz = xyz[:n]
    points = [
        ControlPoint(name=f"P{i}", x_cm=float(x), y_cm=float(y), z_cm=float(z))
        for i, (x, y, z) in enumerate(xyz)
    ]
    calib, _ = calibrate(drawn_frame(TRUTH, xyz), points, cfg)
    detected = np.array([[p.detected_col, p.detected_row] for p in calib.points])  # OpenCV x, y
    return calib, detected


def rms_px(cam_k, dist, rvec, tvec, detected, xyz=POINTS_XYZ) -> float:
    xy, _ = cv2.projectPoints(xyz, np.asarray(rvec, float), np.asarray(tvec, float), cam_k, dist)
    return float(np.sqrt(np.mean(np.sum((xy[:, 0] - detected) ** 2, axis=1))))


@pytest.mark.parametrize("planar", [False, True], ids=["non-planar", "planar"])
def test_pose_calibration_matches_cv2_solve_pnp(planar: bool) -> None:
    xyz = POINTS_XYZ * np.array([1.0, 1.0, 0.0]) if planar else POINTS_XYZ
    calib, detected = synthetic_calibration(POSE_RANGES, xyz=xyz)
    cam = calib.camera
    assert isinstance(cam, PinholeParams) and calib.dipe_px < 0.15
    assert calib.polished and calib.ga_dipe_px is not None and calib.ga_dipe_px > calib.dipe_px
    K, D = pinhole.camera_matrix(TRUTH), pinhole.distortion_coefficients(TRUTH)
    ok, rvec, tvec = cv2.solvePnP(xyz, detected, K, D, flags=cv2.SOLVEPNP_ITERATIVE)
    ok, rvec, tvec = cv2.solvePnP(
        xyz, detected, K, D, rvec, tvec, useExtrinsicGuess=True,
        flags=cv2.SOLVEPNP_ITERATIVE,
    )  # fmt: skip
    assert ok
    # Same pose (compare rotations: near a half turn two Rodrigues vectors describe it).
    np.testing.assert_allclose(
        pinhole.rodrigues(np.array(cam.rvec)), cv2.Rodrigues(rvec)[0], atol=1e-6
    )
    np.testing.assert_allclose(cam.tvec_cm, tvec.ravel(), atol=1e-4)
    ours = rms_px(K, D, cam.rvec, cam.tvec_cm, detected, xyz)
    assert ours <= rms_px(K, D, rvec, tvec, detected, xyz) + 1e-9
    # and near the truth: the drawn discs' centroids are within ~0.1 px of the projections
    np.testing.assert_allclose(cam.tvec_cm, TRUTH.tvec_cm, atol=0.3)


def test_intrinsic_and_pose_calibration_matches_cv2_calibrate_camera() -> None:
    ranges = msgspec.structs.replace(
        POSE_RANGES, fx=(600.0, 760.0), fy=(600.0, 760.0), cx=(290.0, 350.0), cy=(210.0, 260.0)
    )
    calib, detected = synthetic_calibration(ranges)
    cam = calib.camera
    assert isinstance(cam, PinholeParams)
    K0 = pinhole.camera_matrix(TRUTH) * np.array([[1.05], [0.97], [1.0]])
    flags = (
        cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2
        | cv2.CALIB_FIX_K3 | cv2.CALIB_FIX_TANGENT_DIST
    )  # fmt: skip
    rms_cv, K, _, rvecs, tvecs = cv2.calibrateCamera(
        [POINTS_XYZ.astype(np.float32)], [detected.astype(np.float32)], (TRUTH.cols, TRUTH.rows),
        K0, pinhole.distortion_coefficients(TRUTH).copy(), flags=flags,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 1000, 1e-15),
    )  # fmt: skip
    ours = rms_px(
        pinhole.camera_matrix(cam), pinhole.distortion_coefficients(cam), cam.rvec, cam.tvec_cm,
        detected,
    )  # fmt: skip
    assert ours <= rms_cv + 1e-5
    np.testing.assert_allclose(pinhole.camera_matrix(cam), K, atol=0.01)
    np.testing.assert_allclose(
        pinhole.rodrigues(np.array(cam.rvec)), cv2.Rodrigues(rvecs[0])[0], atol=1e-5
    )
    np.testing.assert_allclose(cam.tvec_cm, tvecs[0].ravel(), atol=1e-3)


def test_pinhole_calibration_needs_six_points() -> None:
    with pytest.raises(ConfigError, match="at least 6 control points"):
        synthetic_calibration(POSE_RANGES, n=5)


def test_simulated_pinhole_arena_calibrates_and_detects_within_1_cm() -> None:
    """End to end: the simulator renders through the pinhole camera; GA + polish on the
    first frame's eight objects; detection on later frames within 1 cm of the truth."""
    arena = Arena(PINHOLE, 4)
    frame, truth = arena.render()
    calib, ga = calibrate(frame, control_points(truth), PINHOLE)
    assert isinstance(calib.camera, PinholeParams)
    assert calib.dipe_px < 0.3 and calib.dipe_px < ga.best_fitness  # the polish helped
    detector = Detector(calib.camera, calib.image, calib.pose)
    worst = 0.0
    for _ in range(3):
        arena.step()
        frame, truth = arena.render()
        det = detector.detect(frame)
        assert len(det.objects) == len(truth.objects)
        for o in truth.objects:
            worst = max(
                worst, min(math.hypot(d.x_cm - o.x_cm, d.y_cm - o.y_cm) for d in det.objects)
            )
    assert worst < 1.0


# --------------------------------------------------------------------------- export
@pytest.mark.parametrize("preset", ["default", "paper"])
def test_paper_model_exports_as_an_equivalent_pinhole(preset: str) -> None:
    cam = load_config(preset=preset).camera
    eq = paper_to_pinhole(cam)
    assert eq.max_px < 1e-6 and eq.camera.fy < 0 < eq.camera.fx  # mirror-inverted image
    # cv2.projectPoints with the exported numbers reproduces the paper model.
    rng = np.random.default_rng(0)
    rows, cols = rng.uniform(0, cam.rows - 1, 200), rng.uniform(0, cam.cols - 1, 200)
    b = paper.back_project(rows, cols, cam, 7.0)
    xyz = np.column_stack([b.x_cm, b.y_cm, np.full(200, 7.0)])[b.valid]
    ref = cv_project(eq.camera, xyz)
    np.testing.assert_allclose(ref[:, 0], rows[b.valid], atol=1e-5)
    np.testing.assert_allclose(ref[:, 1], cols[b.valid], atol=1e-5)
    # Without distortion the equivalence is exact.
    flat = paper_to_pinhole(msgspec.structs.replace(cam, k1=0.0, k2=0.0, k3=0.0))
    assert flat.max_px < 1e-9 and flat.camera.k1 == pytest.approx(0.0, abs=1e-12)


def test_strong_paper_distortion_is_fitted_and_its_residual_reported() -> None:
    # The paper's eqs. 7–8 give the undistorted point from the distorted one: k1 < 0
    # there shrinks the edges of the *undistorted* image, i.e. the camera magnifies them
    # (pincushion), which is k1 > 0 in Brown–Conrady. Here 7 % at the image corners.
    cam = msgspec.structs.replace(load_config().camera, k1=-0.05, k2=0.0, k3=0.0)
    eq = paper_to_pinhole(cam)
    assert eq.camera.k1 > 0
    rms, worst = reprojection_difference(cam, eq.camera)
    assert (rms, worst) == (eq.rms_px, eq.max_px)
    assert 0.0 < eq.max_px < 0.5


def test_opencv_and_ros_yaml_load_back(tmp_path: Path) -> None:
    cam = msgspec.structs.replace(TRUTH, k3=0.01)
    write_opencv_yaml(tmp_path / "cv.yaml", cam, note="test")
    fs = cv2.FileStorage(str(tmp_path / "cv.yaml"), cv2.FILE_STORAGE_READ)
    np.testing.assert_array_equal(fs.getNode("camera_matrix").mat(), pinhole.camera_matrix(cam))
    D = fs.getNode("distortion_coefficients").mat()
    assert D.shape == (1, 5)
    np.testing.assert_array_equal(D[0], [cam.k1, cam.k2, cam.p1, cam.p2, cam.k3])
    np.testing.assert_array_equal(fs.getNode("rvec").mat().ravel(), cam.rvec)
    np.testing.assert_array_equal(fs.getNode("tvec").mat().ravel(), cam.tvec_cm)
    assert (fs.getNode("image_width").real(), fs.getNode("image_height").real()) == (640, 480)
    assert fs.getNode("world_units").string() == "cm"
    fs.release()

    write_ros_yaml(tmp_path / "ros.yaml", cam, camera_name="arena_cam", note="a\nb")
    info = yaml.safe_load((tmp_path / "ros.yaml").read_text())
    assert info == ros_camera_info(cam, "arena_cam")
    assert info["distortion_model"] == "plumb_bob" and info["camera_name"] == "arena_cam"
    assert (info["image_width"], info["image_height"]) == (640, 480)
    K = np.array(info["camera_matrix"]["data"]).reshape(3, 3)
    np.testing.assert_array_equal(K, pinhole.camera_matrix(cam))
    assert info["distortion_coefficients"]["data"] == [cam.k1, cam.k2, cam.p1, cam.p2, cam.k3]
    np.testing.assert_array_equal(
        np.reshape(info["rectification_matrix"]["data"], (3, 3)), np.eye(3)
    )
    P = np.reshape(info["projection_matrix"]["data"], (3, 4))
    np.testing.assert_array_equal(P[:, :3], K)
    assert (P[:, 3] == 0).all()


def test_export_command(tmp_path: Path) -> None:
    calib = Calibration(
        dipe_px=0.1, dipe_mm=0.001, dipe_max_px=0.2, dipe_max_mm=0.002,
        camera=load_config().camera, image=PINHOLE.image, pose=PINHOLE.pose,
    )  # fmt: skip
    save_calibration(tmp_path / "c.json", calib)
    cv_file, ros_file = tmp_path / "c_cv.yaml", tmp_path / "c_ros.yaml"
    proc = subprocess.run(
        [sys.executable, "-m", "ovis.services.cli", "export", str(tmp_path / "c.json"),
         "--opencv", str(cv_file), "--ros", str(ros_file)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    out = " ".join(proc.stdout.split())
    assert "fit residual over the image" in out and "fy < 0" in out
    fs = cv2.FileStorage(str(cv_file), cv2.FILE_STORAGE_READ)
    assert fs.getNode("camera_matrix").mat()[1, 1] < 0
    fs.release()
    assert yaml.safe_load(ros_file.read_text())["image_width"] == 640
    proc = subprocess.run(
        [sys.executable, "-m", "ovis.services.cli", "export", str(tmp_path / "c.json")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2 and "error: give --opencv FILE" in proc.stderr
