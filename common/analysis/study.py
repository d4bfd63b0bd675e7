"""The paper's parametric study of the GA settings (§5.1, Figure 7), with spread.

Figure 7 of the paper plots the best fitness (DIPE) against the crossover probability
p_c, the mutation probability p_m, the population size and the number of generations,
each varied alone around the setting the paper then chose (p_c 0.9, p_m 0.005,
population 100, 90 generations). It shows one value per setting. A GA is random, so
here every setting is run with several seeds and the result is a distribution: the
median and the 10–90 % band are plotted (log scale), with every run as a dot.

Runs share one :class:`~ovis.common.calibration.problem.CalibrationProblem` per frame (the blob
tables of each threshold are computed once). The generations factor costs nothing extra:
a run's best-so-far after g generations *is* the result of the same seed run for g
generations (the random stream does not depend on the total), so one long run per seed
at the paper's setting gives the whole curve, and its value at 90 generations is the
paper's point of the other three factors.
"""

from __future__ import annotations

import csv
import io
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

import msgspec
import numpy as np

from ovis.common.atomic import write_atomic
from ovis.common.calibration.ga import run_ga
from ovis.common.calibration.problem import INFEASIBLE, CalibrationProblem
from ovis.common.calibration.refine import dipe_of
from ovis.common.config import OvisConfig
from ovis.common.sim.arena import Arena, control_points

__all__ = [
    "DEFAULT_GRID",
    "FACTORS",
    "PAPER_DIPE_MM",
    "PAPER_SETTING",
    "QUICK_GRID",
    "StudyRun",
    "StudySummary",
    "plot_study",
    "run_study",
    "summarise",
    "write_study",
]

#: The paper's best DIPE (§5.1), mm on the image plane.
PAPER_DIPE_MM = 0.735214
#: The GA factors of Figure 7, in its panel order.
FACTORS = ("pc", "pm", "population", "generations")
#: The setting the paper chose after its study.
PAPER_SETTING: dict[str, float] = {"pc": 0.9, "pm": 0.005, "population": 100, "generations": 90}
#: Values of each factor (the others at the paper's setting).
DEFAULT_GRID: dict[str, tuple[float, ...]] = {
    "pc": (0.5, 0.6, 0.7, 0.8, 0.9, 1.0),
    "pm": (0.001, 0.002, 0.005, 0.01, 0.02, 0.05),
    "population": (20, 40, 60, 100, 150, 200),
    "generations": (10, 20, 30, 45, 60, 90, 120, 150),
}
#: A smaller grid for a quick look (about a quarter of the work).
QUICK_GRID: dict[str, tuple[float, ...]] = {
    "pc": (0.6, 0.9, 1.0),
    "pm": (0.001, 0.005, 0.02),
    "population": (30, 100, 150),
    "generations": (15, 30, 60, 90, 120),
}

_LABELS = {
    "pc": "crossover probability p_c",
    "pm": "mutation probability p_m",
    "population": "population size",
    "generations": "number of generations",
}


class StudyRun(msgspec.Struct, kw_only=True):
    """One GA run of the study (a point of Figure 7)."""

    factor: str
    value: float
    arena_seed: int
    ga_seed: int
    pc: float
    pm: float
    population: int
    generations: int
    dipe_px: float  # best fitness: mean DIPE over the control points (inf: infeasible)
    dipe_mm: float
    evaluations: int
    elapsed_s: float


class StudySummary(msgspec.Struct, kw_only=True):
    """All runs of one setting: the median and the 10–90 % band of the best DIPE."""

    factor: str
    value: float
    runs: int
    median_px: float
    p10_px: float
    p90_px: float
    median_mm: float
    success_rate: float  # share of runs below the paper's DIPE (0.735214 mm)
    mean_evaluations: float
    mean_elapsed_s: float
    paper_setting: bool


def _validate_grid(grid: dict[str, Sequence[float]]) -> dict[str, tuple[float, ...]]:
    out: dict[str, tuple[float, ...]] = {}
    for name, values in grid.items():
        if name not in FACTORS:
            raise ValueError(f"unknown GA factor {name!r}; choose from {', '.join(FACTORS)}")
        vals = tuple(float(v) for v in values)
        if not vals:
            raise ValueError(f"the grid of {name} is empty")
        if name in ("pc", "pm") and not all(0.0 <= v <= 1.0 for v in vals):
            raise ValueError(f"{name} values must lie in [0, 1], got {vals}")
        if name in ("population", "generations") and not all(
            v >= (2 if name == "population" else 1) and v == int(v) for v in vals
        ):
            raise ValueError(f"{name} values must be whole numbers >= 2, got {vals}")
        out[name] = vals
    return out


