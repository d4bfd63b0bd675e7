"""`ovis navigate`: robots driven to their goals among moving obstacles in the physical
world, on what ovis sees and on the truth; `--tune` tunes the fuzzy planner with the GA."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import msgspec
import typer

from ovis.services.cli.errors import UserError
from ovis.services.cli.options import JsonOpt, OfflineConfigOpt

__all__ = ["register"]

FeedOpt = Annotated[
    str,
    typer.Option(
        help="'both': each scenario fed by ovis's detection on rendered frames, then by "
        "the truth (the oracle); 'oracle': the truth only (no frame rendered; the summary's "
        "fields are then the oracle's)."
    ),
]


def _config(config: Path | None, camera: str, case: int | None, robots: int | None) -> Any:
    from ovis.common.navigation.study import navigate_config
    from ovis.services.cli.physical import physical_camera, require_physical, world_config

    require_physical()
    cfg = world_config(config, None, "physical")
    cam = physical_camera(camera, cfg).camera
    try:
        return navigate_config(cfg, cam, case=case, robots=robots)
    except ValueError as exc:
        raise UserError(str(exc)) from None


def _fuzzy(cfg: Any, planner_file: Path | None, untuned: bool) -> Any:
    """The fuzzy controller: --planner-file, else [navigation] planner_file, else the
    shipped tuned one; the designer's with --untuned."""
    from ovis.common.navigation.fuzzy import designer, load_fuzzy, tuned_default

    if untuned:
        if planner_file is not None:
            raise UserError("--untuned drives the designer's controller: not with --planner-file")
        return designer()
    path = planner_file or (
        Path(cfg.navigation.planner_file) if cfg.navigation.planner_file else None
    )
    if path is None:
        return tuned_default()
    try:
        return load_fuzzy(path)
    except ValueError as exc:
        raise UserError(str(exc)) from None


def navigate(
    case: Annotated[
        int | None, typer.Option(min=1, max=2, help="1: two moving obstacles; 2: four.")
    ] = None,
    runs: Annotated[int, typer.Option(min=1, max=100000, help="Scenarios to drive.")] = 10,
    seed: Annotated[
        int,
        typer.Option(min=0, help="First scenario's seed (then seed+1, …); same seed, same run."),
    ] = 0,
    planner: Annotated[
        str | None,
        typer.Option(help="'fuzzy', 'dwa' or 'straight' (default [navigation] planner)."),
    ] = None,
    planner_file: Annotated[
        Path | None,
        typer.Option(
            help="A tuned fuzzy planner (ovis navigate --tune); default the shipped one.",
            dir_okay=False,
        ),
    ] = None,
    untuned: Annotated[
        bool, typer.Option("--untuned", help="The fuzzy planner as designed, before tuning.")
    ] = False,
    robots: Annotated[
        int | None, typer.Option(min=1, max=2, help="Robots (2: crossing goals).")
    ] = None,
    camera: Annotated[
        str,
        typer.Option(
            help="'overhead' (200 cm up, straight down), 'oblique' (the tripod) or a "
            "calibration JSON."
        ),
    ] = "overhead",
    feed: FeedOpt = "both",
    config: OfflineConfigOpt = None,
    json: JsonOpt = False,
    plot: Annotated[
        Path | None,
        typer.Option(help="Draw the first scenarios' paths into this PNG.", dir_okay=False),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option(
            help="Write every run (paths, per robot figures) as JSON here.", dir_okay=False
        ),
    ] = None,
    tune: Annotated[
        bool, typer.Option("--tune", help="Tune the fuzzy planner with the GA instead (see below).")
    ] = False,
    scenarios: Annotated[
        int, typer.Option(min=1, max=10000, help="--tune: training scenarios.")
    ] = 60,
    crossing_scenarios: Annotated[
        int,
        typer.Option(
            min=0,
            max=10000,
            help="--tune: more training scenarios, of two robots with crossing goals.",
        ),
    ] = 0,
    population: Annotated[int, typer.Option(min=4, max=10000, help="--tune: GA population.")] = 60,
    generations: Annotated[
        int, typer.Option(min=1, max=10000, help="--tune: GA generations.")
    ] = 60,
    ga_seed: Annotated[int, typer.Option(min=0, help="--tune: GA seed.")] = 1,
) -> None:
    """Drive robots to their goals among moving obstacles in the physical world.

    Each of --runs scenarios of --case (seeds --seed, --seed+1, …; never the tuning's)
    is driven in lock-step simulated time at [navigation] rate_hz: the planner is fed
    ovis's detection of each rendered frame (shadows off, the camera's true
    calibration), its command reaches the robot after the pipeline's measured latency
    ([navigation] latency_ms), the robot follows it on its wheels in MuJoCo; then the
    same scenario again with the planner fed the physics truth (the oracle). Prints
    the success rate, collisions, timeouts, time ratio, closest approach, frames and
    latency of both (--json: one object).

    --tune: tune the fuzzy planner's membership functions and rules with ovis's GA on
    --scenarios training scenarios (a fast simulation of the same robots; and
    --crossing-scenarios of two robots with crossing goals, each seeing the other as a
    moving obstacle), show its
    progress, write the tuned planner to --out (default fuzzy_tuned.json) and the
    convergence to --plot (default beside it); the planner service and this command
    load it with --planner-file or [navigation] planner_file.
    """
    cfg = _config(config, camera, case, robots)
    if tune:
        counts = (scenarios, crossing_scenarios)
        return _tune(cfg, counts, population, generations, ga_seed, out, plot, json)
    name = planner or cfg.navigation.planner
    from ovis.common.navigation.planners import PLANNERS

    if name not in PLANNERS:
        raise UserError(f"--planner must be one of {', '.join(PLANNERS)}, got {name!r}")
    if feed not in ("both", "oracle"):
        raise UserError(f"--feed must be 'both' or 'oracle', got {feed!r}")
    fuzzy = _fuzzy(cfg, planner_file, untuned) if name == "fuzzy" else None
    from ovis.common.navigation.report import NavigateSummary, summarize
    from ovis.common.navigation.study import drive_scenarios
    from ovis.services.cli.ui import emit_json, progress

    feeds = ("ovis", "oracle") if feed == "both" else ("oracle",)
    seeds = list(range(seed, seed + runs))
    with progress("driving", show=not json) as update:
        try:
            driven = drive_scenarios(cfg, seeds, name, fuzzy, feeds, progress=update)
        except ValueError as exc:
            raise UserError(str(exc)) from None
    first = summarize([d.runs[feeds[0]] for d in driven])
    oracle = summarize([d.runs["oracle"] for d in driven]) if feed == "both" else None
    summary = NavigateSummary(**msgspec.structs.asdict(first), oracle=oracle)
    if out is not None:
        from ovis.common.atomic import write_atomic

        write_atomic(
            out, msgspec.json.encode([{"scenario": d.scenario, "runs": d.runs} for d in driven])
        )
    if plot is not None:
        from ovis.common.navigation.plots import plot_paths

        plot_paths([(d.scenario, d.runs[feeds[0]]) for d in driven[:6]], plot)
    if json:
        emit_json(summary)
        return
    _say(summary, name if not untuned else "fuzzy (untuned)", cfg, seeds, feed)


