"""Offline commands: simulate, calibrate, detect, plan, config show."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Any

import msgspec
import numpy as np
import typer

from ovis.services.cli.errors import UserError

__all__ = ["register"]


def _console():
    from rich.console import Console

    return Console(stderr=False, highlight=False)


def _emit_json(data: Any) -> None:
    sys.stdout.write(msgspec.json.format(msgspec.json.encode(data), indent=2).decode() + "\n")


def _numbers(text: str, n: int, what: str) -> tuple[float, ...]:
    """Parse 'a,b[,c]' into n finite floats, or say what was expected."""
    parts = [p.strip() for p in text.split(",")]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != n or not all(np.isfinite(values)):
        fmt = ",".join("XYR"[:n]) if n <= 3 else "…"
        raise UserError(f"{what} must be {n} finite numbers as {fmt} (cm), got {text!r}")
    return values


def read_image(path: Path) -> np.ndarray:
    """Read an image file as uint8 (grey or BGR), or fail with what to do."""
    import cv2

    if not path.exists():
        raise UserError(f"image {path} does not exist")
    if path.is_dir():
        raise UserError(f"{path} is a folder; give an image file (PNG, JPEG, BMP, …)")
    if path.stat().st_size == 0:
        raise UserError(f"image {path} is empty (0 bytes)")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None or image.size == 0:
        raise UserError(f"cannot read {path} as an image; give a PNG, JPEG, BMP or TIFF file")
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    return image


def resolve_config(config_file: Path | None, preset: str | None, points_config=None):
    from ovis.common.config import config_from_dict, load_config

    if config_file is not None:
        return load_config(config_file)
    if points_config is not None and preset is None:
        return config_from_dict(points_config, "points file [config]")
    return load_config(preset=preset or "default")


ConfigOpt = Annotated[
    Path | None,
    typer.Option(
        "--config",
        "-c",
        help="TOML configuration (may name a preset and override any of its fields).",
        dir_okay=False,
    ),
]
PresetOpt = Annotated[
    str | None,
    typer.Option(
        help="Built-in preset when no --config is given: 'default', 'paper' or 'pinhole'."
    ),
]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print machine-readable JSON.")]


def simulate(
    out: Annotated[Path, typer.Option(help="Folder to write the frames and ground truth to.")],
    frames: Annotated[int, typer.Option(min=1, max=100000, help="Number of frames.")] = 10,
    seed: Annotated[int, typer.Option(min=0, help="Random seed: same seed, same arena.")] = 0,
    config: ConfigOpt = None,
    preset: PresetOpt = None,
    json: JsonOpt = False,
    robots: Annotated[
        int | None,
        typer.Option(
            min=1,
            max=50,
            help="Marked robots (each with an ArUco/AprilTag marker, on crossing paths); "
            "default: the paper's one unmarked robot.",
        ),
    ] = None,
    obstacles: Annotated[
        int | None, typer.Option(min=0, max=500, help="Obstacles (default: the config's).")
    ] = None,
) -> None:
    """Render frames of the simulated arena with ground truth.

    Writes frame_0000.png …, truth.json (camera parameters and, per frame, each object's
    id, kind, x_cm, y_cm, radius_cm) and points.toml (the first frame's objects as
    control points, plus the configuration), ready for
    `ovis calibrate OUT/frame_0000.png --points OUT/points.toml --out calib.json`.
    """
    from ovis.common.sim.arena import write_dataset

    cfg = resolve_config(config, preset)
    cfg = _scene(cfg, robots, obstacles)
    try:
        info = write_dataset(out, cfg, frames, seed)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    if json:
        _emit_json(info)
        return
    con = _console()
    con.print(
        f"wrote {frames} frame(s) of the {cfg.preset} arena "
        f"({cfg.camera.cols}x{cfg.camera.rows}, seed {seed}) to {out}"
    )
    con.print(f"  ground truth: {out / 'truth.json'}\n  control points: {out / 'points.toml'}")
    if info.checks is not None:
        con.print(f"  check points (last frame): {info.checks}")
    con.print(
        f"next: ovis calibrate {out / 'frame_0000.png'} --points {out / 'points.toml'} "
        f"--out {out / 'calib.json'}"
        + (f" --check {info.checks}" if info.checks is not None else "")
    )


def _scene(cfg, robots: int | None, obstacles: int | None):
    """The configuration with --robots marked robots and --obstacles obstacles."""
    if robots is not None:
        from ovis.common.sim.scenes import marked_scene

        return marked_scene(cfg, robots, obstacles)
    if obstacles is not None:
        sim = msgspec.structs.replace(cfg.simulator, n_obstacles=obstacles)
        return msgspec.structs.replace(cfg, simulator=sim)
    return cfg


def calibrate(
    image: Annotated[Path, typer.Argument(help="Calibration frame (one object per point).")],
    points: Annotated[
        Path,
        typer.Option(help="Control points TOML: [[points]] name, x_cm, y_cm, z_cm."),
    ],
    out: Annotated[Path, typer.Option(help="Where to write the calibration JSON.")],
    config: ConfigOpt = None,
    preset: PresetOpt = None,
    seed: Annotated[int | None, typer.Option(min=0, help="GA seed (default: config).")] = None,
    population: Annotated[int | None, typer.Option(min=2, help="GA population size.")] = None,
    generations: Annotated[int | None, typer.Option(min=1, help="GA generations.")] = None,
    pc: Annotated[float | None, typer.Option(min=0.0, max=1.0, help="Crossover prob.")] = None,
    pm: Annotated[float | None, typer.Option(min=0.0, max=1.0, help="Mutation prob.")] = None,
    plot: Annotated[Path | None, typer.Option(help="Write a convergence plot (PNG).")] = None,
    json: JsonOpt = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
    polish: Annotated[
        bool | None,
        typer.Option(
            "--polish/--no-polish",
            help="Least-squares polish after the GA (default: config [ga] polish).",
        ),
    ] = None,
    check: Annotated[
        Path | None,
        typer.Option(
            help="Check points TOML ([[points]] as in --points; optional image = FRAME "
            "relative to it): their error is reported as held-out error.",
            dir_okay=False,
        ),
    ] = None,
    restarts: Annotated[
        int,
        typer.Option(
            min=0,
            max=100,
            help="GA restarts with other seeds, to show which parameters "
            "the data determine (0: only the Jacobian).",
        ),
    ] = 4,
    residuals: Annotated[
        Path | None, typer.Option(help="Write the residual vectors drawn on the frame (PNG).")
    ] = None,
    error_map: Annotated[
        Path | None,
        typer.Option(
            "--error-map",
            help="Write the floor-error map against the configuration's camera (PNG): "
            "the true camera for `ovis simulate` data (its points.toml [config]).",
        ),
    ] = None,
) -> None:
    """Calibrate the camera with the genetic algorithm (paper §4).

    Tunes threshold, size filter, Z0, λ, k1..k3, s_x, s_y within the configured ranges to
    minimise the DIPE (eq. 14) of the control points, under the constraint that exactly
    one object per control point is seen. The configuration comes from --config, else
    from the points file's [config] table, else the default preset.

    Every calibration also reports its held-out error (leave-one-out over the control
    points, and --check points) and which parameters the data determine (GA restarts,
    Jacobian), and the GA's DIPE beside the least-squares polish's.
    """
    from ovis.common.calibration.file import save_calibration
    from ovis.common.config import load_points

    pts = load_points(points)
    cfg = resolve_config(config, preset, pts.config)
    overrides = {
        k: v
        for k, v in dict(
            seed=seed,
            population=population,
            generations=generations,
            pc=pc,
            pm=pm,
            polish=polish,
        ).items()
        if v is not None
    }
    if overrides:
        cfg = msgspec.structs.replace(cfg, ga=msgspec.structs.replace(cfg.ga, **overrides))
    frame = read_image(image)
    calib = calibrate_with_progress(
        frame, pts.points, cfg, source=str(image), show=not quiet and not json
    )
    from ovis.services.cli.analysis import add_accuracy, write_calibration_plots

    calib = add_accuracy(
        frame, pts.points, cfg, calib, check=check, restarts=restarts, show=not quiet and not json
    )
    save_calibration(out, calib)
    if plot is not None:
        from ovis.common.analysis.plots import plot_convergence

        plot_convergence(calib, plot)
    simulated = pts.config is not None and config is None  # `ovis simulate` data
    arena = (cfg.simulator.arena_x_cm, cfg.simulator.arena_y_cm) if simulated else None
    wrote = write_calibration_plots(
        frame, calib, cfg, residuals=residuals, error_map=error_map, arena=arena
    )
    if json:
        _emit_json(calib)
        return
    _print_calibration(calib, out, plot)
    for line in wrote:
        _console().print(line)


def calibrate_with_progress(frame, points, cfg, *, source: str, show: bool = True, con=None):
    """Run the GA calibration, with a progress bar showing the best DIPE so far."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from ovis.common.calibration.problem import calibrate as run_calibration

    if not show:
        return run_calibration(frame, points, cfg, source=source)[0]
    progress = Progress(
        TextColumn("[bold]GA[/]"),
        BarColumn(),
        TextColumn("gen {task.completed}/{task.total}"),
        TextColumn("best DIPE {task.fields[best]}"),
        TimeElapsedColumn(),
        console=con or _console(),
    )
    task = progress.add_task("ga", total=cfg.ga.generations, best="-")

    def on_generation(stats) -> None:
        best = f"{stats.best_so_far:.3f} px" if stats.best_so_far < 1e6 else "infeasible"
        progress.update(task, completed=stats.generation, best=best)

    with progress:
        return run_calibration(frame, points, cfg, on_generation=on_generation, source=source)[0]


