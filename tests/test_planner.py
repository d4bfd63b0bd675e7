"""Motion-planner inputs (paper §5.2): Table 1 distances and the angle definition."""

from __future__ import annotations

import numpy as np
import pytest

from ovis.common.world.planner import (
    planner_inputs,
    signed_angle_deg,
    signed_angle_of,
    wrap_angle_deg,
)

R_O1, R_O2 = 4.884, 5.272  # radii of the paper's two obstacles (Case 1)

# Paper Table 1 (Case 1): robot position, obstacle positions, printed distances.
TABLE_1 = [
    ((98.241, 30.626), (28.715, 26.300), 64.776, (96.862, 132.382), 96.493),
    ((88.829, 50.936), (40.496, 60.470), 44.380, (85.215, 108.946), 52.850),
    ((79.721, 70.979), (50.221, 95.894), 33.730, (74.491, 85.831), 10.474),
    ((70.892, 92.205), (60.948, 127.329), 31.621, (63.028, 62.831), 25.136),
]


@pytest.mark.parametrize("robot,o1,d1,o2,d2", TABLE_1)
def test_table_1_distances(robot, o1, d1, o2, d2) -> None:
    # The second row prints 52.580 for O2: the positions give 52.850, a transposition
    # of two digits in the paper (every other distance matches to the last digit).
    p = planner_inputs(robot, [(*o1, R_O1), (*o2, R_O2)], goal_xy=(65.0, 105.0))
    assert p.distance_cm == pytest.approx([d1, d2], abs=0.002)


def test_angle_hand_computed() -> None:
    # Robot at origin, goal straight up (+Y).
    obs = [(10, 0, 1), (0, 10, 1), (-10, 0, 1), (0, -10, 1), (10, 10, 1)]
    p = planner_inputs((0, 0), obs, goal_xy=(0, 50))
    np.testing.assert_allclose(p.angle_deg, [-90.0, 0.0, 90.0, 180.0, -45.0])
    np.testing.assert_allclose(p.distance_cm, [9, 9, 9, 9, np.hypot(10, 10) - 1])


def test_goal_reference_line_takes_precedence() -> None:
    p = planner_inputs((0, 0), [(10, 10, 1)], goal_xy=(0, 50), goal_angle_deg=0.0)
    assert p.angle_deg[0] == pytest.approx(45.0)
    p = planner_inputs((5, 5), [(5, 15, 1)], goal_angle_deg=116.0)
    assert p.angle_deg[0] == pytest.approx(90.0 - 116.0)


def test_signed_angle_range() -> None:
    a = signed_angle_deg(0.0, np.radians([180.0, -180.0, 540.0, 181.0, -179.0]))
    np.testing.assert_allclose(a, [180.0, 180.0, 180.0, -179.0, -179.0])


def test_one_pair_at_a_time_is_the_array_form_to_the_last_bit() -> None:
    """The per-robot planner's scalar angle (plain Python, a few pairs a frame) equals
    the array form exactly, at random angles and at the wrap's edges."""
    rng = np.random.default_rng(5)
    edges = np.radians([180.0, -180.0, 540.0, 0.0, 360.0, -360.0, 1e-17, -1e-17])
    frm = np.concatenate([rng.uniform(-20.0, 20.0, 5000), np.zeros(edges.size)])
    to = np.concatenate([rng.uniform(-20.0, 20.0, 5000), edges])
    array = signed_angle_deg(frm, to)
    one = [signed_angle_of(f, t) for f, t in zip(frm.tolist(), to.tolist(), strict=True)]
    assert np.array_equal(array, one)
    assert all(-180.0 < a <= 180.0 for a in one)
    assert [wrap_angle_deg(a) for a in (-180.0, 540.0, -179.0, -541.0)] == [
        180.0,
        180.0,
        -179.0,
        179.0,
    ]


def test_bad_input() -> None:
    with pytest.raises(ValueError, match="goal"):
        planner_inputs((0, 0), [(1, 1, 1)])
    with pytest.raises(ValueError, match="finite"):
        planner_inputs((np.nan, 0), [(1, 1, 1)], goal_xy=(0, 1))
    with pytest.raises(ValueError, match="on the goal"):
        planner_inputs((0, 1), [(1, 1, 1)], goal_xy=(0, 1))
