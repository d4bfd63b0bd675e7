"""Calibrate a camera on one frame and its control points (paper §4): the paper's model
by the GA of :mod:`.solve`, the pinhole camera by :mod:`.pinhole` (GA and least squares).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from ovis.common.calibration.file import Calibration
from ovis.common.calibration.ga import GAResult, GenerationStats
from ovis.common.calibration.pinhole import calibrate_pinhole
from ovis.common.calibration.problem import CalibrationProblem
from ovis.common.calibration.solve import build_calibration, run_constrained_ga
from ovis.common.config import ControlPoint, OvisConfig

__all__ = ["calibrate"]


def calibrate(
    image: NDArray[np.uint8],
    points: Sequence[ControlPoint],
    config: OvisConfig,
    *,
    on_generation: Callable[[GenerationStats], None] | None = None,
    source: str = "",
    dedupe: bool = True,
) -> tuple[Calibration, GAResult]:
    """Run the GA calibration of paper §4 on one frame; return the calibration and GA run.

    Raises :class:`InfeasibleCalibrationError` when no string in the ranges sees exactly one
    object per control point, with what was seen and what to change.
    """
    if config.camera.model == "pinhole":  # the general camera: GA + least squares
        return calibrate_pinhole(
            image, points, config, on_generation=on_generation, source=source, dedupe=dedupe
        )
    t0 = time.perf_counter()
    problem = CalibrationProblem(image, points, config)
    result = run_constrained_ga(
        problem, problem.fitness, problem.bounds, on_generation=on_generation, dedupe=dedupe
    )
    elapsed = time.perf_counter() - t0
    return build_calibration(problem, result, elapsed=elapsed, source=source), result
