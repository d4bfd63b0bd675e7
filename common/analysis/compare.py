"""GA alone, GA + least-squares polish, and Levenberg–Marquardt from random starts.

The paper prefers a GA to the Levenberg–Marquardt refinement of Zhang (2000) because
a local method "may get trapped into local minima" and needs a good initial guess
(§1, §5.3). This module measures that claim on many simulated arenas (beyond the paper).
On each arena (the first frame of :class:`~ovis.common.sim.arena.Arena` with a given
seed, its objects as the control points) it runs:

``ga``
    the paper's GA (the configured settings, GA seed = arena seed), with the threshold
    and size filter centred as ``ovis calibrate`` does;
``ga+polish``
    the same, then the bounded least-squares polish of :mod:`ovis.common.calibration.refine`;
``lm``
    MINPACK Levenberg–Marquardt (``scipy.optimize.least_squares(method="lm")``,
    unbounded) on the GA's objective — the pixel residuals of eq. 14 with the optimal
    blob ↔ point matching re-solved at every evaluation — started from a point drawn
    uniformly in the ranges of the seven continuous camera variables;
``lm-known``
    the same, but told the correct blob of every control point (the matching of the
    true camera's projections): local minima of the camera model alone;
``ls-bounded``
    as ``lm`` (matching re-solved, same random starts) but bounded to the ranges
    (trust-region reflective, as the polish): a local method that knows the ranges.

LM cannot choose a threshold or a size filter (they are discrete): it gets the blobs
the GA's centred threshold and size filter see, which favours it.

A run succeeds when its DIPE is below the paper's 0.735214 mm **and** its world error
over the arena is below 1 cm: every point of a 2-cm grid of the arena floor, at the
obstacles' top-face height, imaged by the true camera and back-projected by the
calibrated one, lands within 1 cm of where it is (``world_max_cm``). DIPE is measured
on the same blobs for every method.
"""

from __future__ import annotations

import csv
import io
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

import msgspec
import numpy as np

from ovis.common.analysis.study import PAPER_DIPE_MM
from ovis.common.atomic import write_atomic
from ovis.common.calibration.accuracy import arena_world_error
from ovis.common.calibration.dipe import match_points, pixel_error_mm
from ovis.common.calibration.ga import run_ga
from ovis.common.calibration.problem import INFEASIBLE, CalibrationProblem, camera_with
from ovis.common.calibration.refine import CONTINUOUS_SLICE, fit_camera, matched_blobs, polish
from ovis.common.calibration.solve import centre_image_settings
from ovis.common.camera.paper_model import project
from ovis.common.config import OvisConfig
from ovis.common.sim.arena import Arena, control_points

__all__ = [
    "METHODS",
    "WORLD_LIMIT_CM",
    "CompareRun",
    "CompareSummary",
    "compare_methods",
    "plot_compare",
    "summarise_compare",
    "write_compare",
]

METHODS = ("ga", "ga+polish", "lm", "lm-known", "ls-bounded")
#: Largest floor error over the arena for a run to count as a success (cm).
WORLD_LIMIT_CM = 1.0

_LABELS = {
    "ga": "GA (paper)",
    "ga+polish": "GA + polish",
    "lm": "LM,\nrandom start",
    "lm-known": "LM, random start,\nmatching given",
    "ls-bounded": "bounded LS,\nrandom start",
}


class CompareRun(msgspec.Struct, kw_only=True):
    """One calibration of one arena by one method."""

    method: str
    arena_seed: int
    start: int  # index of the random start (LM), 0 otherwise
    dipe_px: float
    dipe_mm: float
    world_mean_cm: float
    world_max_cm: float
    success: bool
    elapsed_s: float
    Z0_cm: float
    lam_mm: float
    s_x: float
    s_y: float


class CompareSummary(msgspec.Struct, kw_only=True):
    """One method over every arena (and start)."""

    method: str
    runs: int
    success_rate: float
    median_dipe_px: float
    p10_dipe_px: float
    p90_dipe_px: float
    median_dipe_mm: float
    median_world_mean_cm: float
    median_world_max_cm: float
    p90_world_max_cm: float
    median_elapsed_s: float