def _print_calibration(calib, out: Path, plot: Path | None) -> None:
    from rich.table import Table

    con = _console()
    cam = calib.camera
    t = Table(title="calibrated parameters", title_justify="left")
    t.add_column("parameter")
    t.add_column("value", justify="right")
    band = calib.feasible_thresholds
    centred = f" (GA {calib.ga_threshold}; {band[0]}-{band[1]} see the right count)" if band else ""
    ga_af = calib.ga_size_filter_cm2
    rows: list[tuple[str, str]] = [
        ("threshold", f"{calib.image.threshold}{centred}"),
        (
            "size filter A^f",
            f"{calib.image.size_filter_cm2:.2f} cm²"
            + (f" (GA {ga_af:.2f})" if ga_af is not None and band else ""),
        ),
    ]
    if cam.model == "pinhole":
        rows += _pinhole_rows(cam)
    else:
        rows += _paper_rows(cam)
    for name, value in rows:
        t.add_row(name, value)
    con.print(t)
    _print_residuals(calib, out, plot)


def _paper_rows(cam) -> list[tuple[str, str]]:
    """Parameter rows of a paper-model camera."""
    return [
        ("Z0", f"{cam.Z0_cm:.3f} cm"),
        ("λ", f"{cam.lam_mm:.4f} mm"),
        ("k1", f"{cam.k1:.3e}"),
        ("k2", f"{cam.k2:.3e}"),
        ("k3", f"{cam.k3:.3e}"),
        ("s_x", f"{cam.s_x:.5f}"),
        ("s_y", f"{cam.s_y:.5f}"),
    ]


