"""The quality gate before a calibration is published (common/calibration/gate.py) and
the calibrator's decision with it on simulated frames (common/pipeline/candidate.py)."""

from __future__ import annotations

import cv2
import msgspec
import numpy as np
import pytest

from ovis.common.calibration.calibrate import calibrate
from ovis.common.calibration.file import load_calibration
from ovis.common.calibration.gate import (
    DIPE_FLOOR_PX,
    MAX_DIPE_RATIO,
    Seen,
    dipe_problem,
    gate_problem,
    sight_problem,
)
from ovis.common.calibration.rejected import KEEP_REJECTED, save_rejected
from ovis.common.config import ControlPoint, load_config
from ovis.common.pipeline.candidate import judge_candidate, seen_by
from ovis.common.sim.arena import Arena, control_points

FOUR = [Seen(80, 80, 7), Seen(92, 116, 4), Seen(67, 63, 4.5), Seen(57, 48, 5)]


def test_dipe_many_times_worse_is_refused_unless_forced() -> None:
    assert dipe_problem(0.3, 0.3) is None
    assert dipe_problem(DIPE_FLOOR_PX, 0.1) is None  # below a pixel: no ratio asked
    worse = 1.01 * MAX_DIPE_RATIO * 0.5
    assert dipe_problem(worse, 0.5) == (
        f"DIPE {worse:.3g} px vs 0.5 px: more than 3x worse than the current calibration "
        "(send force to publish it anyway)"
    )
    assert dipe_problem(worse, 0.5, force=True) is None
    assert dipe_problem(worse, None) is None  # nothing in use yet


@pytest.mark.parametrize("force", [False, True])
def test_an_unbelievable_dipe_is_refused_even_forced_or_first(force: bool) -> None:
    for current in (0.3, None):
        problem = dipe_problem(152.0, current, force)
        assert problem is not None and problem.startswith("DIPE 152 px")
        assert "above 3 px" in problem
    assert dipe_problem(float("nan"), None) is not None


def test_seeing_nothing_is_refused_even_forced() -> None:
    for force in (False, True):
        assert sight_problem([], FOUR, force) == (
            "sees no object on its frame, the current calibration sees 4"
        )
    assert sight_problem([], []) is None


def test_objects_must_be_seen_inside_their_footprint() -> None:
    assert sight_problem([Seen(o.x_cm + 1.5, o.y_cm - 1, 6) for o in FOUR], FOUR) is None
    shifted = [Seen(o.x_cm + 40, o.y_cm, o.radius_cm) for o in FOUR]
    problem = sight_problem(shifted, FOUR)
    assert problem is not None and problem.startswith("sees 4 objects, ")
    assert sight_problem(shifted, FOUR, force=True) is None
    one_off = [*FOUR[:3], Seen(57 + 6, 48, 5)]  # 6 cm from a 5 cm object
    assert "3 of the current calibration's 4" in (sight_problem(one_off, FOUR) or "")
    extra = sight_problem([*FOUR, Seen(10, 10, 3)], FOUR)
    assert extra is not None and extra.startswith("sees 5 objects, 4 of")
    # one candidate object cannot stand for two current ones
    assert sight_problem([FOUR[0]] * 4, FOUR) is not None


def test_the_most_objects_are_matched_not_the_closest_pair_first() -> None:
    """Two current objects, a candidate object halfway between them and one only the first
    can see: each current object is seen by its own (closest pairs first would give the
    halfway one to the first object and leave the second unseen)."""
    current = [Seen(0.0, 0.0, 2.0), Seen(3.0, 0.0, 2.0)]
    assert sight_problem([Seen(1.5, 0.0, 2.0), Seen(-1.9, 0.0, 2.0)], current) is None
    moved = [Seen(1.5, 0.0, 2.0), Seen(-2.5, 0.0, 2.0)]  # outside the first one's footprint
    assert sight_problem(moved, current) == (
        "sees 2 objects, 1 of the current calibration's 2 where it sees them (largest "
        "offset 1.5 cm; send force if the camera moved)"
    )


def test_gate_names_the_check() -> None:
    assert gate_problem(0.2, 0.3, FOUR, FOUR) is None
    assert gate_problem(152.0, 0.3, FOUR, FOUR) == (
        "rejected candidate: DIPE 152 px vs 0.3 px: above 3 px, the camera does not "
        "explain the control points"
    )
    assert (gate_problem(0.2, 0.3, [], FOUR) or "").startswith("rejected candidate: sees no")


