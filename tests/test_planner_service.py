"""The planner service as a real process on loopback Zenoh (issue 37, items 1 and 4):
obstacle frames signed by the pose stage in, one signed velocity command per robot
out; an unsigned or forged frame is not planned on; a stale frame, or a stream whose
health is not ok, makes it command a stop; with ``[navigation] cmd_vel`` each command
is also ROS 2's TwistStamped on ``/ovis/robots/robot_<id>/cmd_vel``, read here by a
CDR reader written from the format's rules (not ovis's nor rosbags')."""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path

import msgspec
import pytest
from cdr_helpers import read_twist_stamped
from zenoh_helpers import alive, client, free_port, ovis_cmd, spawn, stop, wait_for

from ovis.common.calibration.file import calibration_from_config
from ovis.common.config import dump_toml, load_config
from ovis.common.messages import (
    ObstacleFrame,
    RobotCommand,
    StreamHealth,
    Topics,
    decode,
    encode,
)
from ovis.common.ros2 import wire
from ovis.common.ros2.floor import ros_floor
from ovis.common.trust.keys import PublicKeyFile, load_or_create_private
from ovis.common.trust.proof import Signer, Verifier
from ovis.common.world.detection import DetectedObject
from ovis.common.world.robots import RobotState
from ovis.services.trust import attachment_of

GOAL = (130.0, 60.0)


def _config(endpoint: str, tmp: Path, cmd_vel: bool) -> Path:
    data = msgspec.to_builtins(load_config())
    data["zenoh"]["connect"] = [endpoint]
    data["service"]["state_dir"] = str(tmp / "state")
    data["pose"]["robots"] = [
        {"id": 1, "name": "r1", "marker_id": 0, "marker_side_cm": 7.0,
         "marker_height_cm": 5.0, "radius_cm": 9.0, "goal_cm": list(GOAL)}
    ]  # fmt: skip
    data["navigation"]["cmd_vel"] = cmd_vel
    path = tmp / "planner.toml"
    path.write_text(dump_toml(data))
    return path


def _frame(seq: int, stamp_ns: int, obstacle_x: float | None = None) -> ObstacleFrame:
    robot = RobotState(
        id=1, name="r1", marker_id=0, x_cm=20.0, y_cm=60.0, z_cm=5.0, heading_deg=0.0,
        vx_cm_s=0.0, vy_cm_s=0.0, yaw_rate_deg_s=0.0, age_s=0.0, radius_cm=9.0,
    )  # fmt: skip
    obstacles = []
    if obstacle_x is not None:
        obstacles.append(
            DetectedObject(
                7, "obstacle", 0.0, 0.0, 100.0, 40.0, 1.0, obstacle_x, 60.0, 7.0, 5.0, 78.5
            )
        )
    return ObstacleFrame(
        seq=seq, stamp_ns=stamp_ns, published_ns=stamp_ns, frame_age_ms=0.0,
        calibration_version=0, robot=None, obstacles=obstacles, planner=[], robots=[robot],
    )  # fmt: skip


