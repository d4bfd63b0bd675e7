"""Marked robots through the running services: `ovis router` and the capture, preprocess,
label and pose stages as real `ovis run` processes on loopback Zenoh, the simulated
arena with 4 marked robots and 6 obstacles, scored against the published ground truth."""

from __future__ import annotations

import math
from pathlib import Path

import msgspec
from pipeline_helpers import running_pipeline
from zenoh_helpers import wait_for

from ovis.common.config import dump_toml, load_config
from ovis.common.sim.scenes import marked_scene
from ovis.common.world.planner import wrap_deg

STAGES = ("capture", "preprocess", "label", "pose")


def test_robots_travel_the_bus_with_identity_heading_and_planner(tmp_path: Path) -> None:
    data = msgspec.to_builtins(marked_scene(load_config(), 4, 6))
    data["service"].update(fps=15.0, auto_calibrate=False, state_dir=str(tmp_path / "state"))

    def config_text(endpoint: str) -> str:
        return dump_toml({**data, "zenoh": {"connect": [endpoint]}})

    with running_pipeline(tmp_path, config_text=config_text, stages=STAGES) as p:
        rec = p.rec
        wait_for(lambda: rec.count() >= 40, 60, "40 obstacle messages")
        msgs = [m for m in rec.since(10) if m.seq in rec.truth]
    assert len(msgs) >= 20
    for m in msgs:
        truth = {o.id: o for o in rec.truth[m.seq].objects if o.kind == "robot"}
        assert [r.id for r in m.robots] == [1, 2, 3, 4]
        for r in m.robots:
            o = truth[r.id]
            assert math.hypot(r.x_cm - o.x_cm, r.y_cm - o.y_cm) < 0.5
            assert abs(wrap_deg(r.heading_deg - o.heading_deg)) < 3.0
            assert r.marker_id == o.marker_id and r.age_s == 0.0
        for ob in m.obstacles:  # no robot's blob among the obstacles
            assert all(math.hypot(ob.x_cm - o.x_cm, ob.y_cm - o.y_cm) > 9.0 for o in truth.values())
        assert len(m.obstacles) == 6
        assert [p.robot_id for p in m.robot_plans] == [1, 2, 3, 4]
        assert all(len(p.entries) == 6 + 3 for p in m.robot_plans)
        assert m.robot is not None and m.robot.id == 1  # the legacy field: the first robot
        assert m.unknown_markers == [] and m.markers_at_border == 0
