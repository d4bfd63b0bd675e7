"""Bounded calibration (common/pipeline/recalibration.py): the limits a query must
respect, and the one running calibration's progress, cancel and time budget."""

from __future__ import annotations

import pytest

from ovis.common.config import load_config, with_ga
from ovis.common.messages import CalibrateRequest
from ovis.common.pipeline.recalibration import (
    CalibrationCancelledError,
    CalibrationJob,
    config_for_request,
    too_big,
)

CFG = load_config()


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_the_issues_query_is_refused_and_the_paper_ga_accepted() -> None:
    huge = config_for_request(CFG, CalibrateRequest(population=10000, generations=10000))
    assert too_big(huge) == (
        "refused: population 10000 is above this calibrator's limit 1000 ([service] max_population)"
    )
    long = config_for_request(CFG, CalibrateRequest(population=1000, generations=10000))
    assert too_big(long) == (
        "refused: population x generations = 1000 x 10000 = 10000000 is above this "
        "calibrator's limit 200000 ([service] max_evaluations)"
    )
    assert too_big(CFG) is None  # 100 x 90
    assert too_big(with_ga(CFG, population=1000, generations=200)) is None  # the largest


def test_one_calibration_at_a_time_and_busy_with_progress_and_eta() -> None:
    clock = Clock()
    job = CalibrationJob(clock)
    assert job.claim() and not job.claim()
    reply = job.busy_reply()
    assert reply.busy and not reply.ok and reply.eta_s is None
    assert reply.error.startswith("busy: preparing a calibration;")
    job.start(frame_seq=42, generations=100, budget_s=60.0)
    clock.t += 10.0
    job.after_generation(25)
    reply = job.busy_reply()
    assert (reply.frame_seq, reply.progress, reply.eta_s) == (42, 0.25, 30.0)
    assert reply.error.startswith(
        "busy: calibrating on frame 42: generation 25 of 100, about 30 s to go;"
    )
    job.done()
    assert job.claim()


def test_cancel_and_budget_stop_after_the_generation() -> None:
    clock = Clock()
    job = CalibrationJob(clock)
    assert not job.cancel("nothing runs")
    job.claim()
    job.start(frame_seq=1, generations=90, budget_s=5.0)
    job.after_generation(1)
    assert job.cancel("cancelled by a query")
    with pytest.raises(CalibrationCancelledError, match="generation 2 of 90: cancelled by a query"):
        job.after_generation(2)
    job.done()
    job.claim()
    job.start(frame_seq=2, generations=90, budget_s=5.0)
    clock.t += 5.5
    with pytest.raises(CalibrationCancelledError, match="time budget of 5 s is spent"):
        job.after_generation(3)
