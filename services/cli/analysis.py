"""Analysis commands (beyond the paper): `ovis study`, `ovis compare`, and the accuracy
report and plots that `ovis calibrate` adds to every calibration."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Any

import msgspec
import typer

from ovis.services.cli.errors import UserError

__all__ = ["add_accuracy", "print_accuracy", "register", "write_calibration_plots"]


def _emit_json(summary: object, paths: dict[str, Path]) -> None:
    """The summary and the files written, as indented JSON on stdout."""
    import sys

    payload = {
        "summary": msgspec.to_builtins(summary),
        "files": {k: str(v) for k, v in paths.items()},
    }
    sys.stdout.write(msgspec.json.format(msgspec.json.encode(payload), indent=2).decode() + "\n")


def _console():
    from rich.console import Console

    return Console(highlight=False)


def _progress(con, what: str):
    """A progress bar on stderr (stdout stays clean for --json and redirection)."""
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    return Progress(
        TextColumn(f"[bold]{what}[/]"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[label]}"),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
        console=Console(stderr=True, highlight=False),
    )


def _resolve(config: Path | None, preset: str):
    from ovis.services.cli.offline import resolve_config

    cfg = resolve_config(config, preset)
    if cfg.camera.model != "paper":
        raise UserError(
            f"this analysis runs the paper's camera model; the configuration's camera is "
            f"{cfg.camera.model!r} (use --preset default or paper)"
        )
    return cfg


ConfigOpt = Annotated[
    Path | None,
    typer.Option(
        "--config", "-c", help="TOML configuration (default: the preset).", dir_okay=False
    ),
]


def study(
    out: Annotated[Path, typer.Option(help="Folder for study.csv, study.md, study.png.")] = Path(
        "ovis-study"
    ),
    seeds: Annotated[int, typer.Option(min=1, max=1000, help="GA seeds per setting.")] = 5,
    arenas: Annotated[
        int, typer.Option(min=1, max=1000, help="Simulated arenas (seeds 0..N-1), each's frame 0.")
    ] = 1,
    quick: Annotated[
        bool, typer.Option("--quick", help="A smaller grid (about a quarter of the work).")
    ] = False,
    preset: Annotated[str, typer.Option(help="'default' (640x480) or 'paper' (192x192).")] = (
        "default"
    ),
    config: ConfigOpt = None,
    json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
) -> None:
    """Reproduce the paper's parametric study of the GA (§5.1, Figure 7), with spread.

    Best DIPE against p_c, p_m, population size and number of generations, each varied
    alone around the paper's chosen setting (p_c 0.9, p_m 0.005, population 100, 90
    generations), with --seeds GA seeds per setting on the first frame of the simulated
    arena(s). Writes every run (study.csv), a summary table with the median, 10-90 %
    band and share of runs below the paper's DIPE (study.md), and the four panels of
    Figure 7 with their spread bands (study.png; log y; the paper's setting marked).
    The default (5 seeds, 1 arena) takes about a minute on two cores.
    """
    from ovis.common.analysis.study import (
        DEFAULT_GRID,
        QUICK_GRID,
        run_study,
        summarise,
        write_study,
    )

    cfg = _resolve(config, preset)
    grid = QUICK_GRID if quick else DEFAULT_GRID
    con = _console()
    t0 = time.perf_counter()
    with _progress(con, "study") as progress:
        task = progress.add_task("study", total=None, label="")

        def on_run(done: int, total: int, label: str) -> None:
            progress.update(task, completed=done, total=total, label=label)

        runs = run_study(cfg, grid=grid, seeds=seeds, arena_seeds=range(arenas), on_run=on_run)
    note = (
        f"{seeds} GA seed(s) x {arenas} arena(s) per setting, {cfg.preset} preset "
        f"({cfg.camera.cols}x{cfg.camera.rows}); {len(runs)} points in "
        f"{time.perf_counter() - t0:.0f} s."
    )
    paths = write_study(out, runs, d_mm=float(cfg.camera.d_x_mm), note=note)
    summary = summarise(runs)
    if json:
        _emit_json(summary, paths)
        return
    _print_study(con, summary)
    con.print(note)
    con.print("wrote " + ", ".join(str(p) for p in paths.values()))


def _print_study(con, summary) -> None:
    from rich.table import Table

    t = Table(title="GA parametric study (paper Figure 7): best DIPE", title_justify="left")
    for c in ("factor", "value", "runs", "median px", "10-90 % px", "median mm", "success"):
        t.add_column(c, justify="right")
    for s in summary:
        v = f"{int(s.value)}" if s.factor in ("population", "generations") else f"{s.value:g}"
        t.add_row(
            s.factor,
            f"[bold]{v}*[/]" if s.paper_setting else v,
            str(s.runs),
            f"{s.median_px:.3f}",
            f"{s.p10_px:.3f}-{s.p90_px:.3f}",
            f"{s.median_mm:.4f}",
            f"{100 * s.success_rate:.0f} %",
        )
    con.print(t)
    con.print("* the paper's setting; success: DIPE below the paper's 0.735214 mm")


def compare(
    out: Annotated[Path, typer.Option(help="Folder for compare.csv, .md, .png.")] = Path(
        "ovis-compare"
    ),
    arenas: Annotated[int, typer.Option(min=1, max=10000, help="Simulated arenas.")] = 20,
    starts: Annotated[
        int, typer.Option(min=1, max=1000, help="Random starts per arena for the local methods.")
    ] = 5,
    preset: Annotated[str, typer.Option(help="'default' (640x480) or 'paper' (192x192).")] = (
        "default"
    ),
    config: ConfigOpt = None,
    json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
) -> None:
    """GA alone, GA + least-squares polish, and Levenberg-Marquardt from random starts.

    On the first frame of --arenas simulated arenas: the paper's GA; the GA followed by
    the bounded least-squares polish; Levenberg-Marquardt (unbounded) from --starts
    random points in the ranges, on the GA's objective (matching re-solved) and with the
    correct matching given; and bounded least squares from the same random starts.
    Success: DIPE below the paper's 0.735 mm and a floor error below 1 cm everywhere on
    the arena (against the true camera). Writes compare.csv, compare.md, compare.png.
    """
    from ovis.common.analysis.compare import compare_methods, summarise_compare, write_compare

    cfg = _resolve(config, preset)
    con = _console()
    t0 = time.perf_counter()
    with _progress(con, "compare") as progress:
        task = progress.add_task("compare", total=None, label="")

        def on_run(done: int, total: int, label: str) -> None:
            progress.update(task, completed=done, total=total, label=label)

        runs = compare_methods(cfg, arena_seeds=range(arenas), lm_starts=starts, on_run=on_run)
    note = (
        f"{arenas} arena(s), {starts} random start(s) each for the local methods, "
        f"{cfg.preset} preset; {time.perf_counter() - t0:.0f} s."
    )
    paths = write_compare(out, runs, d_mm=float(cfg.camera.d_x_mm), note=note)
    summary = summarise_compare(runs)
    if json:
        _emit_json(summary, paths)
        return
    from rich.table import Table

    t = Table(title="calibration methods on simulated arenas", title_justify="left")
    for c in ("method", "runs", "success", "median DIPE px", "median world max cm", "p90"):
        t.add_column(c, justify="right")
    for s in summary:
        t.add_row(
            s.method,
            str(s.runs),
            f"{100 * s.success_rate:.0f} %",
            f"{s.median_dipe_px:.3f}",
            f"{s.median_world_max_cm:.3f}",
            f"{s.p90_world_max_cm:.3g}",
        )
    con.print(t)
    con.print(note)
    con.print("wrote " + ", ".join(str(p) for p in paths.values()))


# ---------------------------------------------------------------- ovis calibrate helpers


def add_accuracy(
    frame,
    points,
    cfg,
    calib,
    *,
    check: Path | None = None,
    restarts: int = 4,
    show: bool = True,
):
    """The calibration with its accuracy report (held-out errors, identifiability)."""
    from ovis.common.calibration.accuracy import assess, load_checks

    checks = load_checks(check) if check is not None else None
    check_image = None
    if checks is not None and checks.image is not None:
        from ovis.services.cli.offline import read_image

        check_image = read_image(checks.image)
    if not show:
        report = assess(
            frame, points, cfg, calib, n_restarts=restarts, checks=checks, check_image=check_image
        )
    else:
        with _progress(_console(), "accuracy") as progress:
            task = progress.add_task("accuracy", total=None, label="")

            def on_step(stage: str, done: int, total: int) -> None:
                progress.update(task, completed=done, total=total, label=stage)

            report = assess(
                frame,
                points,
                cfg,
                calib,
                n_restarts=restarts,
                checks=checks,
                check_image=check_image,
                on_step=on_step,
            )
    return msgspec.structs.replace(calib, accuracy=report)


def write_calibration_plots(
    frame,
    calib,
    cfg,
    *,
    residuals: Path | None = None,
    error_map: Path | None = None,
    arena: Any = None,
) -> list[str]:
    """Write the residual-vector and world-error plots asked for; one line each."""
    lines = []
    if residuals is not None:
        from ovis.common.analysis.plots import plot_residuals

        m = plot_residuals(frame, calib, residuals)
        lines.append(f"wrote {residuals} (residual vectors, magnified {m:g}x)")
    if error_map is not None:
        from ovis.common.analysis.plots import plot_error_map

        if type(cfg.camera) is not type(calib.camera):
            raise UserError(
                "--error-map needs a reference camera of the same model as the calibration"
            )
        mean, worst = plot_error_map(calib, cfg.camera, error_map, arena=arena)
        where = "arena" if arena is not None else "view"
        lines.append(
            f"wrote {error_map} (floor error against the configuration's camera: mean "
            f"{mean:.3f} cm, max {worst:.3f} cm over the {where})"
        )
    return lines


_SHORT = {"Z0_cm": "Z0 cm", "lam_mm": "λ mm"}


def _num(v: float) -> str:
    """Two significant digits, never in e-notation (0.00007, 1300)."""
    import numpy as np

    if not np.isfinite(v):
        return str(v)
    return np.format_float_positional(v, precision=2, fractional=False, trim="-")


def print_accuracy(calib, con=None) -> None:
    """Print a calibration's accuracy report (if it has one)."""
    from ovis.common.calibration.file import dipe_text

    rep = calib.accuracy
    if rep is None:
        return
    from rich.table import Table

    con = con or _console()
    if calib.ga_dipe_px is not None and calib.polish_dipe_px is not None:
        if calib.polished:
            which = "the polished camera is kept"
        elif calib.polish_dipe_px < calib.ga_dipe_px:
            which = "the GA's camera is kept: \\[ga] polish = false"
        else:
            which = "the polish does not lower the DIPE here: the GA's camera is kept"
        con.print(
            f"GA alone: DIPE {dipe_text(calib.ga_dipe_px, calib.ga_dipe_mm)}; with the "
            f"least-squares polish: {dipe_text(calib.polish_dipe_px, calib.polish_dipe_mm)} "
            f"({which})"
        )
    for held in (rep.leave_one_out, rep.check):
        if held is None:
            continue
        t = Table(title=f"held-out error: {held.method} ({held.source})", title_justify="left")
        for c in ("point", "X,Y,Z cm", "error px", "error cm", "in-sample px"):
            t.add_column(c, justify="right")
        for p in held.points:
            t.add_row(
                p.name,
                f"{p.x_cm:.1f}, {p.y_cm:.1f}, {p.z_cm:.1f}",
                f"{p.error_px:.3f}",
                "-" if p.error_cm is None else f"{p.error_cm:.3f}",
                "-" if p.in_sample_px is None else f"{p.in_sample_px:.3f}",
            )
        if held.mean_px is not None:
            t.add_row(
                "mean",
                "",
                f"{held.mean_px:.3f}",
                "-" if held.mean_cm is None else f"{held.mean_cm:.3f}",
                "",
            )
        con.print(t)
        if held.missing:
            con.print(f"not found near their projection: {', '.join(held.missing)}")
    if rep.parameters:
        t = Table(title="what the control points determine", title_justify="left")
        for c in ("param.", "value", "range moves", "std. error", "of range", "restarts"):
            t.add_column(c, justify="right")
        t.add_column("fixed")
        for q in rep.parameters:
            t.add_row(
                _SHORT.get(q.name, q.name),
                f"{q.value:.4g}",
                f"{_num(q.sweep_px)} px",
                "-" if q.standard_error is None else f"±{_num(q.standard_error)}",
                "-" if q.relative_error is None else f"{_num(100 * q.relative_error)} %",
                "-" if q.restart_spread is None else f"{_num(100 * q.restart_spread)} %",
                "yes" if q.determined else "no",
            )
        con.print(t)
        con.print(
            "range moves: largest shift of a control point when the parameter alone sweeps "
            "its search range; restarts: spread of the values over GA restarts (share of the "
            "range); fixed: std. error below 5 % of the range"
        )
    for note in rep.notes:
        con.print(f"- {note}")


def register(app: typer.Typer) -> None:
    """Add the analysis commands to the `ovis` app."""
    app.command()(study)
    app.command()(compare)
