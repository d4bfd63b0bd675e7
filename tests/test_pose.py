"""Robot rule and identities across frames (paper §5.2)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linear_sum_assignment

from ovis.common.config import PoseConfig
from ovis.common.world.pose import (
    ROBOT_ID,
    Tracker,
    gated_assignment,
    gated_pairs_few,
    pick_robot,
)


def test_robot_is_least_compact_candidate_in_area_range() -> None:
    pose = PoseConfig(robot_max_compactness=0.9, robot_area_cm2=(100.0, 300.0))
    compact = np.array([1.0, 0.75, 0.70, 0.80])
    area = np.array([150.0, 160.0, 50.0, 200.0])  # index 2 is too small
    assert pick_robot(compact, area, pose) == 1
    assert pick_robot(np.array([1.0, 0.98]), np.array([150.0, 150.0]), pose) == -1
    assert pick_robot(np.zeros(0), np.zeros(0), pose) == -1


def test_tracker_keeps_ids_through_motion_and_crossing_order() -> None:
    t = Tracker(gate_cm=10.0)
    ids0, v0, _ = t.track(np.array([[10.0, 10.0], [50.0, 10.0], [30.0, 40.0]]))
    assert ids0.tolist() == [1, 2, 3] and ROBOT_ID not in ids0
    assert (v0 == 0).all()
    # Next frame: everything moved 3 cm and the detections come in another order.
    ids1, v1, _ = t.track(np.array([[33.0, 40.0], [13.0, 10.0], [53.0, 10.0]]))
    assert ids1.tolist() == [3, 1, 2]
    np.testing.assert_allclose(v1, [[3.0, 0.0]] * 3)
    # Constant velocity is predicted: a 9 cm step after a 3 cm one is within the gate.
    ids2, _, _ = t.track(np.array([[22.0, 10.0]]))
    assert ids2.tolist() == [1]


def test_tracker_says_which_displacements_are_measured() -> None:
    """A new obstacle's displacement (0) is not measured; a tracked one's is."""
    t = Tracker(gate_cm=5.0)
    first = t.track(np.array([[0.0, 0.0]]))
    assert first.tracked.tolist() == [False] and first.step.tolist() == [[0.0, 0.0]]
    second = t.track(np.array([[1.0, 0.0], [30.0, 0.0]]))
    assert second.tracked.tolist() == [True, False]
    assert second.step.tolist() == [[1.0, 0.0], [0.0, 0.0]]


def test_tracker_gives_new_ids_beyond_the_gate_and_never_reuses() -> None:
    t = Tracker(gate_cm=5.0)
    t.track(np.array([[0.0, 0.0]]))
    ids, _, _ = t.track(np.array([[20.0, 0.0], [0.5, 0.0]]))
    assert ids.tolist() == [2, 1]
    ids, _, _ = t.track(np.zeros((0, 2)))
    assert ids.size == 0
    ids, _, _ = t.track(np.array([[0.5, 0.0]]))
    assert ids.tolist() == [3]  # the track was lost: a new id, never an old one


def test_reserved_ids_are_never_given_to_obstacles() -> None:
    """A calibration that configures robots 2 and 7 while obstacles 1–3 are tracked: the
    one holding 2 gets a new id above the robots', the others keep theirs, and new
    obstacles skip every id a robot has or had."""
    t = Tracker(gate_cm=5.0)
    t.track(np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]]))
    t.reserve({2, 7})
    ids, _, _ = t.track(np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [30.0, 0.0]]))
    assert ids.tolist() == [1, 8, 3, 9]
    t.reserve({10})
    ids, _, _ = t.track(np.array([[40.0, 0.0], [50.0, 0.0]]))
    assert ids.tolist() == [11, 12]
    assert ROBOT_ID in t.reserved and {2, 7, 10} <= t.reserved


def _dense_optimum(a: np.ndarray, b: np.ndarray, gate: float) -> tuple[int, float]:
    """Pairs and total distance of the one dense assignment the tracker used to solve."""
    if not (len(a) and len(b)):
        return 0, 0.0
    cost = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    rows, cols = linear_sum_assignment(np.where(cost <= gate, cost, 1e9))
    ok = cost[rows, cols] <= gate
    return int(ok.sum()), float(cost[rows, cols][ok].sum())


@settings(max_examples=300, deadline=None)
@given(
    st.integers(0, 40),
    st.integers(0, 40),
    st.floats(0.3, 6.0),
    st.floats(0.0, 1.0),
    st.integers(0, 2**32 - 1),
)
def test_gated_assignment_is_the_dense_optimum(
    n: int, m: int, gate: float, jitter: float, seed: int
) -> None:
    # Crowded points (many candidates within the gate, conflicts) and points that moved
    # little (the one-query fast path), few (dense path) and many (k-d tree path):
    # always as many pairs, and as short in total, as the dense assignment; one-to-one
    # and within the gate.
    rng = np.random.default_rng(seed)
    a = rng.random((n, 2)) * 10
    b = rng.random((m, 2)) * 10
    k = min(n, m)
    b[:k] = a[:k] + rng.normal(0.0, jitter, (k, 2))
    rows, cols = gated_assignment(a, b, gate)
    assert len(set(rows.tolist())) == rows.size and len(set(cols.tolist())) == cols.size
    dist = np.linalg.norm(a[rows] - b[cols], axis=1)
    assert (dist <= gate).all()
    pairs, total = _dense_optimum(a, b, gate)
    assert rows.size == pairs
    assert dist.sum() == pytest.approx(total, abs=1e-9)
    # the plain-Python pairs of a few points apart, where it answers: the same pairs
    few = gated_pairs_few([tuple(p) for p in a.tolist()], [tuple(p) for p in b.tolist()], gate)
    if few is not None:
        assert few == list(zip(rows.tolist(), cols.tolist(), strict=True))
    elif n * m <= 400 and n and m:
        near = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1]) <= gate
        assert near.sum(0).max() > 1 or near.sum(1).max() > 1


def test_gated_assignment_coincident_points_and_two_hundred_obstacles() -> None:
    rng = np.random.default_rng(0)
    a = rng.random((200, 2)) * [300.0, 220.0]
    rows, cols = gated_assignment(a, a.copy(), 20.0)  # distance 0 is a pair too
    np.testing.assert_array_equal(np.sort(rows), np.arange(200))
    np.testing.assert_array_equal(cols[np.argsort(rows)], np.arange(200))
    shuffled = rng.permutation(200)
    rows, cols = gated_assignment(a, a[shuffled] + 0.5, 20.0)
    np.testing.assert_array_equal(shuffled[cols], rows)
