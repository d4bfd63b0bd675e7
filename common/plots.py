"""Pictures a person would rather look at than read: GA convergence, detections on a frame."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.atomic import write_atomic
from ovis.common.calibration_file import Calibration
from ovis.common.detection import Detection

__all__ = ["draw_detections", "plot_convergence", "save_png"]

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
        f"GA calibration: DIPE {calibration.dipe_px:.3f} px = {calibration.dipe_mm:.4f} mm "
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
