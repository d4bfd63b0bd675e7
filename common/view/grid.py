"""The grid and scale of the arena map: lines every ``step_cm`` (1, 2 or 5 times a power
of ten), chosen from the area the map shows so that a few lines cross it, each labelled
with its distance, and a scale bar one step long."""

from __future__ import annotations

import math
from collections.abc import Iterable

__all__ = ["MAX_LINES", "grid_step_cm", "map_grid_step"]

#: Grid lines across the map's longer side, at most.
MAX_LINES = 10
_NICE = (1.0, 2.0, 5.0)


def grid_step_cm(extent_cm: float, max_lines: int = MAX_LINES) -> float:
    """The smallest step of 1, 2 or 5 × 10^k cm that puts at most ``max_lines`` lines
    across ``extent_cm`` (ValueError for an extent that is not a positive number)."""
    if not math.isfinite(extent_cm) or extent_cm <= 0:
        raise ValueError(f"the map's extent must be a positive number of cm, got {extent_cm}")
    if max_lines < 1:
        raise ValueError(f"max_lines must be at least 1, got {max_lines}")
    raw = extent_cm / max_lines
    power = 10.0 ** math.floor(math.log10(raw))
    for nice in (*_NICE, 10.0):
        step = nice * power
        if step >= raw * (1 - 1e-12):
            return step
    return 10.0 * power  # not reached: 10 × power ≥ raw by construction


def map_grid_step(points: Iterable[tuple[float, float]], margin_cm: float = 10.0) -> float | None:
    """The grid step for a map showing ``points`` (world cm) with ``margin_cm`` around
    them; None when there is nothing to show (no calibration: no centimetres)."""
    pts = [(x, y) for x, y in points if math.isfinite(x) and math.isfinite(y)]
    if not pts:
        return None
    xs, ys = [p[0] for p in pts], [p[1] for p in pts]
    extent = max(max(xs) - min(xs), max(ys) - min(ys)) + 2 * margin_cm
    return grid_step_cm(extent)
