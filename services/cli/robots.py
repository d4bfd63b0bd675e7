"""Console tables of marked robots (``ovis detect`` with ``[[pose.robots]]``)."""

from __future__ import annotations

from typing import Any

__all__ = ["print_robots"]


def print_robots(det: Any, con: Any) -> None:
    """Each robot's pose, heading, velocity and age; its planner inputs; unknown markers."""
    from rich.table import Table

    from ovis.services.cli.ui import velocity_text

    t = Table(title="robots", title_justify="left")
    for col in ("id", "name", "marker", "X cm", "Y cm", "heading °", "v cm/s", "age s"):
        t.add_column(col, justify="right")
    for r in det.robots:
        t.add_row(
            str(r.id),
            r.name,
            str(r.marker_id),
            f"{r.x_cm:.2f}",
            f"{r.y_cm:.2f}",
            f"{r.heading_deg:.1f}",
            velocity_text(r),
            f"{r.age_s:.2f}",
        )
    con.print(t)
    for plan in det.robot_plans:
        p = Table(title=f"planner inputs of robot {plan.robot_id}", title_justify="left")
        for col in ("target", "kind", "distance cm", "angle to goal °", "angle to heading °"):
            p.add_column(col, justify="right")
        for e in plan.entries:
            goal = "-" if e.angle_deg is None else f"{e.angle_deg:.2f}"
            p.add_row(
                str(e.target_id),
                e.target_kind,
                f"{e.distance_cm:.2f}",
                goal,
                f"{e.heading_angle_deg:.2f}",
            )
        con.print(p)
    for u in det.unknown_markers:
        con.print(
            f"unknown marker {u.marker_id} at row {u.row:.0f}, col {u.col:.0f} "
            f"(X {u.x_cm:.1f}, Y {u.y_cm:.1f} cm): no robot in [[pose.robots]] carries it"
        )
    if det.markers_at_border:
        con.print(f"{det.markers_at_border} marker(s) cut by the image border: not used")