@pytest.mark.parametrize("cmd_vel", [False, True])
def test_planner_service_commands_and_stops(tmp_path: Path, cmd_vel: bool) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cfg = _config(endpoint, tmp_path, cmd_vel)
    pose = Signer(load_or_create_private(tmp_path / "state" / "keys" / "pose.key"))
    forger = Signer(load_or_create_private(tmp_path / "forger.key"))
    procs = [spawn(ovis_cmd("router", "--listen", endpoint), tmp_path / "router.log")]
    procs.append(spawn(ovis_cmd("run", "planner", "--config", str(cfg)), tmp_path / "p.log"))
    topics = Topics("default")
    got: list[tuple[RobotCommand, str | None]] = []
    ros: list[tuple[str, bytes]] = []
    lock = threading.Lock()
    try:
        with client(endpoint) as session:
            wait_for(lambda: "planner" in alive(session), 60, "planner alive")
            verifier = Verifier(PublicKeyFile(tmp_path / "state" / "keys" / "planner.pub"))

            def on_cmd(sample) -> None:
                payload = sample.payload.to_bytes()
                problem = verifier.problem(str(sample.key_expr), payload, attachment_of(sample))
                with lock:
                    got.append((decode(payload, RobotCommand), problem))

            def on_ros(sample) -> None:
                with lock:
                    ros.append((str(sample.key_expr), sample.payload.to_bytes()))

            session.declare_subscriber(topics.commands_all, on_cmd)
            session.declare_subscriber("0/**", on_ros)
            obstacles = session.declare_publisher(topics.obstacles)
            health = session.declare_publisher(topics.health)

            def put(pub, message, signer: Signer | None = pose) -> None:
                payload = encode(message)
                attachment = signer.attachment(str(pub.key_expr), payload) if signer else None
                pub.put(payload, attachment=attachment)

            def commands() -> list[tuple[RobotCommand, str | None]]:
                with lock:
                    return list(got)

            time.sleep(0.5)
            # unsigned and forged frames: planned on never
            put(obstacles, _frame(0, time.time_ns()), signer=None)
            put(obstacles, _frame(1, time.time_ns()), signer=forger)
            time.sleep(1.0)
            assert commands() == []
            # a proven, fresh frame: a command towards the goal, signed by the planner
            put(obstacles, _frame(2, time.time_ns()))
            wait_for(lambda: len(commands()) >= 1, 10, "a command")
            first, problem = commands()[0]
            assert problem is None
            assert first.robot_id == 1 and first.stop == "" and first.v_cm_s > 0.0
            assert first.goal_cm == GOAL and first.planner == "fuzzy"
            # an obstacle right ahead: the fuzzy planner turns away and slows
            put(obstacles, _frame(3, time.time_ns(), obstacle_x=32.0))
            wait_for(lambda: len(commands()) >= 2, 10, "a second command")
            second = commands()[1][0]
            assert second.critical_id == 7 and second.distance_cm < 10.0
            assert second.v_cm_s < first.v_cm_s or second.omega_deg_s != 0.0
            # a frame 2 s old: stop
            put(obstacles, _frame(4, time.time_ns() - 2_000_000_000))
            wait_for(lambda: len(commands()) >= 3, 10, "a third command")
            stale = commands()[2][0]
            assert stale.v_cm_s == 0.0 and "old" in stale.stop
            # the stream's health says its source is lost: a stop at once, no frame needed
            put(health, StreamHealth(state="source lost", published_ns=time.time_ns(),
                                     reason="camera unplugged", stream="s", seq=1))  # fmt: skip
            wait_for(lambda: len(commands()) >= 4, 10, "a stop on health")
            cut = commands()[3][0]
            assert cut.v_cm_s == 0.0 and "source lost" in cut.stop
            # and frames then are not driven on either, until the health is ok again
            put(obstacles, _frame(5, time.time_ns()))
            wait_for(lambda: len(commands()) >= 5, 10, "a fifth command")
            assert "source lost" in commands()[4][0].stop
            put(health, StreamHealth(state="ok", published_ns=time.time_ns(), stream="s",
                                     seq=2))  # fmt: skip
            time.sleep(0.5)
            put(obstacles, _frame(6, time.time_ns()))
            wait_for(lambda: len(commands()) >= 6, 10, "a sixth command")
            assert commands()[5][0].stop == "" and commands()[5][0].v_cm_s > 0.0
            if cmd_vel:
                wait_for(lambda: len(ros) >= 6, 10, "six cmd_vel messages")
    finally:
        stop(procs[1:])
        stop(procs[:1])
    log = (tmp_path / "p.log").read_text()
    assert "Traceback" not in log, log
    assert all(problem is None for _, problem in got)
    if not cmd_vel:
        assert not [k for k, _ in ros if "cmd_vel" in k]
        return
    twists = [(k, d) for k, d in ros if "cmd_vel" in k]
    assert len(twists) == len(got)
    key = wire.parse_topic_key(twists[0][0])
    assert key.name == "/ovis/robots/robot_1/cmd_vel"
    assert key.type_name == "geometry_msgs/msg/TwistStamped"
    # the default camera (the paper's) images the floor mirrored: ROS's turn is ovis's
    # negated (ovis.common.ros2.floor)
    sign = ros_floor(calibration_from_config(load_config())).y_sign
    assert sign == -1.0
    for (cmd, _), (_, data) in zip(got, twists, strict=True):
        sec, nanosec, frame_id, (vx, vy, vz, wx, wy, wz) = read_twist_stamped(data)
        assert sec * 1_000_000_000 + nanosec == cmd.stamp_ns
        assert frame_id == "robot_1/base_link"
        assert vx == pytest.approx(cmd.v_cm_s / 100.0)
        assert wz == pytest.approx(sign * math.radians(cmd.omega_deg_s))
        assert vy == vz == wx == wy == 0.0
