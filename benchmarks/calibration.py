"""GA calibration (issue 4, row c).

``calibrate`` with the default preset (the paper's GA: population 100, 90 generations,
9 variables) on a 640×480 simulated frame, against the same GA evaluated "from scratch":
every individual, one at a time, smooths, thresholds and labels the frame itself (the
:class:`CalibrationProblem` with its per-threshold blob cache emptied before each string,
``dedupe=False``). Both runs use the same seed and must give the same best string.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from statistics import median

import msgspec
import numpy as np

from benchmarks.core import Row
from ovis.common.calibration.calibrate import calibrate
from ovis.common.calibration.ga import GAResult, run_ga
from ovis.common.calibration.problem import INFEASIBLE, CalibrationProblem
from ovis.common.config import OvisConfig, load_config
from ovis.common.sim.arena import Arena, control_points
from ovis.common.vision.frames import as_gray
from ovis.common.vision.smoothing import smooth

__all__ = ["calibration_rows"]

SEED = 0
#: Longest the from-scratch run may take before it is cut short and extrapolated (s).
NAIVE_BUDGET_S = 60.0
QUICK_NAIVE_BUDGET_S = 6.0


class ScratchFitness:
    """Fitness without the speed-up: per string, smooth + threshold + label + match."""

    def __init__(self, frame, points, config: OvisConfig) -> None:
        self.problem = CalibrationProblem(frame, points, config)
        self.gray = as_gray(frame)
        self.median = config.image.median
        self.cache = getattr(self.problem, "_tables", None)
        self.fresh_problem = self.cache is None or not hasattr(self.problem, "smoothed")
        self.frame, self.points, self.config = frame, points, config

    def one(self, values: np.ndarray) -> float:
        if self.fresh_problem:  # the cache is not where we expect it: start from nothing
            problem = CalibrationProblem(self.frame, self.points, self.config)
        else:
            problem = self.problem
            problem.smoothed = smooth(self.gray, self.median)
            self.cache.clear()
        return float(problem.fitness(values[None, :])[0])

    def __call__(self, values: np.ndarray) -> np.ndarray:
        return np.array([self.one(v) for v in values])


def _ga(fitness, config: OvisConfig, generations: int, dedupe: bool) -> tuple[GAResult, float]:
    ga = msgspec.structs.replace(config.ga, generations=generations)
    bounds = np.array(config.calibration.bounds())
    t0 = time.perf_counter()
    result = run_ga(fitness, bounds, ga, dedupe=dedupe, feasible_below=INFEASIBLE)
    return result, time.perf_counter() - t0


#: Measures one calibration in a fresh process and prints its peak memory (ru_maxrss).
_PEAK_SCRIPT = """
import json, resource, sys, time
from ovis.common.config import load_config, with_ga
from ovis.common.calibration.calibrate import calibrate
from ovis.common.sim.arena import Arena, control_points
population, generations = int(sys.argv[1]), int(sys.argv[2])
config = load_config()
frame, truth = Arena(config, 0).render()
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
config = with_ga(config, population=population, generations=generations)
t0 = time.perf_counter()
calibrate(frame, control_points(truth), config)
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({"peak_mb": peak, "base_mb": base, "s": time.perf_counter() - t0}))
"""

#: The largest calibration's peak memory must stay within this (MB).
PEAK_LIMIT_MB = 1024.0


def largest_calibration_rows(quick: bool, log=print) -> list[Row]:
    """Peak memory of the largest calibration the calibrator accepts
    (``[service] max_population`` and ``max_evaluations`` of the default preset) on the
    simulated arena, in a fresh process; the floor is the same process before the GA.
    ``quick`` runs 10 generations (the population sets the memory, not the generations)."""
    limits = load_config().service
    population = limits.max_population
    generations = 10 if quick else limits.max_evaluations // population
    out = subprocess.run(
        [sys.executable, "-c", _PEAK_SCRIPT, str(population), str(generations)],
        capture_output=True,
        text=True,
        check=True,
        timeout=1800,
    )
    got = json.loads(out.stdout.strip().splitlines()[-1])
    peak, base = got["peak_mb"], got["base_mb"]
    log(
        f"  largest allowed calibration P={population}, G={generations}: peak {peak:.0f} MB "
        f"(before the GA {base:.0f} MB) in {got['s']:.1f} s"
    )
    return [
        Row(
            name=f"GA calibration: peak memory of the largest allowed calibration "
            f"(P={population}, G={generations}, simulated arena; floor: the process "
            "before the GA)",
            unit="MB",
            value=peak,
            floor=base,
            ratio=peak / base,
            target=f"≤ {PEAK_LIMIT_MB:.0f} MB",
            met=peak <= PEAK_LIMIT_MB,
        )
    ]


def calibration_rows(quick: bool, log=print) -> list[Row]:
    config = load_config()
    ga = config.ga
    frame, truth = Arena(config, SEED).render()
    points = control_points(truth)
    label = f"P={ga.population}, G={ga.generations}, V={len(config.calibration.bounds())}"

    runs = 2 if quick else 5
    calibrate(frame, points, config)  # warm-up
    times, result = [], None
    for _ in range(runs):
        t0 = time.perf_counter()
        calib, result = calibrate(frame, points, config)
        times.append(time.perf_counter() - t0)
    calibrate_s = median(times)
    log(
        f"  calibrate: median {calibrate_s:.3f} s over {runs} runs "
        f"(DIPE {calib.dipe_px:.3f} px, {result.evaluations} evaluations)"
    )
    # The GA alone (what the from-scratch run is compared with): calibrate() may do more
    # after it (threshold centring, least-squares polish).
    ga_times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        problem = CalibrationProblem(frame, points, config)
        result, _ = _ga(problem.fitness, config, ga.generations, dedupe=True)
        ga_times.append(time.perf_counter() - t0)
    fast_s = median(ga_times)
    log(f"  the GA alone: median {fast_s:.3f} s over {runs} runs")

    scratch = ScratchFitness(frame, points, config)
    # Cost of one from-scratch generation, to decide whether the full run fits the budget.
    pop0 = np.random.default_rng(1).uniform(*np.array(config.calibration.bounds()).T, (10, 9))
    t0 = time.perf_counter()
    scratch(pop0)
    per_string = (time.perf_counter() - t0) / pop0.shape[0]
    total_strings = ga.population * (ga.generations + 1)
    projected = per_string * total_strings
    budget = QUICK_NAIVE_BUDGET_S if quick else NAIVE_BUDGET_S
    if projected <= budget:
        generations = ga.generations
    else:
        generations = max(1, int(budget / (per_string * ga.population)) - 1)
    naive, naive_s = _ga(scratch, config, generations, dedupe=False)
    extrapolated = generations < ga.generations
    if extrapolated:
        # Same truncated run with the speed-up, for the identity check.
        problem = CalibrationProblem(frame, points, config)
        reference, _ = _ga(problem.fitness, config, generations, dedupe=True)
        naive_s *= (ga.generations + 1) / (generations + 1)
    else:
        reference = result
    identical = bool(np.array_equal(naive.best_bits, reference.best_bits))
    how = (
        f"{generations} generations timed, extrapolated to {ga.generations}"
        if extrapolated
        else "full run"
    )
    if scratch.fresh_problem:
        how += "; a new CalibrationProblem per string"
    log(f"  from scratch: {naive_s:.1f} s ({how}); identical best string: {identical}")
    speedup = naive_s / fast_s
    return [
        *largest_calibration_rows(quick, log),
        Row(
            name=f"GA calibration 640×480 ({label}) wall time of calibrate() "
            "(GA, then threshold centring and least-squares polish when configured)",
            unit="s",
            value=calibrate_s,
            target="< 1 s",
            met=calibrate_s < 1.0,
        ),
        Row(
            name="GA calibration: the GA alone (per-threshold blob cache, each distinct "
            "string once per generation)",
            unit="s",
            value=fast_s,
        ),
        Row(
            name="GA calibration from scratch (every string smooths, thresholds, labels; "
            f"no cache, no dedupe; {how})",
            unit="s",
            value=naive_s,
        ),
        Row(name="GA calibration speed-up: from scratch / the GA alone", unit="×", value=speedup),
        Row(
            name="GA calibration identical best string with and without the speed-up"
            + (f" ({generations} generations)" if extrapolated else ""),
            unit="",
            value=identical,
            target="identical",
            met=identical,
        ),
    ]