def _print_residuals(calib, out: Path, plot: Path | None) -> None:
    from rich.table import Table

    con = _console()
    p = Table(title="DIPE per control point (eq. 14)", title_justify="left")
    for col in ("point", "X,Y,Z cm", "detected row,col", "predicted row,col", "px", "mm"):
        p.add_column(col, justify="right")
    for r in calib.points:
        p.add_row(
            r.name,
            f"{r.x_cm:g}, {r.y_cm:g}, {r.z_cm:g}",
            f"{r.detected_row:.2f}, {r.detected_col:.2f}",
            f"{r.predicted_row:.2f}, {r.predicted_col:.2f}",
            f"{r.dipe_px:.3f}",
            f"{r.dipe_mm:.4f}",
        )
    con.print(p)
    con.print(
        f"DIPE mean {calib.dipe_px:.3f} px = {calib.dipe_mm:.4f} mm, max {calib.dipe_max_px:.3f}"
        f" px = {calib.dipe_max_mm:.4f} mm (paper: 0.735214 mm); {calib.evaluations} "
        f"evaluations in {calib.elapsed_s:.2f} s"
    )
    from ovis.services.cli.analysis import print_accuracy

    print_accuracy(calib, con)
    con.print(f"wrote {out}" + (f" and {plot}" if plot else ""))


