"""Camera model (eqs. 4–10): round trips, batch shapes, non-projectable points."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ovis.common.camera.paper_model import (
    back_project,
    pixel_footprint_cm2,
    project,
    rotation_world_cam,
)
from ovis.common.config import load_config

PAPER = load_config(preset="paper").camera
DEFAULT = load_config().camera
RANGES = load_config().calibration


def test_rotation_is_proper_and_looks_down() -> None:
    R = rotation_world_cam(70.0)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)
    assert np.linalg.det(R) == pytest.approx(1.0)
    axis = R[:, 2]  # optical axis in world coordinates
    np.testing.assert_allclose(axis, [0.0, -np.cos(np.radians(70)), -np.sin(np.radians(70))])
    np.testing.assert_allclose(rotation_world_cam(90.0)[:, 2], [0, 0, -1], atol=1e-15)


def test_principal_point_is_image_centre() -> None:
    # The point on the optical axis projects to (c_x, c_y) whatever the distortion.
    R = rotation_world_cam(PAPER.theta_deg)
    C = np.array([65.0, 113.0 + 21.0, 145.0])
    p = C + 100.0 * R[:, 2]
    q = project(*p, PAPER)
    assert q.valid
    assert q.row == pytest.approx(PAPER.c_x, abs=1e-9)
    assert q.col == pytest.approx(PAPER.c_y, abs=1e-9)


def test_rows_follow_world_x_cols_follow_world_y() -> None:
    a = project(60.0, 70.0, 0.0, DEFAULT)
    b = project(70.0, 70.0, 0.0, DEFAULT)
    c = project(60.0, 80.0, 0.0, DEFAULT)
    assert abs(b.row - a.row) > 10 * abs(b.col - a.col)  # X moves rows
    assert abs(c.col - a.col) > 10 * abs(c.row - a.row)  # Y moves columns


def test_paper_points_are_in_the_paper_image() -> None:
    pts = np.array([[31, 21, 5], [95, 24, 7], [39, 71, 8], [102, 77, 6.5]], dtype=float)
    q = project(pts[:, 0], pts[:, 1], pts[:, 2], PAPER)
    assert q.valid.all()
    assert (q.row >= 0).all() and (q.row <= PAPER.rows - 1).all()
    assert (q.col >= 0).all() and (q.col <= PAPER.cols - 1).all()


def test_behind_camera_is_not_projectable_and_not_nan() -> None:
    # A point above and behind the camera, and one exactly at the lens.
    q = project([65.0, 65.0], [400.0, 134.0], [300.0, 145.0], PAPER)
    assert not q.valid.any()
    assert np.isfinite(q.row).all() and np.isfinite(q.col).all()


def test_ray_parallel_to_plane_is_reported() -> None:
    # Pixels far above the horizon see the plane Z=0 behind the camera, or never.
    cam = msgspec.structs.replace(PAPER, theta_deg=5.0)
    b = back_project(np.array([96.0, 96.0]), np.array([-5000.0, 96.0]), cam, 0.0)
    assert not b.valid[0] and b.valid[1]
    assert np.isfinite(b.x_cm).all()


def _random_camera(rng: np.random.Generator, base):
    fields = {}
    for name in ("Z0_cm", "lam_mm", "k1", "k2", "k3", "s_x", "s_y"):
        lo, hi = getattr(RANGES, name)
        fields[name] = float(rng.uniform(lo, hi))
    return msgspec.structs.replace(base, **fields)


@pytest.mark.parametrize("base", [PAPER, DEFAULT], ids=["paper", "default"])
def test_round_trip_over_whole_parameter_range(base) -> None:
    rng = np.random.default_rng(1)
    worst = 0.0
    for _ in range(200):
        cam = _random_camera(rng, base)
        row = rng.uniform(0, cam.rows - 1, 500)
        col = rng.uniform(0, cam.cols - 1, 500)
        z = rng.uniform(0, 10, 500)
        b = back_project(row, col, cam, z)
        assert b.valid.all()
        q = project(b.x_cm, b.y_cm, z, cam)
        assert q.valid.all()
        # world -> pixel -> world
        b2 = back_project(q.row, q.col, cam, z)
        worst = max(worst, float(np.max(np.hypot(b2.x_cm - b.x_cm, b2.y_cm - b.y_cm))))
        np.testing.assert_allclose(q.row, row, atol=1e-7)
        np.testing.assert_allclose(q.col, col, atol=1e-7)
    assert worst < 1e-6


@settings(max_examples=200, deadline=None)
@given(
    x=st.floats(30, 100),
    y=st.floats(36, 122),
    z=st.floats(0, 10),
    lam=st.floats(3.5, 8.0),
    s_x=st.floats(0.1, 1.0),
    s_y=st.floats(0.1, 1.0),
    k=st.tuples(*[st.floats(-1e-6, 1e-6)] * 3),
)
def test_world_pixel_world_property(x, y, z, lam, s_x, s_y, k) -> None:
    cam = msgspec.structs.replace(DEFAULT, lam_mm=lam, s_x=s_x, s_y=s_y, k1=k[0], k2=k[1], k3=k[2])
    q = project(x, y, z, cam)
    assert q.valid
    b = back_project(q.row, q.col, cam, z)
    assert b.valid
    assert abs(b.x_cm - x) < 1e-6 and abs(b.y_cm - y) < 1e-6


def test_population_broadcasting() -> None:
    # Camera parameters as (P, 1) arrays against (N,) points give (P, N) pixels.
    P = 5
    cam = msgspec.structs.replace(
        DEFAULT, Z0_cm=np.linspace(125, 150, P)[:, None], s_x=np.full((P, 1), 0.2)
    )
    q = project(np.array([50.0, 60, 70]), np.array([60.0, 70, 80]), np.zeros(3), cam)
    assert q.row.shape == (P, 3) and q.valid.all()
    one = project(50.0, 60.0, 0.0, msgspec.structs.replace(DEFAULT, Z0_cm=150.0, s_x=0.2))
    assert q.row[-1, 0] == pytest.approx(float(one.row))


def test_footprint_matches_area_of_projected_square() -> None:
    # A 1 cm square on the floor covers about 1/footprint pixels.
    cam = DEFAULT
    q = project(65.0, 80.0, 0.0, cam)
    fp = pixel_footprint_cm2(q.row, q.col, cam, 0.0)
    corners = project(
        np.array([64.5, 65.5, 65.5, 64.5]), np.array([79.5, 79.5, 80.5, 80.5]), np.zeros(4), cam
    )
    r, c = corners.row, corners.col
    area_px = 0.5 * abs(np.dot(r, np.roll(c, 1)) - np.dot(c, np.roll(r, 1)))
    assert float(fp) * area_px == pytest.approx(1.0, rel=1e-3)
