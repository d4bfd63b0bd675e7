"""`ovis demo`: the whole method on the simulated arena, scored against ground truth."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

__all__ = ["demo"]


def demo(
    out: Annotated[
        Path, typer.Option(help="Folder for the calibration, plots and overlays.")
    ] = Path("ovis-demo"),
    frames: Annotated[int, typer.Option(min=1, max=10000, help="Frames to detect on.")] = 30,
    seed: Annotated[int, typer.Option(min=0, help="Arena seed.")] = 0,
    preset: Annotated[str, typer.Option(help="'default' (640x480) or 'paper' (192x192).")] = (
        "default"
    ),
    config: Annotated[
        Path | None, typer.Option("--config", "-c", help="TOML configuration.", dir_okay=False)
    ] = None,
) -> None:
    """Simulate an arena, calibrate on its first frame, then track robot and obstacles.

    The first frame's objects are the control points (as in the paper: four objects of
    known position). The GA calibrates the camera on it; then every later frame is
    processed with that calibration and compared with the simulator's ground truth.
    Writes calib.json, convergence.png and overlay.png (last frame) to --out.
    """
    from rich.console import Console
    from rich.table import Table

    from ovis.common.analysis.evaluation import match_objects
    from ovis.common.analysis.plots import draw_detections, plot_convergence, save_png
    from ovis.common.calibration.file import dipe_text, save_calibration
    from ovis.common.sim.arena import Arena, control_points
    from ovis.common.world.detection import Detector
    from ovis.services.cli.offline import calibrate_with_progress, resolve_config

    con = Console(highlight=False)
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
    pos_err, rad_err, times = [], [], []
    missed = spurious = wrong_kind = id_switches = 0
    id_of: dict[int, int] = {}
    last = None
    for _ in range(frames):
        arena.step()
        frame, truth = arena.render()
        t0 = time.perf_counter()
        det = detector.detect(frame)
        times.append(time.perf_counter() - t0)
        acc = match_objects(det.objects, truth.objects)
        pos_err.extend(acc.position_error_cm)
        rad_err.extend(acc.radius_error_cm)
        missed += acc.missed
        spurious += acc.spurious
        wrong_kind += int((~acc.kind_correct).sum())
        for ti, di in zip(acc.truth_index, acc.detection_index, strict=True):
            true_id, det_id = truth.objects[ti].id, det.objects[di].id
            if id_of.setdefault(true_id, det_id) != det_id:
                id_switches += 1
                id_of[true_id] = det_id
        last = (frame, det)
    if last is not None:
        save_png(out / "overlay.png", draw_detections(*last))
        robot = next((o for o in last[1].objects if o.kind == "robot"), None)
        if robot is not None and last[1].planner:
            con.print(
                f"   last frame: robot at ({robot.x_cm:.1f}, {robot.y_cm:.1f}) cm; "
                + "; ".join(
                    f"O{e.obstacle_id}: {e.distance_cm:.1f} cm, {e.angle_deg:+.1f}°"
                    for e in last[1].planner
                )
            )
    pe, re = np.asarray(pos_err), np.asarray(rad_err)
    n_true = frames * len(points)
    t = Table(title="accuracy against ground truth", title_justify="left")
    t.add_column("measure")
    t.add_column("value", justify="right")
    t.add_row("objects found", f"{pe.size} of {n_true} ({missed} missed, {spurious} spurious)")
    if pe.size:
        t.add_row("position error mean / max", f"{pe.mean():.3f} / {pe.max():.3f} cm")
        t.add_row("radius error mean / max |.|", f"{re.mean():+.3f} / {np.abs(re).max():.3f} cm")
    t.add_row("robot/obstacle mislabelled", str(wrong_kind))
    t.add_row("identity switches", str(id_switches))
    ms = 1000 * np.asarray(times)
    t.add_row("detection time p50 / p99", f"{np.median(ms):.2f} / {np.percentile(ms, 99):.2f} ms")
    con.print(t)
    con.print(f"wrote {out / 'calib.json'}, {out / 'convergence.png'}, {out / 'overlay.png'}")
