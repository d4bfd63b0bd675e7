"""How a calibration, its accuracy report and a frame's detections are printed (rich
tables): `ovis calibrate`, `ovis detect`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ovis.services.cli.ui import console, table, velocity_text

__all__ = ["print_accuracy", "print_calibration", "print_detection"]


def print_calibration(calib, out: Path, plot: Path | None) -> None:
    con = console()
    cam = calib.camera
    t = table("calibrated parameters", ("parameter", "value"), left={"parameter"})
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
    rows += _parameter_rows(cam)
    for name, value in rows:
        t.add_row(name, value)
    con.print(t)
    _print_residuals(calib, out, plot)


def _print_residuals(calib, out: Path, plot: Path | None) -> None:
    con = console()
    columns = ("point", "X,Y,Z cm", "detected row,col", "predicted row,col", "px", "mm")
    p = table("DIPE per control point (eq. 14)", columns)
    for r in calib.points:
        p.add_row(
            r.name,
            f"{r.x_cm:g}, {r.y_cm:g}, {r.z_cm:g}",
            f"{r.detected_row:.2f}, {r.detected_col:.2f}",
            f"{r.predicted_row:.2f}, {r.predicted_col:.2f}",
            f"{r.dipe_px:.3f}",
            "-" if r.dipe_mm is None else f"{r.dipe_mm:.4f}",
        )
    con.print(p)
    from ovis.common.calibration.file import dipe_text

    paper = " (paper: 0.735214 mm)" if calib.dipe_mm is not None else " (mm: pixel pitch unknown)"
    con.print(
        f"DIPE mean {dipe_text(calib.dipe_px, calib.dipe_mm)}, max "
        f"{dipe_text(calib.dipe_max_px, calib.dipe_max_mm)}{paper}; {calib.evaluations} "
        f"evaluations in {calib.elapsed_s:.2f} s"
    )
    print_accuracy(calib, con)
    con.print(f"wrote {out}" + (f" and {plot}" if plot else ""))


#: (label, field, format) of each camera model's parameters (pinhole: OpenCV's x is the
#: column, y the row).
_PARAMETERS = {
    "paper": (
        ("Z0", "Z0_cm", "{:.3f} cm"),
        ("λ", "lam_mm", "{:.4f} mm"),
        *((k, k, "{:.3e}") for k in ("k1", "k2", "k3")),
        *((s, s, "{:.5f}") for s in ("s_x", "s_y")),
    ),
    "pinhole": (
        ("fx (columns)", "fx", "{:.3f} px"),
        ("fy (rows)", "fy", "{:.3f} px"),
        ("cx (column)", "cx", "{:.3f} px"),
        ("cy (row)", "cy", "{:.3f} px"),
        *((k, k, "{:.5g}") for k in ("k1", "k2", "p1", "p2", "k3")),
    ),
}


def _parameter_rows(cam) -> list[tuple[str, str]]:
    """The camera's parameters as (name, value) rows."""
    rows = [(label, fmt.format(getattr(cam, f))) for label, f, fmt in _PARAMETERS[cam.model]]
    if cam.model == "pinhole":
        rows.append(("rvec", ", ".join(f"{v:.5f}" for v in cam.rvec) + " rad"))
        rows.append(("tvec", ", ".join(f"{v:.3f}" for v in cam.tvec_cm) + " cm"))
    return rows


_SHORT = {"Z0_cm": "Z0 cm", "lam_mm": "λ mm"}


def _num(v: float) -> str:
    """Two significant digits, never in e-notation (0.00007, 1300)."""
    if not np.isfinite(v):
        return str(v)
    return np.format_float_positional(v, precision=2, fractional=False, trim="-")


def print_accuracy(calib, con=None) -> None:
    """Print a calibration's accuracy report (if it has one)."""
    from ovis.common.calibration.file import dipe_text

    rep = calib.accuracy
    if rep is None:
        return
    con = con or console()
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
        t = table(
            f"held-out error: {held.method} ({held.source})",
            ("point", "X,Y,Z cm", "error px", "error cm", "in-sample px"),
        )
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
        columns = ("param.", "value", "range moves", "std. error", "of range", "restarts", "fixed")
        t = table("what the control points determine", columns, left={"fixed"})
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


def _unmarked_motion(robot) -> str:
    """The unmarked robot's heading (and whether it is its front) and velocity."""
    if robot.heading_deg is None:
        heading = "none (a round blob)"
    elif robot.heading_resolved:
        heading = f"{robot.heading_deg:.1f} deg (its front, from its motion)"
    else:
        heading = f"{robot.heading_deg:.1f} deg (either end: it has not moved yet)"
    if not robot.velocity_measured:
        return f"heading {heading}, velocity – (not measured yet)"
    return f"heading {heading}, velocity {velocity_text(robot)} cm/s"


def _height_text(o) -> str:
    """An object's height and where it comes from."""
    if o.z_source == "one camera" and o.z_sigma_cm is not None:
        return f"{o.z_cm:.2f}±{o.z_sigma_cm:.2f}"
    why = {
        "declared": "declared",
        "not measurable": "cfg: not measurable",
        "pending": "cfg: pending",
    }
    return f"{o.z_cm:.2f} {why.get(o.z_unmeasured, 'marker' if o.z_source == 'marker' else 'cfg')}"


def print_detection(path: Path, det, heights: str = "configured") -> None:
    con = console()
    columns = ("id", "kind", "row", "col", "area px", "perim px", "compact.")
    world = ("X cm", "Y cm", "Z cm", "r cm", "v cm/s")
    t = table(f"{path}: {len(det.objects)} object(s)", (*columns, *world))
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
            _height_text(o),
            f"{o.radius_cm:.2f}",
            velocity_text(o),
        )
    con.print(t)
    if heights == "measured":
        con.print(
            "X, Y: where each object stands (its footprint's centre); Z: its top's height, "
            "measured ± 1σ, or configured (cfg) where it is declared, not measurable here "
            "or still to be fitted"
        )
    else:
        con.print(
            "X, Y: each blob's centroid carried onto its class's top plane at Z (configured "
            "heights: right for objects that tall)"
        )
    robot = next((o for o in det.objects if o.kind == "robot"), None)
    if robot is not None and not det.robots:  # the unmarked robot
        con.print(f"robot {robot.id}: {_unmarked_motion(robot)}")
    if det.robots or det.unknown_markers:
        from ovis.services.cli.robots import print_robots

        print_robots(det, con)
    if det.planner:
        p = table("motion planner inputs", ("obstacle", "distance cm", "angle deg"))
        for e in det.planner:
            p.add_row(str(e.obstacle_id), f"{e.distance_cm:.3f}", f"{e.angle_deg:.3f}")
        con.print(p)
    elif not any(o.kind == "robot" for o in det.objects):
        con.print("no robot found: no planner inputs (check pose.robot_* in the calibration)")
