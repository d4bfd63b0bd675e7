"""Matching detections to ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from ovis.common.analysis.evaluation import match_to_truth


def test_match_counts_missed_spurious_and_errors() -> None:
    truth = [(0, 0, 5), (50, 0, 5), (0, 50, 6)]
    det = [(50.3, 0.4, 5.1), (0.0, 0.0, 4.8), (90, 90, 3)]
    acc = match_to_truth(
        det, ["obstacle", "robot", "obstacle"], truth, ["robot", "obstacle", "obstacle"]
    )
    assert acc.missed == 1 and acc.spurious == 1
    assert acc.truth_index.tolist() == [0, 1] and acc.detection_index.tolist() == [1, 0]
    np.testing.assert_allclose(acc.position_error_cm, [0.0, 0.5])
    np.testing.assert_allclose(acc.radius_error_cm, [-0.2, 0.1], atol=1e-12)
    assert acc.kind_correct.tolist() == [True, True]


def test_empty() -> None:
    acc = match_to_truth([], [], [(0, 0, 1)], ["robot"])
    assert acc.missed == 1 and acc.spurious == 0 and acc.position_error_cm.size == 0
    with pytest.raises(ValueError):
        match_to_truth([(0, 0)], ["robot"], [(0, 0, 1)], ["robot"])


def test_match_objects_takes_detections_and_truth_directly() -> None:
    from ovis.common.analysis.evaluation import match_objects
    from ovis.common.config import load_config
    from ovis.common.sim.arena import Arena

    _, truth = Arena(load_config(), 0).render(clean=True)
    acc = match_objects(truth.objects, truth.objects)
    assert acc.missed == acc.spurious == 0 and acc.kind_correct.all()
    assert acc.position_error_cm.max() == 0.0 and acc.truth_index.size == len(truth.objects)
