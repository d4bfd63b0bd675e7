"""How the lone unmarked robot is turned each frame (:func:`robot_turn`)."""

from __future__ import annotations

import math

from ovis.common.solids.footprint import PoseMap
from ovis.common.world.robot_turn import robot_turn


def _map(slope: float) -> PoseMap:
    """A pose map whose silhouette's axis turns ``slope`` times as fast as the yaw."""
    return PoseMap((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), ((1, 0, 0), (0, 1, 0), (0, 0, slope)))


def test_the_robot_is_turned_by_its_axis_only_where_that_tells_its_yaw_and_nearby() -> None:
    """Its axis turns its yaw where the silhouette's axis turns with it at least 0.75°
    a degree, within what a 3° turn does since its last turn to its outline (however far
    it drove: the map moves it); else a
    blob that moved or turned is turned to its outline (a first frame: always), one
    that stood still is kept; at 30 frames/s, turning slowly, every other such turn is
    carried on at its last rate instead; at 5 frames/s never."""
    at = (10.0, 100.0, 200.0)  # axis (deg), row, col at its last turn to its outline
    fast, slow, rate = 1 / 30, 1 / 5, math.radians(0.5)
    assert robot_turn(None, at, at, fast, rate, False) == "outline"
    assert robot_turn(_map(1.0), at, (12.9, 101.0, 200.0), fast, rate, False) == "axis"
    assert robot_turn(_map(2.0), at, (15.9, 100.0, 200.0), fast, rate, False) == "axis"
    assert robot_turn(_map(1.0), at, (10.0, 104.0, 200.0), slow, rate, False) == "axis"  # moved
    turned = (13.1, 100.0, 200.0)  # too far for the map
    assert robot_turn(_map(1.0), at, turned, fast, rate, False) == "coast"
    assert robot_turn(_map(1.0), at, turned, fast, rate, True) == "outline"
    assert robot_turn(_map(1.0), at, turned, slow, rate, False) == "outline"
    assert robot_turn(_map(1.0), at, turned, fast, math.radians(2.0), False) == "outline"
    weak = _map(0.5)  # its axis tells its yaw poorly
    assert robot_turn(weak, at, (10.2, 100.1, 200.0), fast, rate, False) == "keep"
    assert robot_turn(weak, at, (10.3, 100.0, 200.0), slow, rate, False) == "outline"
    assert robot_turn(weak, at, (10.0, 100.0, 200.3), slow, rate, False) == "outline"
    assert robot_turn(weak, at, (math.nan, 100.0, 200.0), slow, rate, False) == "outline"
    assert robot_turn(weak, at, (10.3, 100.0, 200.0), fast, math.nan, False) == "outline"
