"""Picture of where a lens calibration saw board corners, so a person sees uncovered areas."""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ovis.common.atomic import write_atomic
from ovis.common.calibration.intrinsics import IntrinsicsReport

__all__ = ["plot_coverage"]


def plot_coverage(
    path: Path | str,
    report: IntrinsicsReport,
    corners_xy: Sequence[NDArray[np.float32]],
    background: NDArray[np.uint8] | None = None,
) -> None:
    """Every used view's corners over the image (one colour per view), the grid cells no
    corner fell in shaded red, and the overall and per-view RMS in the title. PNG, atomic."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    w, h = report.image_width, report.image_height
    fig, ax = plt.subplots(figsize=(8, 8 * h / w + 0.8), layout="constrained")
    if background is not None:
        ax.imshow(background, cmap="gray", alpha=0.35, extent=(-0.5, w - 0.5, h - 0.5, -0.5))
    cmap = plt.get_cmap("tab20")
    for i, xy in enumerate(corners_xy):
        ax.plot(xy[:, 0], xy[:, 1], ".", ms=4, color=cmap(i % 20))
    cov = report.coverage
    cw, ch = w / cov.grid_cols, h / cov.grid_rows
    for r, row in enumerate(cov.covered):
        for c, seen in enumerate(row):
            if not seen:
                ax.add_patch(Rectangle((c * cw, r * ch), cw, ch, color="red", alpha=0.25, lw=0))
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.set_aspect("equal")
    ax.set_xlabel("column (px)")
    ax.set_ylabel("row (px)")
    worst = max(report.per_view, key=lambda v: v.rms_px)
    ax.set_title(
        f"{report.board}: {len(report.views_used)} views, RMS {report.rms_px:.3f} px "
        f"(worst view {worst.view} {worst.rms_px:.3f} px)\n"
        f"corners cover {cov.fraction:.0%} of the {cov.grid_cols}x{cov.grid_rows} grid, "
        f"{cov.image_corners_covered}/4 image corners (red: never seen)",
        fontsize=10,
    )
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    write_atomic(path, buf.getvalue())
