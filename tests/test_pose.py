"""Robot rule and identities across frames (paper §5.2)."""

from __future__ import annotations

import numpy as np

from ovis.common.config import PoseConfig
from ovis.common.pose import ROBOT_ID, Tracker, pick_robot


def test_robot_is_least_compact_candidate_in_area_range() -> None:
    pose = PoseConfig(robot_max_compactness=0.9, robot_area_cm2=(100.0, 300.0))
    compact = np.array([1.0, 0.75, 0.70, 0.80])
    area = np.array([150.0, 160.0, 50.0, 200.0])  # index 2 is too small
    assert pick_robot(compact, area, pose) == 1
    assert pick_robot(np.array([1.0, 0.98]), np.array([150.0, 150.0]), pose) == -1
    assert pick_robot(np.zeros(0), np.zeros(0), pose) == -1


def test_tracker_keeps_ids_through_motion_and_crossing_order() -> None:
    t = Tracker(gate_cm=10.0)
    ids0, v0 = t.update(np.array([[10.0, 10.0], [50.0, 10.0], [30.0, 40.0]]))
    assert ids0.tolist() == [1, 2, 3] and ROBOT_ID not in ids0
    assert (v0 == 0).all()
    # Next frame: everything moved 3 cm and the detections come in another order.
    ids1, v1 = t.update(np.array([[33.0, 40.0], [13.0, 10.0], [53.0, 10.0]]))
    assert ids1.tolist() == [3, 1, 2]
    np.testing.assert_allclose(v1, [[3.0, 0.0]] * 3)
    # Constant velocity is predicted: a 9 cm step after a 3 cm one is within the gate.
    ids2, _ = t.update(np.array([[22.0, 10.0]]))
    assert ids2.tolist() == [1]


def test_tracker_gives_new_ids_beyond_the_gate_and_never_reuses() -> None:
    t = Tracker(gate_cm=5.0)
    t.update(np.array([[0.0, 0.0]]))
    ids, _ = t.update(np.array([[20.0, 0.0], [0.5, 0.0]]))
    assert ids.tolist() == [2, 1]
    ids, _ = t.update(np.zeros((0, 2)))
    assert ids.size == 0
    ids, _ = t.update(np.array([[0.5, 0.0]]))
    assert ids.tolist() == [3]  # the track was lost: a new id, never an old one
