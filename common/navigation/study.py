"""Many scenarios driven by one planner, each fed by ovis and again by the oracle
(``ovis navigate``): the configuration it runs with, the planner it is given, the runs.

**Configuration** (:func:`navigate_config`): the physical world seen by the chosen
camera (a rig or a calibration), rendered **without shadows** (a frame costs several
times less; ovis segments against the empty floor either way), with the marked robots
a drive needs (:func:`~.scenarios.driving_config`). ovis's detection uses the camera's
true calibration: calibrating it on the floor marks lands within hundredths of a
centimetre (docs/physical.md), a GA run per scenario that would change nothing here.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Literal, NamedTuple

import msgspec

from ovis.common.config import CameraModel, OvisConfig
from ovis.common.navigation.episode import EpisodeResult, run_episode
from ovis.common.navigation.fuzzy import FuzzyParams
from ovis.common.navigation.planners import make_planner
from ovis.common.navigation.scenarios import Scenario, driving_config, make_scenario

__all__ = ["Driven", "drive_scenarios", "navigate_config"]

FEEDS = ("ovis", "oracle")


class Driven(NamedTuple):
    """One scenario and its runs (feed → result)."""

    scenario: Scenario
    runs: dict[str, EpisodeResult]


def navigate_config(
    config: OvisConfig,
    camera: CameraModel,
    *,
    case: int | None = None,
    robots: int | None = None,
) -> OvisConfig:
    """The configuration ``ovis navigate`` drives with (module docstring)."""
    nav = config.navigation
    nav = msgspec.structs.replace(
        nav,
        case=nav.case if case is None else case,
        robots=nav.robots if robots is None else robots,
    )
    phys = msgspec.structs.replace(config.physical, shadows=False)
    cfg = msgspec.structs.replace(config, camera=camera, physical=phys, navigation=nav)
    return driving_config(cfg)


def drive_scenarios(
    config: OvisConfig,
    seeds: Sequence[int],
    planner: str,
    fuzzy: FuzzyParams | None,
    feeds: Sequence[Literal["ovis", "oracle"]] = FEEDS,
    *,
    progress: Callable[[int, int, str], None] | None = None,
) -> list[Driven]:
    """Drive the scenarios of ``seeds`` with ``planner`` (``fuzzy``: its controller),
    each with every feed; ``progress(done, total, label)`` after each run."""
    total = len(seeds) * len(feeds)
    out: list[Driven] = []
    done = 0
    for seed in seeds:
        scenario = make_scenario(config, seed, [config.camera])
        runs: dict[str, EpisodeResult] = {}
        for feed in feeds:
            planners = {t.id: make_planner(planner, config, fuzzy) for t in scenario.tasks}
            runs[feed] = run_episode(scenario, config, planners, feed)
            done += 1
            if progress is not None:
                r = runs[feed]
                verdict = "reached" if r.success else ("contact" if r.collided else "timeout")
                progress(done, total, f"seed {seed} {feed}: {verdict}")
        out.append(Driven(scenario, runs))
    return out
