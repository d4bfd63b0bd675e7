"""How the unmarked robot, alone in its blob, is turned each frame (it turns as it
drives; its shape and height are known from its fit).

Turning it to its outline (a Gauss–Newton follow of its silhouette onto the blob's pixel
chain) is exact but costs most of a frame's tracking. Its blob's axis in the frame (the
blob's second moments, measured anyway) tells its yaw too, through a linear map of how
the silhouette's image centroid and axis move with its centre and yaw
(:class:`~ovis.common.solids.footprint.PoseMap`), where that axis turns with the yaw
strongly enough and not far from where the robot was last turned to its outline (the
map is linear that far; the axis's offset from the silhouette's is noted there). Between
such turns, while frames come fast, it may turn on at its last rate for a frame."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from ovis.common.solids.footprint import PoseMap

__all__ = [
    "AXIS_CHECK_DEG",
    "AXIS_REACH_DEG",
    "AXIS_SLOPE",
    "AXIS_SLOPE_LEAST",
    "COAST_MAX_S",
    "COAST_TURN_DEG",
    "STILL_PX",
    "TURN_CHECK_DEG",
    "Turn",
    "TurnState",
    "degrees_between",
    "robot_turn",
]

#: The robot's yaw comes from its blob's axis in the frame while that axis stays within
#: what a turn of this much (deg) turns it from where it was when the robot was last
#: turned to its outline, and while the silhouette's axis turns with the yaw at least
#: this much and at most this much (deg per deg: elsewhere the axis tells the yaw
#: poorly) …
AXIS_REACH_DEG = 3.0
AXIS_SLOPE = (0.75, 5.0)
#: … and puts its yaw within this (deg) of where its last turn rate does (else the blob's
#: axis was thrown by something else: it is turned to its outline).
AXIS_CHECK_DEG = 1.0
#: … else it is turned to its outline again when its blob moved this far (px) or its axis
#: turned since it last was as far as a turn of this much (deg) would turn it (the axis
#: taken to turn at least this much with the yaw).
STILL_PX = 0.25
TURN_CHECK_DEG = 0.5
AXIS_SLOPE_LEAST = 0.1
#: Where frames are at most this far apart (s) and it turned at most this much (deg) a
#: frame when last turned to its outline, every other such turn is left out: it turns
#: on at that rate (over so short a time a robot's turn rate holds).
COAST_MAX_S = 0.05
COAST_TURN_DEG = 1.0

Turn = Literal["axis", "coast", "outline", "keep"]


@dataclass
class TurnState:
    """What the unmarked robot's turns keep from frame to frame: its blob's axis in the
    frame (deg) and centroid (row, col) when it was last turned to its outline, the
    silhouette's axis less the blob's then (rad), whether its last frame turned it on
    at its turn rate instead of to its outline, and its pose map (None: none yet)."""

    turned_at: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    axis_bias: float = math.nan
    coasted: bool = False
    pose_map: PoseMap | None = None


def degrees_between(a: float, b: float) -> float:
    """How far (deg) axis ``b`` is turned from axis ``a`` (axes: modulo 180°; NaN where
    either is)."""
    return (b - a + 90.0) % 180.0 - 90.0


def robot_turn(
    pose_map: PoseMap | None,
    turned_at: tuple[float, float, float],
    blob: tuple[float, float, float],
    dt_s: float,
    yaw_rate: float,
    coasted: bool,
) -> Turn:
    """How the robot's yaw is found this frame, from its pose map (None: none yet), its
    blob's axis (deg) and centroid (row, col) when it was last turned to its outline
    (``turned_at``) and now (``blob``; the axis NaN: not known), the time since the
    last frame, its last turn rate (rad a frame, NaN: not known) and whether the last
    frame turned it on at that rate:

    - "axis": from its blob's axis by its pose map (:data:`AXIS_SLOPE`,
      :data:`AXIS_REACH_DEG`);
    - else, where its blob moved or its axis turned (:data:`STILL_PX`,
      :data:`TURN_CHECK_DEG`): "coast", on at its last turn rate, every other frame
      while frames come fast and it turns slowly (:data:`COAST_MAX_S`,
      :data:`COAST_TURN_DEG`), or "outline", turned to its outline;
    - else "keep"."""
    if pose_map is None:
        return "outline"
    slope = pose_map.slope
    turned = abs(degrees_between(turned_at[0], blob[0]))  # NaN: not known
    if turned <= AXIS_REACH_DEG * slope and AXIS_SLOPE[0] <= slope <= AXIS_SLOPE[1]:
        return "axis"
    moved = math.hypot(blob[1] - turned_at[1], blob[2] - turned_at[2])
    if turned <= TURN_CHECK_DEG * max(slope, AXIS_SLOPE_LEAST) and moved <= STILL_PX:
        return "keep"
    slow = abs(yaw_rate) <= math.radians(COAST_TURN_DEG)  # NaN: not known
    return "coast" if not coasted and dt_s <= COAST_MAX_S and slow else "outline"
