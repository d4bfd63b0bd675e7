"""The arena from above: the objects of an obstacle message as plain records, and the
floor area the camera sees (its footprint), both in world cm.

The view forwards obstacle messages as they were decoded (a mapping), so that fields
added later (e.g. a list of ``robots`` with ids, names and headings) reach the page
without a change here; :func:`scene_objects` reads what it knows with ``.get``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import msgspec
import numpy as np

from ovis.common.camera.projection import back_project
from ovis.common.config import CameraModel

__all__ = ["SceneObject", "camera_footprint", "object_label", "scene_objects"]


class SceneObject(msgspec.Struct, kw_only=True):
    """One object to draw: world position (cm), radius, heading, and where the camera
    saw it (row, col; None when the message does not say)."""

    id: int
    kind: str
    x_cm: float
    y_cm: float
    z_cm: float = 0.0
    radius_cm: float = 0.0
    heading_deg: float | None = None
    row: float | None = None
    col: float | None = None
    name: str = ""


def object_label(obj: SceneObject) -> str:
    """How the page names an object: "R4" (a robot; "R4 alpha" with a name) or "O3"."""
    if obj.kind == "robot":
        return f"R{obj.id} {obj.name}" if obj.name else f"R{obj.id}"
    return f"O{obj.id}"


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def _object(item: Any, default_kind: str) -> SceneObject | None:
    if not isinstance(item, Mapping):
        return None
    x, y = _number(item.get("x_cm")), _number(item.get("y_cm"))
    ident = item.get("id", 0)
    if x is None or y is None or not isinstance(ident, int):
        return None
    return SceneObject(
        id=ident,
        kind=str(item.get("kind", default_kind)),
        x_cm=x,
        y_cm=y,
        z_cm=_number(item.get("z_cm")) or 0.0,
        radius_cm=max(0.0, _number(item.get("radius_cm")) or 0.0),
        heading_deg=_number(item.get("heading_deg")),
        row=_number(item.get("row")),
        col=_number(item.get("col")),
        name=str(item.get("name", "")),
    )


def scene_objects(message: Mapping[str, Any]) -> list[SceneObject]:
    """The robots and obstacles of an obstacle message (a decoded mapping): the marked
    ``robots`` when the list has any, else its single ``robot`` (the paper's unmarked
    one); then ``obstacles``. Entries without finite ``x_cm``/``y_cm`` are skipped."""
    robots = message.get("robots")
    if not isinstance(robots, list) or not robots:
        robot = message.get("robot")
        robots = [robot] if robot is not None else []
    obstacles = message.get("obstacles")
    items = [(r, "robot") for r in robots] + [
        (o, "obstacle") for o in (obstacles if isinstance(obstacles, list) else [])
    ]
    return [obj for obj in (_object(item, kind) for item, kind in items) if obj is not None]


def camera_footprint(
    cam: CameraModel, z_cm: float = 0.0, per_side: int = 16
) -> list[tuple[float, float]]:
    """The polygon (world cm, in order around the image) where the camera sees the plane
    Z = ``z_cm``: the image border, ``per_side`` points a side (lens distortion bends
    the sides), back-projected onto the plane. Border pixels that do not see the plane
    (above the horizon) are left out."""
    if per_side < 2:
        raise ValueError(f"per_side must be at least 2, got {per_side}")
    last_r, last_c = cam.rows - 0.5, cam.cols - 0.5
    t = np.linspace(0.0, 1.0, per_side, endpoint=False)
    rows = np.concatenate(
        [np.full_like(t, -0.5), -0.5 + t * cam.rows, np.full_like(t, last_r), last_r - t * cam.rows]
    )
    cols = np.concatenate(
        [-0.5 + t * cam.cols, np.full_like(t, last_c), last_c - t * cam.cols, np.full_like(t, -0.5)]
    )
    b = back_project(rows, cols, cam, z_cm)
    valid = np.asarray(b.valid, bool)
    return list(
        zip(np.asarray(b.x_cm)[valid].tolist(), np.asarray(b.y_cm)[valid].tolist(), strict=True)
    )