def detect(
    images: Annotated[
        list[Path], typer.Argument(help="Frame(s); several frames keep obstacle ids.")
    ],
    calibration: Annotated[Path, typer.Option(help="Calibration JSON from `ovis calibrate`.")],
    goal: Annotated[
        str | None, typer.Option(help="Goal point X,Y (cm); default: the calibration's.")
    ] = None,
    goal_angle: Annotated[
        float | None,
        typer.Option(help="Goal reference line angle (deg from +X); overrides --goal."),
    ] = None,
    json: JsonOpt = False,
    overlay: Annotated[
        Path | None,
        typer.Option(
            help="Write the frame with detections drawn on it (PNG; with several "
            "frames, one file per frame: NAME_0000.png …)."
        ),
    ] = None,
    fps: Annotated[
        float,
        typer.Option(
            min=1e-3,
            max=1e4,
            help="Frame rate of the frames, for velocities in cm/s (`ovis simulate` "
            "frames: simulator.fps, 30); default 1, the paper's Δt = 1 s.",
        ),
    ] = 1.0,
) -> None:
    """Find the robot and the obstacles in frames; compute the planner's inputs.

    Prints, per object, its id, kind, pixel centroid, area, perimeter (Koplowitz–
    Bruckstein), compactness, world position and radius; per obstacle, the distance
    |O − R| − r_O and the signed angle from the goal direction (CCW positive).
    """
    from ovis.common.calibration.file import load_calibration
    from ovis.common.world.detection import Detector

    calib = load_calibration(calibration)
    goal_xy = _numbers(goal, 2, "--goal") if goal is not None else None
    if goal_angle is not None and not np.isfinite(goal_angle):
        raise UserError("--goal-angle must be a finite number of degrees")
    detector = Detector(calib.camera, calib.image, calib.pose)
    results = []
    for i, path in enumerate(images):
        frame = read_image(path)
        det = detector.detect(frame, goal_xy=goal_xy, goal_angle_deg=goal_angle, stamp_s=i / fps)
        results.append((path, frame, det))
        if overlay is not None:
            from ovis.common.analysis.plots import draw_detections, save_png

            target = overlay
            if len(images) > 1:
                target = overlay.with_name(f"{overlay.stem}_{i:04d}{overlay.suffix or '.png'}")
            save_png(target, draw_detections(frame, det))
    if json:
        payload = [{"image": str(p), **msgspec.to_builtins(d)} for p, _, d in results]
        _emit_json(payload[0] if len(payload) == 1 else payload)
        return
    for path, _, det in results:
        _print_detection(path, det)


def _print_detection(path: Path, det) -> None:
    from rich.table import Table

    con = _console()
    t = Table(title=f"{path}: {len(det.objects)} object(s)", title_justify="left")
    for col in (
        "id",
        "kind",
        "row",
        "col",
        "area px",
        "perim px",
        "compact.",
        "X cm",
        "Y cm",
        "r cm",
    ):
        t.add_column(col, justify="right")
    for o in det.objects:
        t.add_row(
            str(o.id),
            o.kind,
            f"{o.row:.2f}",
            f"{o.col:.2f}",
            f"{o.area_px:.0f}",
            f"{o.perimeter_px:.1f}",
            f"{o.compactness:.3f}",
            f"{o.x_cm:.2f}",
            f"{o.y_cm:.2f}",
            f"{o.radius_cm:.2f}",
        )
    con.print(t)
    if det.robots or det.unknown_markers:
        from ovis.services.cli.robots import print_robots

        print_robots(det, con)
    if det.planner:
        p = Table(title="motion planner inputs", title_justify="left")
        for col in ("obstacle", "distance cm", "angle deg"):
            p.add_column(col, justify="right")
        for e in det.planner:
            p.add_row(str(e.obstacle_id), f"{e.distance_cm:.3f}", f"{e.angle_deg:.3f}")
        con.print(p)
    elif not any(o.kind == "robot" for o in det.objects):
        con.print("no robot found: no planner inputs (check pose.robot_* in the calibration)")


