"""The fuzzy planner tuned by ovis's GA (:func:`ovis.common.calibration.ga.run_ga`: the
paper's binary-coded GA, Gray-coded, tournaments, two-point crossover), as Pratihar,
Deb & Ghosh tuned theirs: the scaling factors of the membership functions and the rule
base together, against the travel time over training scenarios.

A string holds :data:`N_VARIABLES` variables:

* the four scalings (distance, angle, deviation steps; the slowest speed's share) and
  the look-ahead of the critical obstacle's prediction, on the ranges of
  :data:`SCALINGS`;
* per rule (distance × angle, 20), whether it is on (a value ≥ 0.5), its deviation
  term (0…5, rounded down) and its speed term (0…4, rounded down);
* the arena's edge (:mod:`.fuzzy`): the edge rule's band and the speed it takes away
  with the heading, on the ranges of :data:`EDGE`, and whether the side is chosen by
  the room (a value ≥ 0.5);
* whether the critical body is taken at its closest approach (a value ≥ 0.5).

A string's fitness is the mean cost of its drives over the training scenarios in the
fast simulation (:func:`ovis.common.navigation.training.costs`: the time ratio at the
goal, penalties for contacts and timeouts), each scenario weighing the same; the whole
population is driven in one batch per set of scenarios. The scenarios may come in
sets of different numbers of robots (one robot among obstacles, and two with crossing
goals: each sees the other as a moving obstacle), so that one controller learns both.
Training scenarios are drawn from seeds :data:`~.scenarios.TRAINING_SEED0` on, which
evaluations never use.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ovis.common.calibration.ga import GAResult, GenerationStats, run_ga
from ovis.common.config import GAConfig, NavigationConfig
from ovis.common.navigation.base import DriveLimits
from ovis.common.navigation.fuzzy import (
    ANGLE_TERMS,
    DEVIATION_TERMS,
    DISTANCE_TERMS,
    SPEED_TERMS,
    FuzzyArrays,
    FuzzyParams,
    Rule,
)
from ovis.common.navigation.planners import fuzzy_batch
from ovis.common.navigation.scenarios import Scenario
from ovis.common.navigation.sides import Sides
from ovis.common.navigation.steering import Arena, Turns
from ovis.common.navigation.training import (
    CONTACT_COST,
    CONTACT_MARGIN_CM,
    TIMEOUT_COST,
    Drives,
    costs,
    simulate,
    training_set,
)

__all__ = [
    "EDGE",
    "N_VARIABLES",
    "SCALINGS",
    "TuningResult",
    "bounds",
    "decode_arrays",
    "decode_params",
    "drive_with",
    "mixed_costs",
    "tune_fuzzy",
]

#: Ranges of the scalings and the look-ahead.
SCALINGS = {
    "distance_step_cm": (5.0, 60.0),
    "angle_step_deg": (10.0, 80.0),
    "deviation_step_deg": (10.0, 80.0),
    "slowest": (0.0, 0.6),
    "lookahead_s": (0.0, 2.0),
}
#: Ranges of the edge's band (cm beyond the robot's radius) and speed share taken away.
EDGE = {"edge_cm": (2.0, 20.0), "edge_slow": (0.0, 1.0)}
#: Range of the guard's time to contact (s; :mod:`.guard`).
GUARD_S = (0.0, 2.5)
RULES = 20
N_VARIABLES = len(SCALINGS) + 3 * RULES + len(EDGE) + 3
#: Just below the top of a term's range, so that its last value decodes to the last term.
_TOP = 1.0 - 1e-9


def bounds() -> NDArray[np.float64]:
    """(N_VARIABLES, 2) ranges of a string's variables (module docstring)."""
    rows = list(SCALINGS.values())
    rows += [(0.0, 1.0)] * RULES
    rows += [(0.0, len(DEVIATION_TERMS) - _TOP)] * RULES
    rows += [(0.0, len(SPEED_TERMS) - _TOP)] * RULES
    rows += [*EDGE.values(), (0.0, 1.0), (0.0, 1.0), GUARD_S]
    return np.array(rows, dtype=np.float64)


def decode_arrays(values: NDArray[np.float64]) -> FuzzyArrays:
    """(P, N_VARIABLES) decoded strings as P controllers."""
    v = np.asarray(values, dtype=np.float64).reshape(-1, N_VARIABLES)
    n = len(SCALINGS)
    e = n + 3 * RULES
    shape = (v.shape[0], 4, 5)
    return FuzzyArrays(
        *(v[:, k] for k in range(n)),
        np.floor(v[:, n + RULES : n + 2 * RULES]).astype(np.int64).reshape(shape),
        np.floor(v[:, n + 2 * RULES : e]).astype(np.int64).reshape(shape),
        (v[:, n : n + RULES] >= 0.5).reshape(shape),
        v[:, e],
        v[:, e + 1],
        v[:, e + 2] >= 0.5,
        v[:, e + 3] >= 0.5,
        v[:, e + 4],
    )


