"""Offline commands, on files: simulate, calibrate, detect, plan, config show."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Any

import msgspec
import numpy as np
import typer

from ovis.common.config import resolve_config
from ovis.common.vision.imageio import read_image
from ovis.services.cli.camera import BoardOriginOpt, BoardRowEndOpt
from ovis.services.cli.errors import UserError
from ovis.services.cli.options import JsonOpt, OfflineConfigOpt, PresetOpt, WorldOpt
from ovis.services.cli.ui import (
    calibrate_with_progress,
    console,
    emit_json,
    progress,
    table,
)

__all__ = ["register"]


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


def simulate(
    out: Annotated[Path, typer.Option(help="Folder to write the frames and ground truth to.")],
    frames: Annotated[int, typer.Option(min=1, max=100000, help="Number of frames.")] = 10,
    seed: Annotated[int, typer.Option(min=0, help="Random seed: same seed, same arena.")] = 0,
    config: OfflineConfigOpt = None,
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
    world: WorldOpt = None,
    camera: Annotated[
        str | None,
        typer.Option(
            help="--world physical: the camera the frames are rendered through: 'oblique' "
            "(a tripod at the side), 'overhead' (straight down) or a calibration JSON "
            "(its camera); default: the configuration's.",
        ),
    ] = None,
) -> None:
    """Render frames of the simulated arena with ground truth.

    Writes frame_0000.png …, truth.json (camera parameters and, per frame, each object's
    id, kind, x_cm, y_cm, radius_cm) and points.toml (the first frame's objects as
    control points, plus the configuration), ready for
    `ovis calibrate OUT/frame_0000.png --points OUT/points.toml --out calib.json`.

    With --world physical (the `physical` preset unless --config or --preset says
    otherwise): solid objects rendered by MuJoCo at [simulator] fps, truth.json (each
    frame's time and every solid's footprint centre, height, yaw, velocity, shape and how
    much of it is seen), background.png (the empty floor), points.toml (the floor marks,
    their pixels measured in the empty floor), lens.yaml (the camera's lens) and
    true_calibration.json (the true camera), ready for `ovis calibrate
    OUT/background.png --intrinsics OUT/lens.yaml --points OUT/points.toml --out calib.json`
    (docs/physical.md).
    """
    from ovis.services.cli.physical import simulate_physical, world_config

    cfg = world_config(config, preset, world)
    if cfg.simulator.world == "physical":
        simulate_physical(out, cfg, frames, seed, json=json, robots=robots,
                          obstacles=obstacles, camera=camera)  # fmt: skip
        return
    if camera is not None:
        raise UserError("--camera picks the camera of --world physical")
    from ovis.common.sim.arena import write_dataset

    cfg = _scene(cfg, robots, obstacles)
    try:
        info = write_dataset(out, cfg, frames, seed)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    if json:
        emit_json(info)
        return
    con = console()
    con.soft_wrap = True  # paths and the next command whole, to be copied (not cut at 80)
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
    out: Annotated[Path, typer.Option(help="Where to write the calibration JSON.")],
    points: Annotated[
        Path | None,
        typer.Option(
            help="Control points TOML: [[points]] name, x_cm, y_cm, z_cm; with row, col (px) "
            "for points whose pixel is known (then give --intrinsics)."
        ),
    ] = None,
    intrinsics: Annotated[
        Path | None,
        typer.Option(
            help="CAM.yaml from `ovis intrinsics`: keep the lens fixed and solve the camera's "
            "pose over the floor (solvePnP) from pixel-known points, --board or --markers."
        ),
    ] = None,
    board: Annotated[
        str | None,
        typer.Option(
            help="With --intrinsics: a board lying on the floor, chessboard:COLSxROWS or "
            "charuco:COLSxROWS:DICT; its first inner corner is the origin, x along its first "
            "row (--board-origin, --board-row-end: placed in the arena's frame)."
        ),
    ] = None,
    square_cm: Annotated[
        float | None,
        typer.Option(
            "--square-cm",
            min=1e-6,
            help="--board (required): side of a square (cm); the camera's position is "
            "in these units.",
        ),
    ] = None,
    marker_cm: Annotated[
        float | None, typer.Option("--marker-cm", min=1e-6, help="--board charuco: marker side.")
    ] = None,
    board_origin: BoardOriginOpt = None,
    board_row_end: BoardRowEndOpt = None,
    markers: Annotated[
        Path | None,
        typer.Option(
            help="With --intrinsics: ArUco markers TOML (dictionary; [[markers]] id, x_cm, "
            "y_cm, side_cm[, angle_deg]) taped at surveyed floor positions."
        ),
    ] = None,
    point_px: Annotated[
        float | None,
        typer.Option(
            "--point-px",
            min=0.0,
            help="With --intrinsics: how precisely the control points' pixels are known "
            "(RMS, px); default 0.5 for --points and --markers (a careful click), 0 for "
            "--board (the lens's own corner detector: its RMS covers them). A pose whose "
            "residuals the lens's RMS and this do not explain is refused (exit 3).",
        ),
    ] = None,
    force: Annotated[
        bool, typer.Option(help="Save a calibration flagged implausible (exit 0).")
    ] = False,
    config: OfflineConfigOpt = None,
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

    With --intrinsics CAM.yaml the lens is fixed and only the camera's pose is solved,
    from pixel-known points, --board (with --square-cm) or --markers. The report gives
    the camera's height and tilt, the lens's RMS and each point's residual; a pose whose
    residuals the lens's RMS and the points' precision (--point-px) do not explain is
    refused (exit 3) naming the point, or the lens file, to blame, unless --force.
    """
    from ovis.common.calibration.file import save_calibration
    from ovis.common.config import load_points, with_ga
    from ovis.services.cli.camera import calibrate_known_lens, refuse_implausible
    from ovis.services.cli.reports import print_calibration

    placed = board_origin is not None or board_row_end is not None
    if intrinsics is not None or board is not None or markers is not None or placed:
        calibrate_known_lens(
            image,
            board_origin=board_origin,
            board_row_end=board_row_end,
            intrinsics=intrinsics,
            points=points,
            board=board,
            square_cm=square_cm,
            marker_cm=marker_cm,
            markers=markers,
            point_px=point_px,
            config=config,
            preset=preset,
            out=out,
            json=json,
            force=force,
            quiet=quiet,
        )
        return
    if points is None:
        raise UserError("give --points FILE (or --intrinsics CAM.yaml with --board/--markers)")
    pts = load_points(points)
    if any(p.pixel_known for p in pts.points):
        raise UserError(f"{points} gives pixels (row, col): add --intrinsics CAM.yaml")
    cfg = resolve_config(config, preset, pts.config)
    cfg = with_ga(
        cfg, seed=seed, population=population, generations=generations, pc=pc, pm=pm, polish=polish
    )
    frame = read_image(image)
    cfg = _sized_to(cfg, frame)
    calib = calibrate_with_progress(
        frame, pts.points, cfg, source=str(image), show=not quiet and not json
    )
    calib = add_accuracy(
        frame, pts.points, cfg, calib, check=check, restarts=restarts, show=not quiet and not json
    )
    warnings = refuse_implausible(calib, force)
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
        emit_json(calib)
        return
    print_calibration(calib, out, plot)
    for line in wrote + [f"WARNING (forced): {w}" for w in warnings]:
        console().print(line)


def _sized_to(cfg, frame):
    """The configuration with the camera sized to the frame (the size comes from the image)."""
    from ovis.common.camera.projection import camera_for_image_size

    try:
        camera = camera_for_image_size(cfg.camera, frame.shape[0], frame.shape[1])
    except ValueError as exc:
        raise UserError(str(exc)) from None
    return msgspec.structs.replace(cfg, camera=camera)


# ------------------------------------------------ what `ovis calibrate` adds to a calibration


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
        check_image = read_image(checks.image)
    with progress("accuracy", show=show) as update:
        report = assess(
            frame,
            points,
            cfg,
            calib,
            n_restarts=restarts,
            checks=checks,
            check_image=check_image,
            on_step=lambda stage, done, total: update(done, total, stage),
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


def detect(
    images: Annotated[
        list[Path], typer.Argument(help="Frame(s); several frames keep obstacle ids.")
    ],
    calibration: Annotated[
        Path | None,
        typer.Option(
            help="Calibration JSON from `ovis calibrate`; without it, blobs in pixels only "
            "(automatic threshold unless --threshold)."
        ),
    ] = None,
    threshold: Annotated[
        str | None,
        typer.Option(
            help="Threshold: a level 0..255, 'otsu', 'auto' (Otsu on the local contrast) or "
            "'adaptive:LEVEL' (LEVEL on the local contrast, 128 = the surroundings)."
        ),
    ] = None,
    size_filter: Annotated[
        float | None,
        typer.Option(
            min=0.0,
            help="Smallest object: cm² with a calibration (default: its size filter), px "
            "without (default: 1/20 of the typical object's area, at least 16 px).",
        ),
    ] = None,
    max_size: Annotated[
        float | None,
        typer.Option(min=0.0, help="Largest object: cm² with a calibration, px without."),
    ] = None,
    block_px: Annotated[
        int | None,
        typer.Option(
            min=3,
            help="Local-contrast window (px) for auto/adaptive. Default: four times the "
            "typical object's width.",
        ),
    ] = None,
    polarity: Annotated[
        str | None, typer.Option(help="'bright' objects on a dark floor, or 'dark'.")
    ] = None,
    background: Annotated[
        Path | None, typer.Option(help="Image of the empty floor, subtracted first.")
    ] = None,
    roi: Annotated[
        Path | None, typer.Option(help="Region-of-interest mask image (non-zero: look there).")
    ] = None,
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
        float | None,
        typer.Option(
            min=1e-3,
            max=1e4,
            help="Frame rate of the frames, for velocities in cm/s. Default: the "
            "simulator's for `ovis simulate` frames (the points.toml beside them), else 1 "
            "(the paper's Δt = 1 s).",
        ),
    ] = None,
    heights: Annotated[
        str | None,
        typer.Option(
            help="'measured': each solid's footprint and height fitted to its silhouette "
            "(needs --background, the empty floor); 'configured': every top face at its "
            "class's height. Default: the calibration's [pose] heights."
        ),
    ] = None,
    height: Annotated[
        list[str] | None,
        typer.Option(
            help="Declare a height: robot=CM or obstacle=CM (that class's height, not "
            "measured), marker:ID=CM (the robot carrying marker ID); repeat for several."
        ),
    ] = None,
) -> None:
    """Find the robot and the obstacles in frames; compute the planner's inputs.

    Prints, per object, its id, kind, pixel centroid, area, perimeter (Koplowitz–
    Bruckstein), compactness, world position, height (and where it comes from) and
    radius; per obstacle, the distance |O − R| − r_O and the signed angle from the goal
    direction (CCW positive). With measured heights X, Y is where each solid stands
    (its footprint's centre); with configured ones, its blob's centroid on its class's
    top plane.
    """
    from ovis.common.calibration.file import load_calibration
    from ovis.common.world.detection import Detector
    from ovis.common.world.heights import with_heights
    from ovis.services.cli.camera import detect_without_calibration, with_image_flags
    from ovis.services.cli.reports import print_detection

    flags = dict(
        threshold=threshold,
        size_filter=size_filter,
        max_size=max_size,
        block_px=block_px,
        polarity=polarity,
        background=background,
        roi=roi,
    )
    if calibration is None:
        detect_without_calibration(images, flags, json=json, overlay=overlay)
        return
    calib = load_calibration(calibration)
    try:
        pose = with_heights(calib.pose, heights, height or [])
    except ValueError as exc:
        raise UserError(str(exc)) from None
    image = with_image_flags(calib.image, **flags)
    calib = msgspec.structs.replace(calib, image=image, pose=pose)
    goal_xy = _numbers(goal, 2, "--goal") if goal is not None else None
    if goal_angle is not None and not np.isfinite(goal_angle):
        raise UserError("--goal-angle must be a finite number of degrees")
    try:
        detector = Detector(calib.camera, calib.image, calib.pose)
    except ValueError as exc:
        raise UserError(f"{exc}; give it with --background") from None
    rate, rate_from = _frame_rate(images, fps)
    results = []
    for i, path in enumerate(images):
        frame = read_image(path)
        det = detector.detect(
            frame, goal_xy=goal_xy, goal_angle_deg=goal_angle, stamp_s=i / rate, fit_all=True
        )
        results.append((path, frame, det))
        if overlay is not None:
            from ovis.common.analysis.plots import draw_detections, save_png

            target = overlay
            if len(images) > 1:
                target = overlay.with_name(f"{overlay.stem}_{i:04d}{overlay.suffix or '.png'}")
            save_png(target, draw_detections(frame, det))
    if json:
        payload = [
            {"image": str(p), "stamp_s": i / rate, **msgspec.to_builtins(d)}
            for i, (p, _, d) in enumerate(results)
        ]
        emit_json(payload[0] if len(payload) == 1 else payload)
        return
    for path, _, det in results:
        print_detection(path, det, calib.pose.heights)
    if len(images) > 1:
        console().print(f"frames 1/{rate:g} s apart ({rate_from}): velocities in cm/s over them")


def _frame_rate(images: list[Path], fps: float | None) -> tuple[float, str]:
    """The frames' rate (per s) and where it comes from: ``--fps``; else, for frames
    written by `ovis simulate` (its truth.json and points.toml beside them), the
    simulator's; else 1, the paper's Δt = 1 s."""
    from ovis.common.config import ConfigError, config_from_dict, load_points

    if fps is not None:
        return fps, "--fps"
    folder = images[0].parent
    points = folder / "points.toml"
    together = all(p.parent == folder for p in images)
    if together and (folder / "truth.json").is_file() and points.is_file():
        try:
            cfg = load_points(points).config
        except ConfigError:
            cfg = None
        if cfg is not None:
            return config_from_dict(cfg).simulator.fps, f"simulator.fps of {points}"
    return 1.0, "no --fps: the paper's Δt = 1 s"


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
        emit_json(rows)
        return
    t = table("motion planner inputs", ("obstacle", "X,Y,R cm", "distance cm", "angle deg"))
    for i, (o, row) in enumerate(zip(obs, rows, strict=True), start=1):
        t.add_row(
            str(i),
            ", ".join(f"{v:g}" for v in o),
            f"{row['distance_cm']:.3f}",
            f"{row['angle_deg']:.3f}",
        )
    console().print(t)


config_app = typer.Typer(help="Show configurations.", no_args_is_help=True, rich_markup_mode=None)


@config_app.command("show")
def config_show(
    preset: Annotated[
        str, typer.Option(help="Built-in preset: 'default', 'paper', 'pinhole' or 'physical'.")
    ] = "default",
    config: OfflineConfigOpt = None,
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


def register(app: typer.Typer) -> None:
    """Add the offline commands to the `ovis` app."""
    app.command()(simulate)
    app.command()(calibrate)
    app.command()(detect)
    app.command()(plan)
    app.add_typer(config_app, name="config")