@pytest.fixture(scope="module")
def arena_calibrated():
    cfg = load_config(preset="default")
    arena = Arena(cfg, 0)
    frame, truth = arena.render()
    calib, _ = calibrate(frame, control_points(truth), cfg)
    return cfg, arena, frame, truth, calib


def _points(truth, change) -> list[ControlPoint]:
    return [
        ControlPoint(name=p.name, **dict(zip(("x_cm", "y_cm", "z_cm"), change(p), strict=True)))
        for p in control_points(truth)
    ]


@pytest.mark.parametrize(
    "change",
    [
        lambda p: (p.x_cm + 40, p.y_cm, p.z_cm),
        lambda p: (p.x_cm * 1.3, p.y_cm * 1.3, p.z_cm),
        lambda p: (p.y_cm, p.x_cm, p.z_cm),
    ],
    ids=["shifted 40 cm", "scaled 1.3x", "axes swapped"],
)
def test_poisoned_control_points_give_a_refused_candidate(arena_calibrated, change) -> None:
    cfg, _, frame, truth, current = arena_calibrated
    candidate, _ = calibrate(frame, _points(truth, change), cfg)
    assert candidate.dipe_px > 10 * MAX_DIPE_RATIO * current.dipe_px
    problem = judge_candidate(candidate, current, frame)
    assert problem is not None and problem.startswith(
        f"rejected candidate: DIPE {candidate.dipe_px:.3g} px vs {current.dipe_px:.3g} px"
    )
    assert judge_candidate(candidate, current, frame, force=True) == problem
    # refused on its DIPE alone: no detection runs (it would refuse a frame this small)
    assert judge_candidate(candidate, current, frame[:8, :8]) == problem
    first = judge_candidate(candidate, None, frame)  # even as the first one
    assert first == f"rejected candidate: DIPE {candidate.dipe_px:.3g} px: above 3 px, " + (
        "the camera does not explain the control points"
    )


def test_a_genuine_recalibration_on_a_later_frame_passes(arena_calibrated) -> None:
    cfg, arena, _, _, current = arena_calibrated
    for _ in range(5):
        arena.step()
    frame, truth = arena.render()
    candidate, _ = calibrate(frame, control_points(truth), cfg)
    assert len(seen_by(current, frame)) == len(truth.objects)
    assert judge_candidate(candidate, current, frame) is None


@pytest.mark.parametrize(
    ("part", "change"),
    [
        ("image", {"threshold": 255}),
        # a region of interest that holds no object: the stages apply it too
        ("image", {"roi": "EMPTY_ROI"}),
        ("pose", {"obstacle_height_cm": 100.0, "robot_height_cm": 100.0}),
    ],
)
def test_a_calibration_that_sees_nothing_is_refused(
    arena_calibrated, part, change, tmp_path
) -> None:
    _, _, frame, truth, current = arena_calibrated
    if change.get("roi") == "EMPTY_ROI":
        empty = tmp_path / "roi.png"
        cv2.imwrite(str(empty), np.zeros(frame.shape[:2], np.uint8))
        change = {"roi": str(empty)}
    blind = msgspec.structs.replace(
        current, **{part: msgspec.structs.replace(getattr(current, part), **change)}
    )
    assert seen_by(blind, frame) == []
    n = len(truth.objects)
    want = f"rejected candidate: sees no object on its frame, the current calibration sees {n}"
    assert judge_candidate(blind, current, frame) == want
    assert judge_candidate(blind, current, frame, force=True) == want


def test_rejected_candidates_are_kept_aside_and_bounded(tmp_path, arena_calibrated) -> None:
    calib = arena_calibrated[4]
    paths = [save_rejected(tmp_path, calib, f"reason {i}") for i in range(KEEP_REJECTED + 3)]
    kept = sorted((tmp_path / "rejected").glob("candidate-*.json"))
    assert kept == paths[-KEEP_REJECTED:]
    assert load_calibration(kept[-1]) == calib
    assert kept[-1].with_suffix(".reason").read_text() == f"reason {KEEP_REJECTED + 2}\n"
    assert not list(tmp_path.glob("calibration-v*.json"))  # never a version of the store
