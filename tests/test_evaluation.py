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


def test_a_runs_score_finds_a_position_not_measurable_within_the_uncertainty_it_states() -> None:
    """A solid whose foot is hidden is reported 7 cm along the line of sight from where it
    stands, stating 1σ of 4 cm that way: the run's score counts it found within its
    stated uncertainty, apart (not missed, not spurious, not in the position errors);
    the same detection stating 1 cm, or 7 cm off across its long axis, is missed and
    spurious as before."""
    from ovis.common.analysis.evaluation import TrackingScore
    from ovis.common.sim.arena import SimObject
    from ovis.common.world.detection import DetectedObject

    def det(x: float, y: float, cov: list[float] | None) -> DetectedObject:
        return DetectedObject(
            id=1, kind="obstacle", row=0.0, col=0.0, area_px=100.0, perimeter_px=40.0,
            compactness=1.0, x_cm=x, y_cm=y, z_cm=7.0, radius_cm=3.0, area_cm2=28.3,
            covariance_cm2=cov,
        )  # fmt: skip

    def solid(k: int, x: float, y: float) -> SimObject:
        return SimObject(
            id=k, kind="obstacle", x_cm=x, y_cm=y, z_cm=7.0, radius_cm=3.0, heading_deg=0.0,
            shape="disk", length_cm=6.0, width_cm=6.0,
        )  # fmt: skip

    truth = [solid(0, 10.0, 10.0), solid(1, 60.0, 40.0)]
    along = [16.0, 0.0, 0.0, 0.0, 0.25, 0.0, 0.0, 0.0, 4.0]  # 4 cm along x, 0.5 across
    near = det(10.2, 10.1, [0.01, 0, 0, 0, 0.01, 0, 0, 0, 1.0])
    score = TrackingScore()
    score.add([near, det(67.0, 40.0, along)], truth)
    assert (score.matched, score.missed, score.spurious, score.within_stated) == (1, 0, 0, 1)
    assert score.stated_error_cm == pytest.approx([7.0])
    assert score.stated_sigma_cm == pytest.approx([4.0])
    assert max(score.position_error_cm) < 0.3
    for wrong in (det(67.0, 40.0, [1.0, 0, 0, 0, 1.0, 0, 0, 0, 4.0]), det(60.0, 47.0, along)):
        score = TrackingScore()
        score.add([near, wrong], truth)
        assert (score.missed, score.spurious, score.within_stated) == (1, 1, 0)
        assert score.stated_error_cm == []


def test_a_fused_position_not_measurable_is_scored_within_the_uncertainty_it_states() -> None:
    """Several cameras' world frame (issue 36's fused scoring): a solid whose foot every
    camera has hidden, fused 7 cm from where it stands with a 4 cm σ, is found within
    its stated uncertainty (flagged so, not spurious); stating 1 cm it is missed and
    its fused object spurious."""
    from ovis.common.analysis.fused_heights import score_fused
    from ovis.common.fusion.merge import Fused
    from ovis.common.sim.arena import SimObject

    truth = [
        SimObject(
            id=0, kind="obstacle", x_cm=60.0, y_cm=40.0, z_cm=12.0, radius_cm=3.0,
            heading_deg=0.0, shape="disk", length_cm=6.0, width_cm=6.0,
        )
    ]  # fmt: skip

    def fused(sigma: float) -> Fused:
        return Fused(
            kind="obstacle", x_cm=67.0, y_cm=40.0, z_cm=12.0, radius_cm=3.0, sigma_cm=sigma,
            cameras=["cam00", "cam01"],
        )  # fmt: skip

    scene = score_fused(7, [fused(4.0)], truth, {"cam00": [True], "cam01": [True]})
    (o,) = scene.obstacles
    assert o.found and o.within_stated and scene.spurious == 0
    assert o.footprint_error_cm == pytest.approx(7.0)
    scene = score_fused(7, [fused(1.0)], truth, {"cam00": [True], "cam01": [True]})
    assert not scene.obstacles[0].found and scene.spurious == 1