def _dipe(
    problem: CalibrationProblem,
    values: np.ndarray,
    blob_row: np.ndarray,
    blob_col: np.ndarray,
) -> tuple[float, float]:
    """Mean DIPE (px, mm) of ``values`` on fixed blobs with the optimal matching."""
    cam = camera_with(problem.config.camera, values)
    pred = project(*problem.points_xyz.T, cam)
    if not pred.valid.all():
        return float("inf"), float("inf")
    m = match_points(pred.row[None], pred.col[None], blob_row[None], blob_col[None])
    idx = m.blob_index[0]
    d_row, d_col = blob_row[idx] - pred.row, blob_col[idx] - pred.col
    mm = pixel_error_mm(d_row, d_col, cam.d_x_mm, cam.d_y_mm)
    return float(m.dipe_px[0].mean()), float(np.mean(mm))


def compare_methods(
    config: OvisConfig,
    *,
    arena_seeds: Sequence[int] = tuple(range(20)),
    lm_starts: int = 5,
    methods: Sequence[str] = METHODS,
    on_run: Callable[[int, int, str], None] | None = None,
) -> list[CompareRun]:
    """Calibrate the first frame of each arena by each method; see the module docstring.

    ``lm_starts`` random starts per arena for each LM variant (drawn with the arena seed).
    ``on_run(done, total, label)`` is called after each arena and method.
    """
    for m in methods:
        if m not in METHODS:
            raise ValueError(f"unknown method {m!r}; choose from {', '.join(METHODS)}")
    sim = config.simulator
    z_cm = config.pose.obstacle_height_cm
    true_cam = config.camera
    runs: list[CompareRun] = []
    total = len(arena_seeds) * len(methods)
    done = 0

    def add(method: str, seed: int, start: int, values, blobs, elapsed: float) -> None:
        px, mm = _dipe(problem, values, *blobs)
        cam = camera_with(config.camera, values)
        err = arena_world_error(cam, true_cam, sim.arena_x_cm, sim.arena_y_cm, z_cm=z_cm)
        w_mean = float(np.mean(err)) if np.all(np.isfinite(err)) else float("inf")
        w_max = float(np.max(err))
        runs.append(
            CompareRun(
                method=method,
                arena_seed=int(seed),
                start=start,
                dipe_px=px,
                dipe_mm=mm,
                world_mean_cm=w_mean,
                world_max_cm=w_max,
                success=bool(mm < PAPER_DIPE_MM and w_max < WORLD_LIMIT_CM),
                elapsed_s=float(elapsed),
                Z0_cm=float(values[2]),
                lam_mm=float(values[3]),
                s_x=float(values[7]),
                s_y=float(values[8]),
            )
        )

    def tick(label: str) -> None:
        nonlocal done
        done += 1
        if on_run is not None:
            on_run(done, total, label)

    for seed in arena_seeds:
        frame, truth = Arena(config, int(seed)).render()
        problem = CalibrationProblem(frame, control_points(truth), config)
        t0 = time.perf_counter()
        ga_cfg = msgspec.structs.replace(config.ga, seed=int(seed))
        result = run_ga(problem.fitness, problem.bounds, ga_cfg, feasible_below=INFEASIBLE)
        t_ga = time.perf_counter() - t0
        if result.best_fitness >= INFEASIBLE:  # no blobs to work with: every method fails
            for m in methods:
                runs.append(
                    CompareRun(
                        method=m, arena_seed=int(seed), start=0, dipe_px=float("inf"),
                        dipe_mm=float("inf"), world_mean_cm=float("inf"),
                        world_max_cm=float("inf"), success=False, elapsed_s=t_ga,
                        Z0_cm=float("nan"), lam_mm=float("nan"), s_x=float("nan"),
                        s_y=float("nan"),
                    )
                )  # fmt: skip
                tick(f"arena {seed} {m}")
            continue
        best = result.best_values
        if config.calibration.centre_image_settings:
            best, _ = centre_image_settings(problem, best)
        t_ga = time.perf_counter() - t0
        blobs = matched_blobs(problem, best)
        if "ga" in methods:
            add("ga", seed, 0, best, blobs, t_ga)
            tick(f"arena {seed} ga")
        if "ga+polish" in methods:
            t1 = time.perf_counter()
            pol = polish(problem, best)
            add("ga+polish", seed, 0, pol.values, blobs, t_ga + time.perf_counter() - t1)
            tick(f"arena {seed} ga+polish")
        # Random starts (the same for both LM variants), and the true matching.
        rng = np.random.default_rng([int(seed), 7])
        lo, hi = problem.bounds[CONTINUOUS_SLICE].T
        starts = lo + rng.random((int(lm_starts), lo.size)) * (hi - lo)
        true_pred = project(*problem.points_xyz.T, true_cam)
        tm = match_points(
            true_pred.row[None], true_pred.col[None], blobs[0][None], blobs[1][None]
        ).blob_index[0]
        known = (blobs[0][tm], blobs[1][tm])
        local = (
            ("lm", "lm", True, blobs),
            ("lm-known", "lm", False, known),
            ("ls-bounded", "trf", True, blobs),
        )
        for method, solver, rematch, b in local:
            if method not in methods:
                continue
            for k, u in enumerate(starts):
                v0 = best.copy()
                v0[CONTINUOUS_SLICE] = u
                t1 = time.perf_counter()
                fit = fit_camera(problem, v0, *b, method=solver, rematch=rematch, max_nfev=400)
                add(method, seed, k, fit.values, blobs, time.perf_counter() - t1)
            tick(f"arena {seed} {method}")
    return runs