def _say(summary: Any, name: str, cfg: Any, seeds: list[int], feed: str) -> None:
    from ovis.services.cli.ui import console, table

    nav = cfg.navigation
    t = table(
        f"case {nav.case}, {nav.robots} robot(s), planner {name}, seeds {seeds[0]}…{seeds[-1]}",
        ["fed by", "runs", "success", "collisions", "timeouts", "time ratio p50",
         "closest cm", "frames", "latency p50 ms"],
        left=["fed by"],
    )  # fmt: skip
    rows = [("ovis" if feed == "both" else "oracle", summary)]
    if summary.oracle is not None:
        rows.append(("oracle", summary.oracle))
    for who, s in rows:
        t.add_row(
            who,
            str(s.runs),
            f"{100 * s.success_rate:.1f} %",
            str(s.collisions),
            str(s.timeouts),
            "–" if s.time_ratio_p50 is None else f"{s.time_ratio_p50:.3f}",
            "–" if s.min_clearance_cm is None else f"{s.min_clearance_cm:.2f}",
            str(s.frames_processed),
            "–" if s.latency_ms_p50 is None else f"{s.latency_ms_p50:.1f}",
        )
    console().print(t)


def _tune(cfg: Any, counts: tuple[int, int], population: int, generations: int, ga_seed: int,
          out: Path | None, plot: Path | None, json: bool) -> None:  # fmt: skip
    """``ovis navigate --tune`` (the command's docstring): ``counts`` training scenarios
    of the configured robots, and of two robots with crossing goals."""
    from ovis.common.config import GAConfig
    from ovis.common.navigation.fuzzy import FuzzyArrays, designer, save_fuzzy
    from ovis.common.navigation.plots import plot_tuning
    from ovis.common.navigation.scenarios import TRAINING_SEED0, driving_config, make_scenario
    from ovis.common.navigation.tuning import N_VARIABLES, mixed_costs, tune_fuzzy
    from ovis.services.cli.ui import console, emit_json, progress

    out = out or Path("fuzzy_tuned.json")
    plot = plot or out.with_suffix(".png")
    n, crossing = counts
    pair = msgspec.structs.replace(cfg.navigation, robots=2)
    configs = (cfg, driving_config(msgspec.structs.replace(cfg, navigation=pair), 2))
    sets: list[list[Any]] = [[], []]
    with progress("training scenarios", show=not json) as update:
        for s, (count, c) in enumerate(zip(counts, configs, strict=True)):
            for k in range(count):
                sets[s].append(make_scenario(c, TRAINING_SEED0 + k, [c.camera]))
                update(len(sets[0]) + len(sets[1]), n + crossing, f"seed {TRAINING_SEED0 + k}")
    nav = cfg.navigation
    designer_cost = float(mixed_costs(FuzzyArrays.of(designer()), sets, nav)[0])
    bits = 6
    ga = GAConfig(population=population, generations=generations, bits=bits,
                  pm=1.5 / (N_VARIABLES * bits), pc=0.9, tournament=3, elitism=2,
                  seed=ga_seed, coding="gray")  # fmt: skip
    with progress("GA", show=not json) as update:
        result = tune_fuzzy(
            sets,
            nav,
            ga,
            designer_cost,
            on_generation=lambda g: update(g.generation, generations, f"cost {g.best_so_far:.4f}"),
        )
    save_fuzzy(out, result.params)
    plot_tuning(result.ga.history, designer_cost, plot)
    info = {
        "planner_file": str(out),
        "plot": str(plot),
        "training_scenarios": n,
        "training_seeds": [TRAINING_SEED0, TRAINING_SEED0 + n - 1],
        "crossing_scenarios": crossing,
        "cost": round(result.ga.best_fitness, 4),
        "designer_cost": round(designer_cost, 4),
        "evaluations": result.ga.evaluations,
    }
    if json:
        emit_json(info)
        return
    console().print(
        f"tuned fuzzy planner written to {out} (convergence: {plot}); cost on the "
        f"{n + crossing} training scenarios {result.ga.best_fitness:.4f}, the designer's "
        f"{designer_cost:.4f} (time ratio at the goal; contacts and timeouts penalised)\n"
        f"next: ovis navigate --planner-file {out}"
    )


def register(app: typer.Typer) -> None:
    app.command()(navigate)
