"""Pictures a person would rather look at than read: GA convergence, detections on a frame."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.atomic import write_atomic
from ovis.common.calibration.file import Calibration, dipe_text
from ovis.common.world.detection import Detection

__all__ = [
    "draw_detections",
    "plot_convergence",
    "plot_error_map",
    "plot_residuals",
    "save_png",
]

_ROBOT = (60, 200, 60)  # BGR
_OBSTACLE = (40, 140, 255)
_POINT = (255, 80, 220)


def save_png(path: Path | str, image: NDArray[np.uint8]) -> None:
    """Encode a frame as PNG and write it atomically."""
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise ValueError(f"could not encode an image of shape {image.shape} as PNG")
    write_atomic(path, buf.tobytes())


def plot_convergence(calibration: Calibration, path: Path | str) -> None:
    """Best, best-so-far and mean feasible DIPE per generation, with the feasible share."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    h = calibration.history
    gen = np.array([r.generation for r in h])
    best = np.array([r.best_px if r.best_px < 1e6 else np.nan for r in h])
    so_far = np.array([r.best_so_far_px if r.best_so_far_px < 1e6 else np.nan for r in h])
    mean = np.array([np.nan if r.mean_px is None else r.mean_px for r in h])
    feas = np.array([r.feasible_fraction for r in h])
    fig, (ax, ax2) = plt.subplots(
        2, 1, figsize=(7, 5.5), sharex=True, height_ratios=[3, 1], layout="constrained"
    )
    ax.plot(gen, mean, color="0.6", label="mean of feasible strings")
    ax.plot(gen, best, color="tab:blue", alpha=0.6, label="best of generation")
    ax.plot(gen, so_far, color="tab:red", lw=2, label="best so far")
    ax.axhline(
        0.735214 / calibration.camera.d_x_mm,
        ls="--",
        color="k",
        lw=1,
        label="paper's DIPE (0.735 mm)",
    )
    ax.set_yscale("log")
    ax.set_ylabel("DIPE (px, mean over control points)")
    ax.set_title(
        f"GA calibration: DIPE {dipe_text(calibration.dipe_px, calibration.dipe_mm)} "
        f"after {len(h) - 1} generations"
    )
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    ax2.plot(gen, 100 * feas, color="tab:green")
    ax2.set_ylabel("feasible %")
    ax2.set_xlabel("generation")
    ax2.set_ylim(0, 105)
    ax2.grid(True, alpha=0.3)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def draw_detections(
    frame: NDArray[np.uint8],
    detection: Detection,
    *,
    control_points: Sequence[tuple[float, float]] = (),
    scale: int | None = None,
) -> NDArray[np.uint8]:
    """The frame (BGR) with each object's outline circle, id, kind and world position, and
    the robot → obstacle lines with the planner's distance and angle."""
    img = frame if frame.ndim == 3 else cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    if scale is None:
        scale = max(1, int(np.ceil(640 / img.shape[1])))
    img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)

    def pt(row: float, col: float) -> tuple[int, int]:
        return round((col + 0.5) * scale - 0.5), round((row + 0.5) * scale - 0.5)

    by_id = {o.id: o for o in detection.objects}
    robot = next((o for o in detection.objects if o.kind == "robot"), None)
    font = cv2.FONT_HERSHEY_SIMPLEX
    for entry in detection.planner:
        o = by_id.get(entry.obstacle_id)
        if robot is None or o is None:
            continue
        a, b = pt(robot.row, robot.col), pt(o.row, o.col)
        cv2.line(img, a, b, (200, 200, 200), 1, cv2.LINE_AA)
        mid = ((a[0] + b[0]) // 2, (a[1] + b[1]) // 2)
        text = f"{entry.distance_cm:.1f}cm {entry.angle_deg:+.0f}deg"
        cv2.putText(img, text, mid, font, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
    for o in detection.objects:
        color = _ROBOT if o.kind == "robot" else _OBSTACLE
        centre = pt(o.row, o.col)
        radius_px = max(3, round(np.sqrt(o.area_px / np.pi) * scale))
        cv2.circle(img, centre, radius_px, color, 2, cv2.LINE_AA)
        cv2.drawMarker(img, centre, color, cv2.MARKER_CROSS, 8, 1)
        label = f"{'R' if o.kind == 'robot' else 'O'}{o.id} ({o.x_cm:.1f}, {o.y_cm:.1f})"
        cv2.putText(
            img, label, (centre[0] + radius_px + 2, centre[1]), font, 0.45, color, 1, cv2.LINE_AA
        )
    for row, col in control_points:
        cv2.drawMarker(img, pt(row, col), _POINT, cv2.MARKER_TILTED_CROSS, 10, 1)
    return img


def _nice_factor(x: float) -> float:
    """The largest of 1, 2, 5 × 10^k not above ``x`` (at least 1)."""
    if not np.isfinite(x) or x <= 1:
        return 1.0
    k = 10 ** np.floor(np.log10(x))
    return float(max(m * k for m in (1, 2, 5) if m * k <= x))


def plot_residuals(
    frame: NDArray[np.uint8],
    calibration: Calibration,
    path: Path | str,
    *,
    magnify: float | None = None,
) -> float:
    """Residual vectors on the calibration frame: for each control point an arrow from
    the detected blob centroid to where the camera projects the point, magnified; with
    a leave-one-out report in the calibration, a second arrow to where the camera
    refitted *without* that point projects it. Returns the magnification used (by
    default the 1-2-5 step that makes the longest arrow about 1/8 of the frame width).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    gray = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    rows, cols = gray.shape
    pts = calibration.points
    loo = calibration.accuracy.leave_one_out if calibration.accuracy is not None else None
    held = {p.name: p for p in loo.points} if loo is not None else {}
    lengths = [p.dipe_px for p in pts] + [p.error_px for p in held.values()]
    longest = max(lengths, default=0.0)
    if magnify is None:
        magnify = _nice_factor(cols / 8.0 / max(longest, 1e-9))
    fig, ax = plt.subplots(figsize=(8.5, 8.5 * rows / cols + 0.8), layout="constrained")
    ax.imshow(gray, cmap="gray", vmin=0, vmax=255, interpolation="nearest")

    def arrow(r0: float, c0: float, r1: float, c1: float, color: str, ls: str) -> None:
        end = (c0 + magnify * (c1 - c0), r0 + magnify * (r1 - r0))
        ax.annotate(
            "",
            xy=end,
            xytext=(c0, r0),
            arrowprops={"arrowstyle": "-|>", "color": color, "lw": 1.8, "ls": ls},
        )

    for p in pts:
        arrow(p.detected_row, p.detected_col, p.predicted_row, p.predicted_col, "red", "-")
        h = held.get(p.name)
        if h is not None:
            arrow(h.detected_row, h.detected_col, h.predicted_row, h.predicted_col, "orange", "--")
        ax.plot(p.detected_col, p.detected_row, "o", ms=6, mfc="none", mec="cyan", mew=1.5)
        text = f"{p.name}: {p.dipe_px:.2f} px"
        if h is not None:
            text += f"\nheld out {h.error_px:.2f} px"
            if h.error_cm is not None:
                text += f" = {h.error_cm:.2f} cm"
        ax.annotate(
            text,
            (p.detected_col, p.detected_row),
            xytext=(8, 10),
            textcoords="offset points",
            color="yellow",
            fontsize=8,
            bbox={"facecolor": "black", "alpha": 0.55, "pad": 1.5, "lw": 0},
        )
    ax.plot([], [], "o", mfc="none", mec="cyan", label="detected blob centroid")
    ax.plot([], [], color="red", label=f"→ projection of the point (× {magnify:g})")
    if held:
        ax.plot(
            [], [], color="orange", ls="--", label=f"→ projection, refit without it (× {magnify:g})"
        )
    ax.legend(loc="lower right", fontsize=8, framealpha=0.8)
    ax.set_xlim(-0.5, cols - 0.5)
    ax.set_ylim(rows - 0.5, -0.5)
    ax.set_xlabel("col")
    ax.set_ylabel("row")
    title = (
        f"Residuals of the control points, magnified {magnify:g}×: DIPE "
        f"{dipe_text(calibration.dipe_px, calibration.dipe_mm)}"
    )
    if loo is not None and loo.mean_px is not None:
        title += f"; leave-one-out {loo.mean_px:.3f} px"
    ax.set_title(title, fontsize=10)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return magnify


def plot_error_map(
    calibration: Calibration,
    true_camera,
    path: Path | str,
    *,
    z_cm: float | None = None,
    arena: tuple[tuple[float, float], tuple[float, float]] | None = None,
    step_px: int = 6,
) -> tuple[float, float]:
    """World-error map: where the calibrated camera puts each pixel on the floor versus
    where ``true_camera`` does, coloured in cm over the floor the camera sees (plane
    Z = ``z_cm``, default the obstacles' top-face height), with the control points and
    the ``arena`` rectangle ((x_lo, x_hi), (y_lo, y_hi)). Returns (mean, max) error in
    cm over the arena (over the whole view when no arena is given).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm, Normalize

    from ovis.common.calibration.accuracy import arena_world_error, floor_error_grid
    from ovis.common.camera.projection import back_project

    z = calibration.pose.obstacle_height_cm if z_cm is None else float(z_cm)
    X, Y, err = floor_error_grid(calibration.camera, true_camera, z_cm=z, step_px=step_px)
    if arena is not None:
        e = arena_world_error(calibration.camera, true_camera, arena[0], arena[1], z_cm=z)
    else:
        e = err[np.isfinite(err)]
    mean, worst = float(np.mean(e)), float(np.max(e))
    fig, ax = plt.subplots(figsize=(8, 7), layout="constrained")
    finite = err[np.isfinite(err)]
    lo = max(float(np.percentile(finite, 1)), 1e-4) if finite.size else 1e-3
    hi = max(float(finite.max()), 1e-3) if finite.size else 1.0
    # Linear from 0 unless the errors span more than a factor 30 (bad calibrations).
    norm = LogNorm(vmin=lo, vmax=hi) if hi > 30 * lo else Normalize(vmin=0.0, vmax=hi)
    # Cell corners: the pixel grid's edges back-projected by the true camera.
    n_r, n_c = err.shape
    r_e = np.minimum(np.arange(n_r + 1) * step_px, true_camera.rows) - 0.5
    c_e = np.minimum(np.arange(n_c + 1) * step_px, true_camera.cols) - 0.5
    edges = back_project(*np.meshgrid(r_e, c_e, indexing="ij"), true_camera, z)
    data = np.ma.masked_invalid(err)
    if edges.valid.all():
        mesh = ax.pcolormesh(edges.x_cm, edges.y_cm, data, shading="flat", norm=norm)
    else:  # part of the frame does not see the plane: plot the cell centres
        mesh = ax.scatter(X.ravel(), Y.ravel(), c=err.ravel(), s=6, norm=norm)
    fig.colorbar(mesh, ax=ax, label=f"floor error, cm (plane Z = {z:g} cm)")
    levels = [v for v in (0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0) if lo < v < hi]
    if levels and np.isfinite(X).all():
        cs = ax.contour(X, Y, err, levels=levels, colors="white", linewidths=0.8)
        ax.clabel(cs, fmt=lambda v: f"{v:g} cm", fontsize=7)
    if arena is not None:
        (x0, x1), (y0, y1) = arena
        ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color="red", lw=1.2, label="arena")
    if calibration.points:
        ax.plot(
            [p.x_cm for p in calibration.points],
            [p.y_cm for p in calibration.points],
            "w^",
            mec="k",
            ms=8,
            label="control points",
        )
        for p in calibration.points:
            ax.annotate(p.name, (p.x_cm, p.y_cm), xytext=(5, 5), textcoords="offset points",
                        color="white", fontsize=8)  # fmt: skip
    ax.set_aspect("equal")
    ax.set_xlabel("X, cm")
    ax.set_ylabel("Y, cm")
    where = "arena" if arena is not None else "view"
    ax.set_title(
        f"Floor error of the calibrated camera vs the true one: mean {mean:.3f} cm, "
        f"max {worst:.3f} cm over the {where}",
        fontsize=10,
    )
    ax.legend(loc="upper right", fontsize=8)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return mean, worst
