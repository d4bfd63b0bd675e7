"""Analysis commands (beyond the paper): `ovis study`, `ovis compare`, `ovis demo` and
`ovis heights`."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import msgspec
import numpy as np
import typer

from ovis.common.config import resolve_config
from ovis.services.cli.errors import UserError
from ovis.services.cli.options import OfflineConfigOpt, PaperPresetOpt, SummaryJsonOpt
from ovis.services.cli.ui import calibrate_with_progress, console, emit_json, progress, table

__all__ = ["register"]


def _emit_json(summary: object, paths: dict[str, Path]) -> None:
    """The summary and the files written, as indented JSON on stdout."""
    emit_json({"summary": summary, "files": {k: str(v) for k, v in paths.items()}})


def _resolve(config: Path | None, preset: str):
    cfg = resolve_config(config, preset)
    if cfg.camera.model != "paper":
        raise UserError(
            f"this analysis runs the paper's camera model; the configuration's camera is "
            f"{cfg.camera.model!r} (use --preset default or paper)"
        )
    return cfg


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
    preset: PaperPresetOpt = "default",
    config: OfflineConfigOpt = None,
    json: SummaryJsonOpt = False,
) -> None:
    """Reproduce the paper's parametric study of the GA (§5.1, Figure 7), with spread.

    Best DIPE against p_c, p_m, population size and number of generations, each varied
    alone around the paper's chosen setting (p_c 0.9, p_m 0.005, population 100, 90
    generations), with --seeds GA seeds per setting on the first frame of the simulated
    arena(s). Writes every run (study.csv), a summary table with the median, 10-90 %
    band and share of runs below the paper's DIPE (study.md), and the four panels of
    Figure 7 with their spread bands (study.png; log y; the paper's setting marked).
    The progress bar shows how far it is and how long the rest will take.
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
    con = console()
    t0 = time.perf_counter()
    with progress("study") as on_run:
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
    columns = ("factor", "value", "runs", "median px", "10-90 % px", "median mm", "success")
    t = table("GA parametric study (paper Figure 7): best DIPE", columns)
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
    preset: PaperPresetOpt = "default",
    config: OfflineConfigOpt = None,
    json: SummaryJsonOpt = False,
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
    con = console()
    t0 = time.perf_counter()
    with progress("compare") as on_run:
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
    columns = ("method", "runs", "success", "median DIPE px", "median world max cm", "p90")
    t = table("calibration methods on simulated arenas", columns)
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


def demo(
    out: Annotated[
        Path, typer.Option(help="Folder for the calibration, plots and overlays.")
    ] = Path("ovis-demo"),
    frames: Annotated[int, typer.Option(min=1, max=10000, help="Frames to detect on.")] = 30,
    seed: Annotated[int, typer.Option(min=0, help="Arena seed.")] = 0,
    preset: PaperPresetOpt = "default",
    config: OfflineConfigOpt = None,
) -> None:
    """Simulate an arena, calibrate on its first frame, then track robot and obstacles.

    The first frame's objects are the control points (as in the paper: four objects of
    known position). The GA calibrates the camera on it; then every later frame is
    processed with that calibration and compared with the simulator's ground truth.
    Writes calib.json, convergence.png and overlay.png (last frame) to --out.
    """
    from ovis.common.analysis.plots import draw_detections, plot_convergence, save_png
    from ovis.common.analysis.tracking import track_simulated
    from ovis.common.calibration.file import dipe_text, save_calibration
    from ovis.common.sim.arena import Arena, control_points
    from ovis.common.world.detection import Detector

    con = console()
    cfg = resolve_config(config, preset)
    arena = Arena(cfg, seed)
    frame0, truth0 = arena.render()
    points = control_points(truth0)
    con.print(
        f"[bold]1. simulated arena[/] {cfg.preset}, {cfg.camera.cols}x{cfg.camera.rows}, "
        f"seed {seed}: robot + {len(points) - 1} obstacles; control points "
        + ", ".join(f"{p.name} ({p.x_cm:.1f}, {p.y_cm:.1f}, {p.z_cm:.1f})" for p in points)
    )
    con.print("[bold]2. GA calibration[/] on frame 0 (paper §4)")
    calib = calibrate_with_progress(frame0, points, cfg, source="simulated frame 0", con=con)
    out.mkdir(parents=True, exist_ok=True)
    save_calibration(out / "calib.json", calib)
    plot_convergence(calib, out / "convergence.png")
    con.print(
        f"   DIPE {dipe_text(calib.dipe_px, calib.dipe_mm)} (paper 0.735 mm), "
        f"threshold {calib.image.threshold}, A^f {calib.image.size_filter_cm2:.1f} cm², "
        f"{calib.elapsed_s:.2f} s"
    )
    con.print(f"[bold]3. detection[/] on {frames} frames with identities kept")
    detector = Detector(calib.camera, calib.image, calib.pose)
    run = track_simulated(arena, detector, frames)
    score, last = run.score, run.last_detection
    if last is not None and run.last_frame is not None:
        save_png(out / "overlay.png", draw_detections(run.last_frame, last))
        robot = next((o for o in last.objects if o.kind == "robot"), None)
        if robot is not None and last.planner:
            con.print(
                f"   last frame: robot at ({robot.x_cm:.1f}, {robot.y_cm:.1f}) cm; "
                + "; ".join(
                    f"O{e.obstacle_id}: {e.distance_cm:.1f} cm, {e.angle_deg:+.1f}°"
                    for e in last.planner
                )
            )
    pe, re = np.asarray(score.position_error_cm), np.asarray(score.radius_error_cm)
    n_true = frames * len(points)
    t = table("accuracy against ground truth", ("measure", "value"), left={"measure"})
    found = f"{pe.size} of {n_true} ({score.missed} missed, {score.spurious} spurious)"
    t.add_row("objects found", found)
    if pe.size:
        t.add_row("position error mean / max", f"{pe.mean():.3f} / {pe.max():.3f} cm")
        t.add_row("radius error mean / max |.|", f"{re.mean():+.3f} / {np.abs(re).max():.3f} cm")
    t.add_row("robot/obstacle mislabelled", str(score.wrong_kind))
    t.add_row("identity switches", str(score.id_switches))
    ms = 1000 * run.detect_s
    t.add_row("detection time p50 / p99", f"{np.median(ms):.2f} / {np.percentile(ms, 99):.2f} ms")
    con.print(t)
    con.print(f"wrote {out / 'calib.json'}, {out / 'convergence.png'}, {out / 'overlay.png'}")


def heights(
    rig: Annotated[
        str, typer.Option(help="Camera: 'oblique' (tripod), 'overhead' or 'both'.")
    ] = "both",
    first_seed: Annotated[
        int,
        typer.Option(min=0, help="First scene's seed (the tests' and tuning's are below 1000)."),
    ] = 1000,
    scenes: Annotated[int, typer.Option(min=1, max=10000, help="Scenes (seeds) per camera.")] = 20,
    method: Annotated[
        str,
        typer.Option(
            help="'measured' (heights fitted to the silhouettes), 'configured' (today's: "
            "centroids on the 7 cm and 5 cm planes) or 'both'."
        ),
    ] = "both",
    marked: Annotated[
        bool, typer.Option("--marked", help="Also run the scenes with a marked robot.")
    ] = False,
    config: OfflineConfigOpt = None,
    json: SummaryJsonOpt = False,
) -> None:
    """Footprints and heights of solid objects in the physical world, against its truth.

    Draws --scenes physical scenes (MuJoCo; 4-8 cylinders, boxes and prisms 1-25 cm tall
    and a 16 x 10 x 5 cm robot on a 150 x 120 cm arena) from --first-seed on, renders
    each through the rig's true camera with the empty floor beside it, and detects
    with measured heights and/or today's configured ones. Prints per camera and method:
    obstacles found (missed, taken for the robot; those more than half hidden by others
    apart), spurious detections, footprint error, the detections whose position is not
    measurable (a stated 1-sigma over 1.65 cm) and how many lie within their stated
    uncertainty of an object, the errors of obstacles about 7 and
    about 20 cm tall, the measured heights' errors, and in how many scenes the robot
    was reported as the robot.
    """
    from ovis.common.analysis.footprints import evaluate_rig, summarise
    from ovis.common.physical.availability import why_unavailable
    from ovis.common.physical.rigs import RIGS

    reason = why_unavailable()
    if reason is not None:
        raise UserError(f"the physical world cannot render here: {reason}")
    rigs = list(RIGS) if rig == "both" else [rig]
    if any(r not in RIGS for r in rigs):
        raise UserError(f"--rig must be one of {', '.join(RIGS)} or both, got {rig!r}")
    methods = ["configured", "measured"] if method == "both" else [method]
    if any(m not in ("configured", "measured") for m in methods):
        raise UserError(f"--method must be measured, configured or both, got {method!r}")
    cfg = resolve_config(config, "default")
    seeds = range(first_seed, first_seed + scenes)
    runs = [
        (r, m, k) for r in rigs for m in methods for k in ([False, True] if marked else [False])
    ]
    reports = []
    with progress("scenes", show=not json) as on_run:
        total, done = len(runs) * scenes, [0]

        def step(result) -> None:
            done[0] += 1
            on_run(done[0], total, f"seed {result.seed}")

        for r, m, k in runs:
            results = evaluate_rig(cfg, r, seeds, m, marked=k, on_scene=step)  # type: ignore[arg-type]
            reports.append(summarise(results, r, m, marked=k))
    if json:
        emit_json([msgspec.to_builtins(x) for x in reports])
        return
    _print_heights(reports, seeds)


def _print_heights(reports, seeds: range) -> None:
    def pair(mean: float, top: float) -> str:
        return "-" if not np.isfinite(mean) else f"{mean:.2f} / {top:.2f}"

    columns = ["measure"] + [f"{x.rig} {x.method}{' marked' if x.marked else ''}" for x in reports]
    t = table(
        f"footprints and heights, physical scenes (seeds {seeds.start}-{seeds.stop - 1})",
        columns,
        left={"measure"},
    )
    rows = {
        "obstacles found": lambda x: f"{x.found} of {x.obstacles}",
        "missed / taken for the robot": lambda x: f"{x.missed} / {x.as_robot}",
        "spurious": lambda x: str(x.spurious),
        "mostly hidden (found)": lambda x: f"{x.hidden} ({x.hidden_found})",
        "footprint error mean / max cm": lambda x: pair(x.footprint_mean_cm, x.footprint_max_cm),
        "positions not measurable (within their σ)": lambda x: (
            f"{x.positions_unmeasurable} ({x.positions_within_stated})"
        ),
        "  their error max / stated σ max cm": lambda x: (
            "-"
            if not np.isfinite(x.unmeasurable_error_max_cm)
            else f"{x.unmeasurable_error_max_cm:.2f} / {x.unmeasurable_sigma_max_cm:.2f}"
        ),
        "about 7 cm tall: n, mean / max cm": lambda x: (
            f"{x.near_7cm}: " + pair(x.near_7cm_mean_cm, x.near_7cm_max_cm)
        ),
        "about 20 cm tall: n, mean / max cm": lambda x: (
            f"{x.near_20cm}: " + pair(x.near_20cm_mean_cm, x.near_20cm_max_cm)
        ),
        "heights measured (within 1 cm)": lambda x: (
            f"{x.heights_measured} ({x.heights_within_1cm})"
        ),
        "height error mean / max cm": lambda x: pair(x.height_mean_cm, x.height_max_cm),
        "heights not measurable": lambda x: str(x.heights_not_measurable),
        "robot reported as the robot": lambda x: f"{x.robot_scenes} of {x.scenes}",
        "detection s per scene": lambda x: f"{x.seconds_per_scene:.2f}",
    }
    for name, cell in rows.items():
        t.add_row(name, *(cell(x) for x in reports))
    console().print(t)
    console().print(
        "footprint: where each obstacle stands (its centre on the floor) against MuJoCo's "
        "truth, matched within 5 cm; a position not measurable (a detection's stated 1σ over "
        "1.65 cm: a foot hidden behind another solid) is matched within its stated "
        "uncertainty (99 %, 0.5 cm added, at most 20 cm off and a stated 1σ of at most "
        "10 cm) and kept out of the footprint error; "
        "'about' a height: within 1.5 cm of it; an obstacle is "
        "mostly hidden when others hide more than half of its silhouette (counted apart); "
        "the rigs' true cameras, the empty floor subtracted, objects 3 levels brighter"
    )


def register(app: typer.Typer) -> None:
    """Add the analysis commands to the `ovis` app."""
    app.command()(study)
    app.command()(compare)
    app.command()(demo)
    app.command()(heights)
