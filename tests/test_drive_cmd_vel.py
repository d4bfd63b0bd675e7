"""``ovis up --world physical --drive --follow cmd_vel``: the robot of the seed's
scenario driven in the physical world by the planner's ROS 2 ``TwistStamped`` on
``/ovis/robots/robot_<id>/cmd_vel`` (rmw_zenoh's key), not by ovis's signed commands;
a message on that key, read here by a CDR reader written from the format's rules,
is the command the robot reports it received; malformed and impossible ones on that key
are refused and counted, one over the robot's limit clamped (issue 37, item 3). What the
robots follow is checked before anything starts."""

from __future__ import annotations

import json
import math
import re
import threading
import time
from pathlib import Path

import msgspec
import pytest
from cdr_helpers import pack_twist_stamped, read_twist_stamped
from cli_helpers import assert_one_line_error, ovis
from physical_helpers import DriveReports, needs_physical
from pipeline_helpers import start_up
from zenoh_helpers import alive, client, wait_for

from ovis.common.calibration.file import calibration_from_config
from ovis.common.config import ConfigError, config_from_dict, load_config
from ovis.common.messages import RobotDrive, Topics
from ovis.common.ros2 import wire
from ovis.common.ros2.floor import ros_floor


@needs_physical
def test_robot_follows_the_planners_cmd_vel(tmp_path: Path) -> None:
    options = ("--world", "physical", "--drive", "--follow", "cmd_vel", "--pin", "none",
               "--duration", "30", "--seed", "3", "--max-restarts", "0")  # fmt: skip
    proc, endpoint, err = start_up(tmp_path, *options)
    twists: dict[int, tuple[str, str, tuple[float, ...]]] = {}  # stamp → key, frame, six
    lock = threading.Lock()
    try:
        with client(endpoint) as session:

            def on_twist(sample) -> None:
                sec, nanosec, frame_id, six = read_twist_stamped(sample.payload.to_bytes())
                with lock:
                    twists[sec * 1_000_000_000 + nanosec] = (str(sample.key_expr), frame_id, six)

            drives = DriveReports(session, Topics("default"))
            listening = session.declare_subscriber("0/ovis/robots/*/cmd_vel/**", on_twist)
            wait_for(lambda: "planner" in alive(session), 120, "the planner alive")
            wait_for(lambda: drives.followed() >= 25, 120, "25 cmd_vel commands followed")
            reports = drives.all()
            first, last = reports[0], reports[-1]
            listening.undeclare()
            with lock:
                heard = dict(twists)
            # on the robot's key: not CDR, a NaN turn, no rmw_zenoh attachment (refused);
            # 1 m/s (followed, clamped to the robot's top speed)
            key = next(iter(heard.values()))[0]
            sec, nanosec = divmod(time.time_ns(), 1_000_000_000)
            attachment = wire.encode_attachment(1, time.time_ns(), bytes(16))
            nan = pack_twist_stamped(sec, nanosec, "", (0.1, 0, 0, 0, 0, math.nan))
            fast = pack_twist_stamped(sec, nanosec, "", (1.0, 0, 0, 0, 0, 0))
            session.put(key, b"\x00\x01\x00\x00 not a twist", attachment=attachment)
            session.put(key, nan, attachment=attachment)
            session.put(key, fast)
            wait_for(lambda: drives.last.refused >= 3, 30, "three refused cmd_vel")
            session.put(key, fast, attachment=attachment)
            wait_for(lambda: drives.last.clamped >= 1, 30, "a clamped cmd_vel")
        logs = Path(re.search(r"logs in (\S+)", err.read_text()).group(1))
    finally:
        proc.terminate()
        out, _ = proc.communicate(timeout=120)
    assert last.follows == "cmd_vel" and last.refused == 0
    goal = last.goal_cm
    assert goal is not None

    def to_goal(r: RobotDrive) -> float:
        return math.hypot(goal[0] - r.x_cm, goal[1] - r.y_cm)

    assert to_goal(first) - to_goal(last) > 5.0, "the robot drove towards its goal"
    # the command the robot reports it received is a TwistStamped heard on the key
    assert last.command_stamp_ns in heard, "the robot's command came over cmd_vel"
    key, frame_id, (vx, vy, vz, wx, wy, wz) = heard[last.command_stamp_ns]
    assert frame_id == f"robot_{last.robot_id}/base_link"
    parsed = wire.parse_topic_key(key)
    assert parsed.name == f"/ovis/robots/robot_{last.robot_id}/cmd_vel"
    assert parsed.type_name == "geometry_msgs/msg/TwistStamped"
    cfg = load_config(logs / "config.toml")
    nav = cfg.navigation
    assert nav.follow == "cmd_vel" and nav.cmd_vel
    sign = ros_floor(calibration_from_config(cfg)).y_sign  # ROS's turn on ovis's floor
    v = min(max(vx * 100.0, -nav.max_speed_cm_s), nav.max_speed_cm_s)
    omega = min(max(sign * math.degrees(wz), -nav.max_yaw_rate_deg_s), nav.max_yaw_rate_deg_s)
    assert last.command_v_cm_s == pytest.approx(v, abs=1e-9)
    assert last.command_omega_deg_s == pytest.approx(omega, abs=1e-9)
    assert vy == vz == wx == wy == 0.0
    assert any(abs(x) > 1.0 for x in [r.command_v_cm_s or 0.0 for r in reports])
    summary = json.loads(out.decode())
    robot = summary["navigation"]["robots"][0]
    assert robot["follows"] == "cmd_vel" and robot["commands"] >= 25
    assert robot["refused"] == 3 and robot["clamped"] == 1
    assert "Traceback" not in err.read_text()


def test_what_the_robots_follow_is_checked_before_anything_starts() -> None:
    proc = ovis("up", "--world", "physical", "--drive", "--follow", "ros", check=False)
    assert_one_line_error(proc, "--follow 'ros'", "'cmd_vel'", code=2)
    data = msgspec.to_builtins(load_config())
    data["navigation"]["follow"] = "ros2"
    with pytest.raises(ConfigError, match="follow"):
        config_from_dict(data)