def decode_params(values: NDArray[np.float64], origin: str) -> FuzzyParams:
    """One decoded string as a controller."""
    f = decode_arrays(values)
    rules = [
        Rule(
            distance=DISTANCE_TERMS[i],  # type: ignore[arg-type]
            angle=ANGLE_TERMS[j],  # type: ignore[arg-type]
            deviation=DEVIATION_TERMS[int(f.deviation[0, i, j])],  # type: ignore[arg-type]
            speed=SPEED_TERMS[int(f.speed[0, i, j])],  # type: ignore[arg-type]
            on=bool(f.on[0, i, j]),
        )
        for i in range(4)
        for j in range(5)
    ]
    return FuzzyParams(
        distance_step_cm=round(float(f.distance_step[0]), 4),
        angle_step_deg=round(float(f.angle_step[0]), 4),
        deviation_step_deg=round(float(f.deviation_step[0]), 4),
        slowest=round(float(f.slowest[0]), 4),
        lookahead_s=round(float(f.lookahead[0]), 4),
        rules=rules,
        edge_cm=round(float(f.edge_cm[0]), 4),
        edge_slow=round(float(f.edge_slow[0]), 4),
        side_by_room=bool(f.side_by_room[0]),
        closest_approach=bool(f.closest_approach[0]),
        guard_s=round(float(f.guard[0]), 4),
        origin=origin,
    )


def drive_with(
    controllers: FuzzyArrays,
    scenarios: Sequence[Scenario],
    nav: NavigationConfig,
    margin_cm: float = CONTACT_MARGIN_CM,
) -> Drives:
    """Every controller's drives over the scenarios in the fast simulation (a contact
    closer than ``margin_cm``)."""
    limits = DriveLimits.of(nav)
    data = training_set(scenarios)
    (x0, x1), (y0, y1) = scenarios[0].scene.arena_x_cm, scenarios[0].scene.arena_y_cm
    arena = Arena(x0, x1, y0, y1)

    sides, turns = Sides(), Turns()

    def policy(s, rows):
        f = controllers.take(rows)
        return fuzzy_batch(s, f, limits, nav.goal_tolerance_cm, arena, sides, turns=turns)[0]

    return simulate(policy, data, controllers.distance_step.size, nav, margin_cm)


def mixed_costs(
    controllers: FuzzyArrays, sets: Sequence[Sequence[Scenario]], nav: NavigationConfig
) -> NDArray[np.float64]:
    """Each controller's mean cost over the scenarios of all ``sets`` (each set of one
    number of robots; every scenario weighs the same), (C,)."""
    total = sum(len(s) for s in sets)
    if total == 0:
        raise ValueError("no training scenarios")
    return sum(len(s) / total * costs(drive_with(controllers, s, nav)) for s in sets if s)


class TuningResult(NamedTuple):
    """The tuned controller, its GA run, and its cost against the designer's."""

    params: FuzzyParams
    ga: GAResult
    designer_cost: float


def tune_fuzzy(
    sets: Sequence[Sequence[Scenario]],
    nav: NavigationConfig,
    ga: GAConfig,
    designer_cost: float,
    *,
    on_generation: Callable[[GenerationStats], None] | None = None,
) -> TuningResult:
    """Tune the fuzzy planner on the scenarios of ``sets`` (each of one number of
    robots; module docstring) with the GA settings ``ga``; ``designer_cost`` is the
    untuned controller's cost, for the record."""
    sets = [s for s in sets if s]

    def fitness(values: NDArray[np.float64]) -> NDArray[np.float64]:
        return mixed_costs(decode_arrays(values), sets, nav)

    result = run_ga(fitness, bounds(), ga, on_generation=on_generation)
    described = ", ".join(
        f"{len(s)} {'training scenarios' if k == 0 else 'more'} of {len(s[0].tasks)} "
        f"robot{'s' if len(s[0].tasks) > 1 else ''} (seeds {s[0].seed}…{s[-1].seed})"
        for k, s in enumerate(sets)
    )
    origin = (
        f"ovis navigate --tune: case {sets[0][0].case}, {described}, "
        f"GA population {ga.population}, {ga.generations} generations, "
        f"{ga.bits} bits, seed {ga.seed}, contact margin {CONTACT_MARGIN_CM:g} cm, "
        f"contact cost {CONTACT_COST:g}, timeout cost {TIMEOUT_COST:g}; "
        f"cost {result.best_fitness:.4f} "
        f"(designer's {designer_cost:.4f})"
    )
    return TuningResult(decode_params(result.best_values, origin), result, designer_cost)
