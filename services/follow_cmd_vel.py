"""The physical world's robots following ROS 2's ``cmd_vel`` (``[navigation] follow =
"cmd_vel"``) instead of ovis's signed commands: each robot's
``geometry_msgs/msg/TwistStamped`` on ``<[ros2] namespace>/robots/robot_<id>/cmd_vel``
over rmw_zenoh (the key's type and type hash checked, the message decoded, mapped to
ovis's units and floor, within the robot's limits: :func:`ovis.common.ros2.cmd_vel.read_cmd_vel`),
heard on the ROS 2 side's router (``[ros2] connect``) or else ovis's bus, as a ROS 2
node (``<[ros2] node>_world``) with a subscription per configured robot.

A ROS 2 message carries no proof of origin: whatever may put on that key drives the
robot (docs/navigation.md, "Trust"). What is not followed is counted (``refused``
in the robot's reports, ``refused_cmd_vel`` in the capture's status) and said; the
robot's firmware keeps its watchdog and its frame-age rule on the header's stamp."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator

import msgspec
import zenoh

from ovis.common.ros2 import wire
from ovis.common.ros2.cdr import type_hash
from ovis.common.ros2.cmd_vel import (
    TWIST_STAMPED,
    CmdVelError,
    TwistCommand,
    cmd_vel_robot,
    cmd_vel_topic,
    read_cmd_vel,
)
from ovis.common.ros2.floor import ros_floor
from ovis.common.ros2.topics import STREAM
from ovis.services.ros2 import ros_session
from ovis.services.ros2_node import RosNode
from ovis.services.service import Service
from ovis.services.trust import attachment_of

__all__ = ["follow_cmd_vel"]


@contextlib.contextmanager
def follow_cmd_vel(
    service: Service,
    follow: Callable[[int, TwistCommand], None],
    refuse: Callable[[str], None],
) -> Iterator[None]:
    """Hand each robot's ``cmd_vel`` that may be followed to ``follow(robot_id,
    command)``, and why any other may not to ``refuse``, until the context ends."""
    cfg = service.config
    ros, nav = cfg.ros2, cfg.navigation
    mirrored = ros_floor(service.calibration).mirrored
    hash_ = type_hash(TWIST_STAMPED)
    robots = wire.qualified_name(ros.namespace, "robots")
    pattern = f"{ros.domain_id}/{robots[1:]}/*/cmd_vel/*/*"

    def on_sample(sample: zenoh.Sample) -> None:
        try:
            key = wire.parse_topic_key(str(sample.key_expr))
            if (key.type_name, key.type_hash) != (TWIST_STAMPED, hash_):
                raise CmdVelError(f"a {key.type_name} ({key.type_hash}) is not a {TWIST_STAMPED}")
            robot_id = cmd_vel_robot(key.name, ros.namespace)
            if robot_id is None:
                raise CmdVelError(f"{key.name} is no robot's cmd_vel")
            wire.decode_attachment(attachment_of(sample) or b"")  # rmw_zenoh's, always sent
            payload = service.take(sample.payload, "small", "cmd_vel")
            if payload is None:
                return refuse("larger than a cmd_vel can be")
            command = read_cmd_vel(
                payload, robot_id, now_ns=time.time_ns(), mirrored=mirrored,
                max_speed_cm_s=nav.max_speed_cm_s, max_yaw_rate_deg_s=nav.max_yaw_rate_deg_s,
                max_frame_age_s=nav.max_frame_age_s,
            )  # fmt: skip
        except (wire.WireError, CmdVelError) as exc:
            return refuse(f"{sample.key_expr}: {exc}")
        follow(robot_id, command)

    with ros_session(service) as session:
        node_cfg = msgspec.structs.replace(ros, node=f"{ros.node}_world")
        node = RosNode(session, node_cfg)
        try:
            for robot in cfg.pose.robots:
                name = wire.qualified_name(ros.namespace, cmd_vel_topic(robot.id))
                node.subscription_token(name, TWIST_STAMPED, STREAM)
            subscriber = session.declare_subscriber(pattern, on_sample)
            service.log.info("robots follow ROS 2 cmd_vel on %s (no proof of origin)", pattern)
            yield
            subscriber.undeclare()
        finally:
            node.close()
