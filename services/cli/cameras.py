"""``ovis cameras``: several cameras over one arena (issue 19, docs/cameras.md)."""

from __future__ import annotations

import re
import sys
from typing import Annotated

import msgspec
import typer

from ovis.services.cli.errors import UserError
from ovis.services.cli.options import SummaryJsonOpt

__all__ = ["register"]


def parse_grid(text: str) -> tuple[int, int]:
    """``"2x2"`` → (2, 2); one to eight cameras each way."""
    m = re.fullmatch(r"\s*([1-8])\s*[xX×]\s*([1-8])\s*", text)
    if m is None:
        raise UserError(f"--grid {text!r}: give columns x rows, e.g. 2x2 (1 to 8 each)")
    return int(m.group(1)), int(m.group(2))


def simulate(
    grid: Annotated[str, typer.Option(help="Cameras as columns x rows, e.g. 2x2.")] = "2x2",
    frames: Annotated[int, typer.Option(min=1, max=100000, help="Frames per camera.")] = 600,
    seed: Annotated[int, typer.Option(min=0, help="Scene and camera seed.")] = 101,
    robots: Annotated[int, typer.Option(min=0, max=50, help="Marked robots.")] = 4,
    obstacles: Annotated[int, typer.Option(min=0, max=200, help="Still obstacles.")] = 10,
    kill: Annotated[
        str | None, typer.Option(help="A camera (e.g. cam11) that stops half-way.")
    ] = None,
    json: SummaryJsonOpt = False,
) -> None:
    """Fuse a simulated arena seen by a grid of cameras and score the world against
    the ground truth: per camera frames captured/processed/dropped; duplicates,
    identity swaps, the largest hand-over jump and the position error of the world.

    In-process and without images: each camera's detections are the truth projected
    to its pixels with pixel noise and back-projected (docs/cameras.md); the network
    and the camera chains are not in it.
    """
    from ovis.common.analysis.multicam import simulate_grid

    nx, ny = parse_grid(grid)
    out = sys.stderr if json else sys.stdout
    step = max(1, frames // 10)

    def progress(done: int) -> None:
        if done % step == 0 or done == frames:
            print(f"fused {done}/{frames} frames", file=out, flush=True)

    try:
        run = simulate_grid(nx, ny, frames=frames, seed=seed, robots=robots,
                            obstacles=obstacles, dead=kill, progress=progress)  # fmt: skip
    except ValueError as exc:
        raise UserError(str(exc)) from None
    if json:
        sys.stdout.write(msgspec.json.encode(summary(run)).decode() + "\n")
        return
    from rich.console import Console
    from rich.table import Table

    con = Console(highlight=False)
    t = Table(title=f"cameras ({run.grid}, seed {run.seed})", title_justify="left")
    for col in ("camera", "captured", "processed", "dropped"):
        t.add_column(col, justify="right")
    for name, c in run.cameras.items():
        t.add_row(name, str(c.captured), str(c.processed), str(c.dropped))
    con.print(t)
    w = summary(run)["world"]
    con.print(
        f"world: {w['frames']} frames, {w['duplicates']} duplicates, "
        f"{w['identity_swaps']} identity swaps, {w['missed']} missed, {w['phantoms']} "
        f"phantoms; hand-over jump max {w['handover_jump_cm']:.3f} cm over "
        f"{w['handovers']} hand-overs; error mean {w['world_error_cm']['mean']:.3f} cm, "
        f"max {w['world_error_cm']['max']:.3f} cm; merging p50 "
        f"{w['fuse_ms']['p50']:.2f} ms, p99 {w['fuse_ms']['p99']:.2f} ms per world frame"
    )


def summary(run) -> dict:
    """The summary's fields, named as the issue names them."""
    s = run.world
    return {
        "grid": run.grid,
        "seed": run.seed,
        "cameras": msgspec.to_builtins(run.cameras),
        "world": {
            "frames": s.frames,
            "duplicates": s.duplicates,
            "identity_swaps": s.identity_swaps,
            "missed": s.missed,
            "phantoms": s.phantoms,
            "handovers": s.handovers,
            "handover_jump_cm": s.handover_jump_cm,
            "world_error_cm": {"mean": s.world_error_cm_mean, "max": s.world_error_cm_max},
            "fuse_ms": {"p50": run.fuse_ms_p50, "p99": run.fuse_ms_p99},
        },
    }


def register(app: typer.Typer) -> None:
    group = typer.Typer(
        help="Several cameras over one arena, fused into one world (docs/cameras.md).",
        no_args_is_help=True,
    )
    group.command("simulate")(simulate)
    app.add_typer(group, name="cameras")