def plan(
    robot: Annotated[str, typer.Option(help="Robot centre X,Y (cm).")],
    obstacle: Annotated[list[str], typer.Option(help="Obstacle X,Y,R (cm); repeat for several.")],
    goal: Annotated[str | None, typer.Option(help="Goal point X,Y (cm).")] = None,
    goal_angle: Annotated[
        float | None, typer.Option(help="Goal reference line angle, deg from +X.")
    ] = None,
    json: JsonOpt = False,
) -> None:
    """Motion-planner inputs for given positions.

    Per obstacle: distance = |O − R| − r_O, and the signed angle (deg, CCW positive, in
    (−180, 180]) from the goal direction (robot → goal, or the goal reference line) to
    robot → obstacle. Output is in the order the obstacles are given.
    """
    from ovis.common.world.planner import planner_inputs

    if goal is None and goal_angle is None:
        raise UserError("give --goal X,Y or --goal-angle DEG")
    r = _numbers(robot, 2, "--robot")
    obs = [_numbers(o, 3, "--obstacle") for o in obstacle]
    if any(o[2] < 0 for o in obs):
        raise UserError("an obstacle radius must not be negative")
    g = _numbers(goal, 2, "--goal") if goal is not None else None
    try:
        res = planner_inputs(r, obs, goal_xy=g, goal_angle_deg=goal_angle)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    rows = [
        {"distance_cm": float(d), "angle_deg": float(a)}
        for d, a in zip(res.distance_cm, res.angle_deg, strict=True)
    ]
    if json:
        _emit_json(rows)
        return
    from rich.table import Table

    t = Table(title="motion planner inputs", title_justify="left")
    for col in ("obstacle", "X,Y,R cm", "distance cm", "angle deg"):
        t.add_column(col, justify="right")
    for i, (o, row) in enumerate(zip(obs, rows, strict=True), start=1):
        t.add_row(
            str(i),
            ", ".join(f"{v:g}" for v in o),
            f"{row['distance_cm']:.3f}",
            f"{row['angle_deg']:.3f}",
        )
    _console().print(t)


config_app = typer.Typer(help="Show configurations.", no_args_is_help=True, rich_markup_mode=None)


@config_app.command("show")
def config_show(
    preset: Annotated[
        str, typer.Option(help="Built-in preset: 'default', 'paper' or 'pinhole'.")
    ] = "default",
    config: ConfigOpt = None,
) -> None:
    """Print a complete, editable TOML configuration.

    A built-in preset (with comments saying which values are the paper's), or a --config
    file merged over its preset.
    """
    from ovis.common.config import dump_toml, load_config, preset_text

    if config is not None:
        sys.stdout.write(dump_toml(load_config(config)))
    else:
        sys.stdout.write(preset_text(preset))


def _pinhole_rows(cam) -> list[tuple[str, str]]:
    """Parameter rows of a pinhole camera (OpenCV: x = column, y = row)."""
    return [
        ("fx (columns)", f"{cam.fx:.3f} px"),
        ("fy (rows)", f"{cam.fy:.3f} px"),
        ("cx (column)", f"{cam.cx:.3f} px"),
        ("cy (row)", f"{cam.cy:.3f} px"),
        *((n, f"{getattr(cam, n):.5g}") for n in ("k1", "k2", "p1", "p2", "k3")),
        ("rvec", ", ".join(f"{v:.5f}" for v in cam.rvec) + " rad"),
        ("tvec", ", ".join(f"{v:.3f}" for v in cam.tvec_cm) + " cm"),
    ]


def register(app: typer.Typer) -> None:
    """Add the offline commands to the `ovis` app."""
    app.command()(simulate)
    app.command()(calibrate)
    app.command()(detect)
    app.command()(plan)
    from ovis.services.cli.export import export

    app.command()(export)
    app.add_typer(config_app, name="config")
    from ovis.services.cli.demo import demo

    app.command()(demo)
