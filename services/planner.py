"""Planner service (``ovis run planner``, started by ``ovis up --drive``): on every
obstacle frame the pose stage proved (``ovis/<arena>/obstacles``), one velocity command
per robot with a goal (:mod:`ovis.common.navigation.live`) on
``ovis/<arena>/robots/<id>/cmd``, signed with the "planner" role's key (the robots
follow nothing else); and with ``[navigation] cmd_vel`` the same command as ROS 2's
``TwistStamped`` on ``/ovis/robots/robot_<id>/cmd_vel`` (:mod:`ovis.common.ros2.cmd_vel`),
for a real robot base. The stream's health (``ovis/<arena>/health``, proven too) that
is not ok sends every robot a stop at once, not at the next frame."""

from __future__ import annotations

import contextlib
import secrets
import threading
import time
from collections.abc import Callable, Iterator

from ovis.common.messages import ObstacleFrame, RobotCommand, StreamHealth
from ovis.common.navigation.fuzzy import load_fuzzy, tuned_default
from ovis.common.navigation.live import LivePlanner, Order
from ovis.common.navigation.planners import BRAKE
from ovis.services.service import Service
from ovis.services.trust import signer_for

__all__ = ["main"]


def _fuzzy(service: Service):
    path = service.config.navigation.planner_file
    return load_fuzzy(path) if path else tuned_default()


@contextlib.contextmanager
def _cmd_vel(service: Service) -> Iterator[Callable[[Order, int], None] | None]:
    """A publisher of the orders as ROS 2 ``cmd_vel`` (None when not wanted)."""
    if not service.config.navigation.cmd_vel:
        yield None
        return
    from ovis.common.ros2.cmd_vel import cmd_vel_message
    from ovis.common.ros2.floor import ros_floor
    from ovis.common.ros2.topics import qos_of
    from ovis.services.ros2 import ros_session
    from ovis.services.ros2_node import RosNode

    with ros_session(service) as session:
        node = RosNode(session, service.config.ros2)
        mirrored = ros_floor(service.calibration).mirrored
        try:

            def send(order: Order, stamp_ns: int) -> None:
                c = order.command
                message = cmd_vel_message(
                    order.robot_id, c.v_cm_s, c.omega_deg_s, stamp_ns, mirrored=mirrored
                )
                node.publish(message, qos_of(message.topic))

            yield send
        finally:
            node.close()


def main(service: Service) -> None:
    cfg = service.config
    live = LivePlanner(cfg, cfg.navigation.planner, _fuzzy(service))
    if not live.goals:
        raise SystemExit("planner: no robot has a goal ([pose] goal_cm or [[pose.robots]] goal_cm)")
    signer = signer_for(cfg, "planner")
    publishers = {
        i: service.publisher(service.topics.command(i), drop=False, signer=signer)
        for i in live.goals
    }
    stream = secrets.token_hex(8)
    seq = 0
    last_stamp = [0]
    with _cmd_vel(service) as ros:

        def send(orders: list[Order], stamp_ns: int) -> None:
            nonlocal seq
            for order in orders:
                c = order.command
                publishers[order.robot_id](
                    RobotCommand(
                        robot_id=order.robot_id,
                        seq=seq,
                        stream=stream,
                        stamp_ns=stamp_ns,
                        published_ns=time.time_ns(),
                        v_cm_s=c.v_cm_s,
                        omega_deg_s=c.omega_deg_s,
                        stop=order.stop,
                        planner=cfg.navigation.planner,
                        arena=service.topics.arena,
                        goal_cm=order.goal_cm,
                        arrived=c.arrived,
                        critical_id=c.critical_id,
                        distance_cm=c.distance_cm,
                        angle_deg=c.angle_deg,
                        deviation_deg=c.deviation_deg,
                    )
                )
                seq += 1
                if ros is not None:
                    ros(order, stamp_ns)
            service.sent()

        def on_health(payload: bytes, _receipt_ns: int) -> None:
            msg = service.decode(payload, StreamHealth, "health")
            if msg is None:
                return
            live.on_health(msg.state, msg.reason)
            if msg.state not in ("ok", "waiting"):  # stop them now, not at the next frame
                now = time.time_ns()
                send(live.plan([], [], last_stamp[0] / 1e9, now / 1e9), last_stamp[0] or now)
                service.state = f"robots stopped: stream {msg.state}"

        health = service.inbox(service.topics.health, depth=4, proven_by="pose")

        def handle(payload: bytes, _receipt_ns: int) -> None:
            msg = service.decode(payload, ObstacleFrame, "obstacles")
            if msg is None:
                return
            service.saw_frame(msg.seq, msg.stamp_ns, msg.stream)
            last_stamp[0] = msg.stamp_ns
            now = time.time_ns()
            orders = live.plan(msg.robots, msg.obstacles, msg.stamp_ns / 1e9, now / 1e9)
            send(orders, msg.stamp_ns)
            service.last_latency_ms = (now - msg.stamp_ns) / 1e6
            stops = {o.stop for o in orders if o.stop and o.stop != BRAKE}  # a brake: driving
            service.state = "; ".join(sorted(stops)) if stops else "ok"

        def health_loop() -> None:
            while not service.stop.is_set():
                item = health.get(timeout=0.2)
                if item is None:
                    continue
                try:
                    on_health(*item)
                except Exception as exc:  # counted and said; the next one may do
                    service.error("processing", f"health: {type(exc).__name__}: {exc}")

        threading.Thread(target=health_loop, daemon=True).start()
        inbox = service.inbox(service.topics.obstacles, proven_by="pose")
        service.serve(inbox, handle)
