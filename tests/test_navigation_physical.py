"""Robots driven in the physical world (MuJoCo): a differential-drive body follows its
commands within the limits and stops when they stop; a scenario's run is the same for
the same seed; the fast simulation the GA tunes on agrees with MuJoCo; ``ovis
navigate`` reports the issue's fields for ovis's detection and for the oracle (issue 37)."""

from __future__ import annotations

import json
import math

import msgspec
import pytest
from cli_helpers import assert_one_line_error, ovis
from physical_helpers import needs_physical, skip_module_without_physical

skip_module_without_physical()  # before MuJoCo is imported: without OpenGL its import fails

from ovis.common.config import load_config  # noqa: E402
from ovis.common.navigation.base import DriveCommand  # noqa: E402
from ovis.common.navigation.driving import Driving  # noqa: E402
from ovis.common.navigation.episode import run_episode  # noqa: E402
from ovis.common.navigation.fuzzy import FuzzyArrays, designer, tuned_default  # noqa: E402
from ovis.common.navigation.planners import make_planner  # noqa: E402
from ovis.common.navigation.scenarios import make_scenario  # noqa: E402
from ovis.common.navigation.study import navigate_config  # noqa: E402
from ovis.common.navigation.tuning import drive_with  # noqa: E402
from ovis.common.physical.rigs import rig  # noqa: E402
from ovis.common.physical.world import PhysicalWorld  # noqa: E402

pytestmark = needs_physical


def _config(case: int = 2):
    cfg = load_config(preset="physical")
    return navigate_config(cfg, rig("overhead", cfg), case=case, robots=1)


def _robot(world: PhysicalWorld, ident: int):
    return next(o for o in world.truth(0).objects if o.id == ident)


def test_robot_follows_commands_and_stops_when_they_stop() -> None:
    """Commands of 15 cm/s straight on at 10 Hz: after 1.5 s the MuJoCo robot rolls at
    that speed (±5 %) along its heading (±2°); the commands then stop and the robot's
    watchdog brings it to rest within 0.3 s of the last one; a turn command turns it
    counter-clockwise at about the commanded rate. (The robot alone on the floor.)"""
    cfg = _config()
    scenario = make_scenario(cfg, 11, [cfg.camera])
    task = scenario.tasks[0]
    alone = [s for s in scenario.scene.solids if s.kind == "robot"]
    scene = msgspec.structs.replace(scenario.scene, solids=alone)
    world = PhysicalWorld(scene, cfg, [cfg.camera], driven=True)
    try:
        world.set_time(0.0)
        drive = Driving(world, scenario.tasks, cfg.navigation)
        t = 0.0
        while t < 1.5 - 1e-9:
            drive.receive(task.id, DriveCommand(15.0, 0.0, t, t))
            t = round(t + 0.1, 3)
            drive.advance_to(t)
        me = _robot(world, task.id)
        speed = math.hypot(me.vx_cm_s, me.vy_cm_s)
        assert speed == pytest.approx(15.0, rel=0.05)
        along = math.degrees(math.atan2(me.vy_cm_s, me.vx_cm_s))
        assert abs(math.remainder(along - me.heading_deg, 360.0)) < 2.0
        assert abs(math.remainder(me.heading_deg - task.yaw_deg, 360.0)) < 2.0
        last = t - 0.1  # the last command's receipt
        drive.advance_to(last + 0.3)
        me = _robot(world, task.id)
        assert math.hypot(me.vx_cm_s, me.vy_cm_s) < 0.5
        assert drive.bases[task.id].stopped.startswith("no command for")
        yaw0 = me.heading_deg
        t = world.t_s
        for _ in range(10):
            drive.receive(task.id, DriveCommand(0.0, 90.0, t, t))
            t = round(t + 0.1, 3)
            drive.advance_to(t)
        turned = math.remainder(_robot(world, task.id).heading_deg - yaw0, 360.0)
        assert 60.0 < turned < 95.0  # 1 s at 90°/s, less the ramp up
    finally:
        world.close()


