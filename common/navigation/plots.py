"""Pictures of navigation: the tuning's convergence, and the paths of driven scenarios."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ovis.common.calibration.ga import GenerationStats
from ovis.common.navigation.episode import EpisodeResult
from ovis.common.navigation.scenarios import Scenario

__all__ = ["plot_paths", "plot_tuning"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_tuning(history: Sequence[GenerationStats], designer_cost: float, path: Path | str) -> None:
    """The GA's best-so-far, best and mean cost per generation, with the designer's
    controller's cost on the same scenarios."""
    plt = _pyplot()
    gen = np.array([h.generation for h in history])
    fig, ax = plt.subplots(figsize=(7, 4.2), layout="constrained")
    mean = np.array([h.mean if np.isfinite(h.mean) else np.nan for h in history])
    ax.plot(gen, mean, color="0.6", label="mean of the population")
    ax.plot(gen, [h.best for h in history], color="tab:blue", alpha=0.6, label="best of generation")
    ax.plot(gen, [h.best_so_far for h in history], color="tab:red", lw=2, label="best so far")
    ax.axhline(designer_cost, ls="--", color="k", lw=1, label="designer's controller (untuned)")
    ax.axhline(1.0, ls=":", color="tab:green", lw=1, label="straight line at top speed")
    ax.set_xlabel("generation")
    ax.set_ylabel("cost (time ratio; contacts, timeouts penalised)")
    ax.set_title(f"fuzzy planner tuned by the GA: cost {history[-1].best_so_far:.3f}")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_paths(
    pairs: Sequence[tuple[Scenario, EpisodeResult]], path: Path | str, columns: int = 3
) -> None:
    """One panel per scenario: each robot's path from start (circle) to goal (star),
    where contacts ended it (cross), and the obstacles' tracks during the run."""
    plt = _pyplot()
    n = len(pairs)
    if n == 0:
        raise ValueError("no scenario to draw")
    cols = min(columns, n)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.6 * rows), squeeze=False)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    for ax, (scenario, result) in zip(axes.ravel(), pairs, strict=False):
        (x0, x1), (y0, y1) = scenario.scene.arena_x_cm, scenario.scene.arena_y_cm
        ax.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, color="0.7"))
        for track in result.obstacle_paths.values():
            if track:
                xy = np.array(track)
                ax.plot(xy[:, 0], xy[:, 1], color="tab:orange", lw=1, alpha=0.7)
                ax.plot(*xy[-1], "o", color="tab:orange", ms=4)
        for run, task in zip(result.robots, scenario.tasks, strict=True):
            xy = np.array([(x, y) for _, x, y in run.path]) if run.path else np.zeros((0, 2))
            ax.plot(*task.start_cm, "o", color="tab:green", ms=6)
            ax.plot(*task.goal_cm, "*", color="tab:green", ms=10)
            if len(xy):
                ax.plot(xy[:, 0], xy[:, 1], color="tab:blue", lw=1.5)
                if run.collisions:
                    ax.plot(*xy[-1], "x", color="tab:red", ms=10, mew=2)
        verdict = "reached" if result.success else ("contact" if result.collided else "timeout")
        ratio = [f"{r.time_ratio:.2f}" for r in result.robots if r.goal_reached]
        ax.set_title(
            f"seed {scenario.seed} ({result.feed}): {verdict}"
            + (f", time ratio {', '.join(ratio)}" if ratio else ""),
            fontsize=9,
        )
        ax.set_aspect("equal")
        ax.set_xlim(x0 - 5, x1 + 5)
        ax.set_ylim(y0 - 5, y1 + 5)
        ax.tick_params(labelsize=7)
    fig.suptitle(
        f"case {pairs[0][0].case}, planner {pairs[0][1].planner}: robot paths (blue), "
        "obstacles' tracks (orange)",
        fontsize=10,
    )
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