def _pct(x: np.ndarray, q: float) -> float:
    """Percentile without interpolating between infinite values (failures are ∞)."""
    return float(np.percentile(x, q, method="nearest"))


def summarise_compare(runs: Iterable[CompareRun]) -> list[CompareSummary]:
    """Success rate, DIPE and world error per method (in :data:`METHODS` order)."""
    by: dict[str, list[CompareRun]] = {}
    for r in runs:
        by.setdefault(r.method, []).append(r)
    out = []
    for method in [m for m in METHODS if m in by]:
        rs = by[method]
        px = np.array([r.dipe_px for r in rs])
        mm = np.array([r.dipe_mm for r in rs])
        wmean = np.array([r.world_mean_cm for r in rs])
        wmax = np.array([r.world_max_cm for r in rs])
        out.append(
            CompareSummary(
                method=method,
                runs=len(rs),
                success_rate=float(np.mean([r.success for r in rs])),
                median_dipe_px=_pct(px, 50),
                p10_dipe_px=_pct(px, 10),
                p90_dipe_px=_pct(px, 90),
                median_dipe_mm=_pct(mm, 50),
                median_world_mean_cm=_pct(wmean, 50),
                median_world_max_cm=_pct(wmax, 50),
                p90_world_max_cm=_pct(wmax, 90),
                median_elapsed_s=float(np.median([r.elapsed_s for r in rs])),
            )
        )
    return out


def _f(v: float, fmt: str) -> str:
    return format(v, fmt) if np.isfinite(v) else "∞"