def _setting_key(pc: float, pm: float, population: int) -> tuple[float, float, int]:
    return (round(pc, 12), round(pm, 12), int(population))


def _point(
    factor: str,
    value: float,
    key: tuple[float, float, int],
    gens: int,
    result: tuple[list[float], float, int, float],
    ids: tuple[int, int],
    d_mm: float,
) -> StudyRun:
    """The point of one factor value, read from a run's best-so-far history."""
    so_far, mm_end, evals, elapsed = result
    px = so_far[min(gens, len(so_far) - 1)]
    finished = gens == len(so_far) - 1
    px_out = px if px < INFEASIBLE else float("inf")
    # Exact mm of the run's final best; for a shorter prefix of the run, px·d (exact
    # when d_x = d_y, as on both presets). Evaluations and time of a prefix: pro rata.
    mm = mm_end if finished else px_out * d_mm
    share = gens / max(len(so_far) - 1, 1)
    return StudyRun(
        factor=factor,
        value=float(value),
        arena_seed=ids[0],
        ga_seed=ids[1],
        pc=key[0],
        pm=key[1],
        population=key[2],
        generations=gens,
        dipe_px=float(px_out),
        dipe_mm=float(mm),
        evaluations=round(evals * share),
        elapsed_s=float(elapsed * share),
    )


def run_study(
    config: OvisConfig,
    *,
    grid: dict[str, Sequence[float]] | None = None,
    seeds: int = 5,
    arena_seeds: Sequence[int] = (0,),
    paper_setting: dict[str, float] | None = None,
    on_run: Callable[[int, int, str], None] | None = None,
) -> list[StudyRun]:
    """Run the parametric study on the first frame of simulated arenas.

    Every factor of ``grid`` (default :data:`DEFAULT_GRID`) is varied alone, the others
    at ``paper_setting`` (default :data:`PAPER_SETTING`), with GA seeds
    ``0 … seeds − 1`` on each arena of ``arena_seeds``; the other GA settings (bits,
    tournament, elitism, coding) come from ``config.ga``. ``on_run(done, total, label)``
    is called after every GA run. Returns one :class:`StudyRun` per point.
    """
    grid = _validate_grid(DEFAULT_GRID if grid is None else grid)
    base = dict(PAPER_SETTING if paper_setting is None else paper_setting)
    if int(seeds) < 1:
        raise ValueError(f"seeds must be at least 1, got {seeds}")
    gens_grid = grid.get("generations", ())
    long_gens = int(max([base["generations"], *gens_grid]))
    # Distinct (pc, pm, population) settings to run; each runs for the generations it
    # needs (the longest for the paper's setting, which gives the generations curve).
    settings: dict[tuple[float, float, int], int] = {}
    key0 = _setting_key(base["pc"], base["pm"], int(base["population"]))
    settings[key0] = long_gens
    for name in ("pc", "pm", "population"):
        for v in grid.get(name, ()):
            s = dict(base)
            s[name] = v
            key = _setting_key(s["pc"], s["pm"], int(s["population"]))
            settings.setdefault(key, int(base["generations"]))
    total = len(settings) * int(seeds) * len(arena_seeds)
    d_mm = float(config.camera.d_x_mm)
    done = 0
    runs: list[StudyRun] = []
    for arena_seed in arena_seeds:
        arena = Arena(config, int(arena_seed))
        frame, truth = arena.render()
        problem = CalibrationProblem(frame, control_points(truth), config)
        for seed in range(int(seeds)):
            results: dict[tuple[float, float, int], tuple[list[float], float, int, float]] = {}
            for (pc, pm, pop), gens in settings.items():
                ga = msgspec.structs.replace(
                    config.ga, pc=pc, pm=pm, population=pop, generations=gens, seed=seed
                )
                t0 = time.perf_counter()
                res = run_ga(problem.fitness, problem.bounds, ga, feasible_below=INFEASIBLE)
                elapsed = time.perf_counter() - t0
                mm = (
                    dipe_of(problem, res.best_values)[1]
                    if res.best_fitness < INFEASIBLE
                    else np.inf
                )
                so_far = [h.best_so_far for h in res.history]
                results[(pc, pm, pop)] = (so_far, mm, res.evaluations, elapsed)
                done += 1
                if on_run is not None:
                    label = f"arena {arena_seed} seed {seed} pc {pc:g} pm {pm:g} P {pop}"
                    on_run(done, total, label)

            paper_gens = int(base["generations"])
            ids = (int(arena_seed), seed)
            for name in ("pc", "pm", "population"):
                for v in grid.get(name, ()):
                    s = dict(base)
                    s[name] = v
                    key = _setting_key(s["pc"], s["pm"], int(s["population"]))
                    runs.append(_point(name, v, key, paper_gens, results[key], ids, d_mm))
            for g in gens_grid:
                runs.append(_point("generations", g, key0, int(g), results[key0], ids, d_mm))
    return runs