def test_oracle_run_is_deterministic_and_agrees_with_the_fast_simulation() -> None:
    """The same scenario, planner and seed give the same run, path for path; and the
    GA's fast simulation ends each of three scenarios the way MuJoCo does (goal or
    contact; at the goal at about the same time, ±10 %) for the designer's controller."""
    cfg = _config()
    seeds = (3, 4, 6)
    scenarios = [make_scenario(cfg, s, [cfg.camera]) for s in seeds]
    fast = drive_with(FuzzyArrays.of(designer()), scenarios, cfg.navigation, margin_cm=0.0)
    for k, scenario in enumerate(scenarios):
        runs = []
        for _ in range(2 if k == 0 else 1):
            planners = {t.id: make_planner("fuzzy", cfg, designer()) for t in scenario.tasks}
            runs.append(run_episode(scenario, cfg, planners, "oracle"))
        assert runs[0] == runs[-1]
        robot = runs[0].robots[0]
        assert robot.goal_reached == bool(fast.reached[0, k, 0]), seeds[k]
        assert (robot.collisions > 0) == bool(fast.contact[0, k, 0]), seeds[k]
        if robot.goal_reached:
            assert robot.time_s == pytest.approx(fast.time_s[0, k, 0], rel=0.1), seeds[k]


def test_tuned_planner_reaches_the_goal_on_what_ovis_sees() -> None:
    """One Case 2 scenario with the shipped tuned planner, fed ovis's detection of each
    rendered frame: the robot arrives with no contact, its marker seen in all but a few
    frames (≤ 2 %), its closest approach measured by MuJoCo."""
    cfg = _config()
    scenario = make_scenario(cfg, 21, [cfg.camera])
    planners = {t.id: make_planner("fuzzy", cfg, tuned_default()) for t in scenario.tasks}
    run = run_episode(scenario, cfg, planners, "ovis")
    robot = run.robots[0]
    assert robot.goal_reached and robot.collisions == 0
    assert robot.unseen_frames <= run.frames // 50
    assert 0.0 < robot.min_clearance_cm < 50.0
    assert run.frames == len(run.latency_ms) + robot.unseen_frames


def test_navigate_command_reports_both_feeds() -> None:
    """``ovis navigate --json`` on a Case 1 scenario: the issue's fields for ovis's
    feed and the oracle's; the straight driver collides there; bad input is one line."""
    out = ovis("navigate", "--case", "1", "--runs", "1", "--seed", "2", "--planner",
               "straight", "--json")  # fmt: skip
    summary = json.loads(out.stdout)
    fields = {"runs", "success_rate", "collisions", "timeouts", "time_ratio_p50",
              "min_clearance_cm", "frames_processed", "latency_ms_p50"}  # fmt: skip
    assert fields <= set(summary) and fields <= set(summary["oracle"])
    assert summary["runs"] == 1 and summary["frames_processed"] > 0
    assert summary["oracle"]["collisions"] == 1
    assert summary["oracle"]["min_clearance_cm"] <= 0.0
    assert 30.0 < summary["latency_ms_p50"] < 70.0
    bad = ovis("navigate", "--planner", "teleport", "--json", check=False)
    assert_one_line_error(bad, "--planner", code=2)


def test_tune_writes_a_planner_the_command_loads(tmp_path) -> None:
    """``ovis navigate --tune`` (a tiny GA, on one-robot and two-robot training
    scenarios): the tuned planner file loads and says how it was made, its cost is at
    least the straight line's (a time ratio from rest is above 1), the convergence plot
    is written, and ``ovis navigate`` drives with it."""
    out = tmp_path / "tuned.json"
    tune = ("navigate", "--tune", "--scenarios", "4", "--crossing-scenarios", "2",
            "--population", "8", "--generations", "2", "--out", str(out), "--json")  # fmt: skip
    info = json.loads(ovis(*tune).stdout)
    from ovis.common.navigation.fuzzy import load_fuzzy

    params = load_fuzzy(out)
    assert params.origin.startswith("ovis navigate --tune: case 2, 4 training scenarios")
    assert "2 more of 2 robots (seeds 1000000…1000001)" in params.origin
    assert (tmp_path / "tuned.png").stat().st_size > 10_000
    assert info["cost"] > 1.0 and info["designer_cost"] > 1.0
    assert info["training_seeds"] == [1_000_000, 1_000_003]
    assert info["crossing_scenarios"] == 2
    drive = ("navigate", "--case", "2", "--runs", "1", "--seed", "7", "--feed", "oracle",
             "--planner-file", str(out), "--json")  # fmt: skip
    run = json.loads(ovis(*drive).stdout)
    assert run["runs"] == 1 and run["oracle"] is None and run["frames_processed"] > 0