def compare_markdown(summary: Sequence[CompareSummary], *, note: str = "") -> str:
    """The summary as a Markdown table."""
    lines = [
        "# GA vs GA + polish vs Levenberg–Marquardt from random starts",
        "",
        f"Success: DIPE < {PAPER_DIPE_MM} mm (the paper's) and world error < "
        f"{WORLD_LIMIT_CM:g} cm everywhere on the arena (2-cm grid at the obstacles' "
        "top-face height, calibrated vs true camera)." + (f" {note}" if note else ""),
        "",
        "| method | runs | success | median DIPE px (10-90 %) | median DIPE mm | median "
        "world mean cm | median world max cm | 90 % world max cm | median time s |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for s in summary:
        lines.append(
            f"| {s.method} | {s.runs} | {100 * s.success_rate:.0f} % | "
            f"{_f(s.median_dipe_px, '.3f')} ({_f(s.p10_dipe_px, '.3f')}-"
            f"{_f(s.p90_dipe_px, '.3g')}) | {_f(s.median_dipe_mm, '.4f')} | "
            f"{_f(s.median_world_mean_cm, '.3f')} | {_f(s.median_world_max_cm, '.3f')} | "
            f"{_f(s.p90_world_max_cm, '.3g')} | {s.median_elapsed_s:.3f} |"
        )
    return "\n".join(lines) + "\n"


def compare_csv(runs: Sequence[CompareRun]) -> str:
    """Every run as CSV."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(CompareRun.__struct_fields__), lineterminator="\n")
    w.writeheader()
    for r in runs:
        w.writerow(msgspec.to_builtins(r))
    return buf.getvalue()


def plot_compare(runs: Sequence[CompareRun], path: Path | str, *, d_mm: float) -> None:
    """DIPE and world error of every run, per method (log y), with success rates."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    summary = {s.method: s for s in summarise_compare(runs)}
    methods = [m for m in METHODS if m in summary]
    cap_px, cap_cm = 1e4, 1e4  # where failures (∞) are drawn
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2), layout="constrained")
    rng = np.random.default_rng(0)
    for ax, key, limit, cap, ylabel in (
        (axes[0], "dipe_px", PAPER_DIPE_MM / d_mm, cap_px, "DIPE, px (mean over points)"),
        (axes[1], "world_max_cm", WORLD_LIMIT_CM, cap_cm, "largest floor error on the arena, cm"),
    ):
        for i, m in enumerate(methods):
            rs = [r for r in runs if r.method == m]
            y = np.array([getattr(r, key) for r in rs], dtype=float)
            y = np.where(np.isfinite(y), np.clip(y, 1e-3, cap), cap)
            ok = np.array([r.success for r in rs])
            x = i + rng.uniform(-0.18, 0.18, size=y.size)
            ax.scatter(x[ok], y[ok], s=14, color="tab:green", alpha=0.7, label=None)
            ax.scatter(x[~ok], y[~ok], s=14, color="tab:red", alpha=0.7, marker="x")
            ax.hlines(np.percentile(y, 50, method="nearest"), i - 0.3, i + 0.3, color="k", lw=2)
        ax.axhline(limit, ls="--", color="k", lw=1)
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(
            FuncFormatter(lambda v, _, cap=cap: "∞" if v >= cap else f"{v:g}")
        )
        ax.set_xticks(range(len(methods)))
        ax.set_xticklabels(
            [f"{_LABELS[m]}\n{100 * summary[m].success_rate:.0f} % success" for m in methods],
            fontsize=8,
        )
        ax.set_ylabel(ylabel)
        ax.grid(True, axis="y", which="both", alpha=0.3)
    axes[0].set_title("DIPE (dashed: the paper's 0.735 mm)", fontsize=10)
    axes[1].set_title(f"world error (dashed: {WORLD_LIMIT_CM:g} cm)", fontsize=10)
    axes[0].scatter([], [], color="tab:green", s=14, label="success")
    axes[0].scatter([], [], color="tab:red", marker="x", s=14, label="failure")
    axes[0].plot([], [], color="k", lw=2, label="median")
    axes[0].legend(fontsize=8, loc="upper left")
    n_arenas = len({r.arena_seed for r in runs})
    fig.suptitle(
        f"{n_arenas} simulated arenas: GA, GA + polish, local least squares from random "
        "starts (∞: the camera cannot image or back-project part of the arena)",
        fontsize=10,
    )
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_compare(
    out_dir: Path | str, runs: Sequence[CompareRun], *, d_mm: float, note: str = ""
) -> dict[str, Path]:
    """Write ``compare.csv`` (every run), ``compare.md`` (summary) and ``compare.png``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {
        "csv": out / "compare.csv",
        "markdown": out / "compare.md",
        "plot": out / "compare.png",
    }
    write_atomic(paths["csv"], compare_csv(runs).encode("utf-8"))
    md = compare_markdown(summarise_compare(runs), note=note)
    write_atomic(paths["markdown"], md.encode("utf-8"))
    plot_compare(runs, paths["plot"], d_mm=d_mm)
    return paths