def _is_paper(factor: str, value: float, paper: dict[str, float]) -> bool:
    return bool(np.isclose(value, paper[factor], rtol=1e-9, atol=1e-12))


def _pct(x: np.ndarray, q: float) -> float:
    """Percentile (linear) that is ∞ when it depends on an infeasible (∞) run."""
    big = 1e300
    v = float(np.percentile(np.where(np.isfinite(x), x, big), q))
    return float("inf") if v > 1e200 else v


def summarise(
    runs: Iterable[StudyRun], *, paper_setting: dict[str, float] | None = None
) -> list[StudySummary]:
    """Median, 10–90 % band and success rate of every (factor, value), in grid order."""
    paper = dict(PAPER_SETTING if paper_setting is None else paper_setting)
    groups: dict[tuple[str, float], list[StudyRun]] = {}
    for r in runs:
        groups.setdefault((r.factor, r.value), []).append(r)
    out = []
    for (factor, value), rs in sorted(
        groups.items(), key=lambda kv: (FACTORS.index(kv[0][0]), kv[0][1])
    ):
        px = np.array([r.dipe_px for r in rs])
        mm = np.array([r.dipe_mm for r in rs])
        out.append(
            StudySummary(
                factor=factor,
                value=value,
                runs=len(rs),
                median_px=_pct(px, 50),
                p10_px=_pct(px, 10),
                p90_px=_pct(px, 90),
                median_mm=_pct(mm, 50),
                success_rate=float(np.mean(mm < PAPER_DIPE_MM)),
                mean_evaluations=float(np.mean([r.evaluations for r in rs])),
                mean_elapsed_s=float(np.mean([r.elapsed_s for r in rs])),
                paper_setting=_is_paper(factor, value, paper),
            )
        )
    return out


def _fmt_value(factor: str, value: float) -> str:
    return f"{int(value)}" if factor in ("population", "generations") else f"{value:g}"


def study_markdown(summary: Sequence[StudySummary], *, seeds_note: str = "") -> str:
    """The summary as a Markdown table (the paper's setting in bold)."""
    lines = [
        "# GA parametric study (paper §5.1, Figure 7)",
        "",
        "Best DIPE (mean over the control points) of each GA run; each factor varied alone, "
        "the others at the paper's setting (p_c 0.9, p_m 0.005, population 100, 90 "
        "generations, **bold**). Success: DIPE below the paper's 0.735214 mm."
        + (f" {seeds_note}" if seeds_note else ""),
        "",
        "| factor | value | runs | median px | 10 % px | 90 % px | median mm | success "
        "| evaluations | time s |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for s in summary:
        v = _fmt_value(s.factor, s.value)
        if s.paper_setting:
            v = f"**{v}**"
        lines.append(
            f"| {s.factor} | {v} | {s.runs} | {s.median_px:.3f} | {s.p10_px:.3f} | "
            f"{s.p90_px:.3f} | {s.median_mm:.4f} | {100 * s.success_rate:.0f} % | "
            f"{s.mean_evaluations:.0f} | {s.mean_elapsed_s:.2f} |"
        )
    return "\n".join(lines) + "\n"


def study_csv(runs: Sequence[StudyRun]) -> str:
    """Every run as CSV (one row per point)."""
    buf = io.StringIO()
    fields = list(StudyRun.__struct_fields__)
    w = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    w.writeheader()
    for r in runs:
        w.writerow(msgspec.to_builtins(r))
    return buf.getvalue()


def _plain_log_ticks(ax) -> None:
    """Log-scale y ticks as plain numbers (0.2, 0.5, 1, 2) rather than 2×10⁻¹."""
    from matplotlib.ticker import FuncFormatter, LogLocator

    fmt = FuncFormatter(lambda v, _: f"{v:g}")
    ax.yaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    ax.yaxis.set_major_formatter(fmt)
    ax.yaxis.set_minor_formatter(FuncFormatter(lambda v, _: ""))


def plot_study(
    runs: Sequence[StudyRun],
    path: Path | str,
    *,
    d_mm: float,
    paper_setting: dict[str, float] | None = None,
    title: str = "",
) -> None:
    """Figure 7 with spread: one panel per factor, median and 10–90 % band, log y."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paper = dict(PAPER_SETTING if paper_setting is None else paper_setting)
    summary = summarise(runs, paper_setting=paper)
    fig, axes = plt.subplots(2, 2, figsize=(10, 7.5), layout="constrained")
    paper_px = PAPER_DIPE_MM / d_mm
    for ax, factor, letter in zip(axes.ravel(), FACTORS, "abcd", strict=True):
        rows = [s for s in summary if s.factor == factor]
        if not rows:
            ax.set_visible(False)
            continue
        x = np.array([s.value for s in rows])
        med = np.array([s.median_px for s in rows])
        lo = np.array([s.p10_px for s in rows])
        hi = np.array([s.p90_px for s in rows])
        pts = [r for r in runs if r.factor == factor]
        px = np.array([r.dipe_px for r in pts])
        xs = np.array([r.value for r in pts])
        finite = px[np.isfinite(px)]
        cap = 2.0 * float(finite.max()) if finite.size else 10.0  # where ∞ is drawn
        ax.scatter(xs[np.isfinite(px)], finite, s=9, color="0.55", alpha=0.6,
                   label="one run", zorder=2)  # fmt: skip
        if not np.isfinite(px).all():
            ax.scatter(xs[~np.isfinite(px)], np.full((~np.isfinite(px)).sum(), cap),
                       marker="x", color="tab:red", s=25, zorder=3,
                       label="infeasible run (drawn at the top)")  # fmt: skip
        med, lo, hi = (np.minimum(a, cap) for a in (med, lo, hi))
        ax.fill_between(x, lo, hi, color="tab:blue", alpha=0.22, label="10–90 % of runs")
        ax.plot(x, med, "o-", color="tab:blue", lw=2, ms=4, label="median", zorder=3)
        ax.axhline(paper_px, ls="--", color="k", lw=1, label="paper's DIPE (0.735 mm)")
        pv = paper[factor]
        ax.axvline(pv, color="tab:red", lw=1, ls=":")
        at = [s for s in rows if s.paper_setting]
        if at:
            ax.plot(
                [pv],
                [at[0].median_px],
                marker="*",
                ms=15,
                color="tab:red",
                ls="none",
                label="paper's setting",
                zorder=4,
            )
        if factor == "pm":
            ax.set_xscale("log")
        ax.set_yscale("log")
        _plain_log_ticks(ax)
        ax.set_xlabel(_LABELS[factor])
        ax.set_ylabel("best DIPE, px")
        sec = ax.secondary_yaxis("right", functions=(lambda p: p * d_mm, lambda m: m / d_mm))
        sec.set_ylabel("mm")
        _plain_log_ticks(sec)
        ax.set_title(f"({letter}) DIPE vs {_LABELS[factor]}", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        if letter == "a":
            ax.legend(fontsize=7, loc="upper right")
    n = len({(r.arena_seed, r.ga_seed) for r in runs})
    fig.suptitle(
        title
        or f"GA parametric study (paper Figure 7) with spread: {n} runs per setting, "
        "others at the paper's setting"
    )
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_study(
    out_dir: Path | str,
    runs: Sequence[StudyRun],
    *,
    d_mm: float,
    paper_setting: dict[str, float] | None = None,
    note: str = "",
) -> dict[str, Path]:
    """Write ``study.csv`` (every run), ``study.md`` (summary) and ``study.png``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary = summarise(runs, paper_setting=paper_setting)
    paths = {"csv": out / "study.csv", "markdown": out / "study.md", "plot": out / "study.png"}
    write_atomic(paths["csv"], study_csv(runs).encode("utf-8"))
    write_atomic(paths["markdown"], study_markdown(summary, seeds_note=note).encode("utf-8"))
    plot_study(runs, paths["plot"], d_mm=d_mm, paper_setting=paper_setting)
    return paths
