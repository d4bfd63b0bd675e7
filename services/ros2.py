"""The ROS 2 bridge (``ovis up --ros2``, ``ovis run ros2``): ovis's own topics, as they
are published, turned into standard ROS 2 messages by a paced
:class:`~ovis.common.ros2.stream.RosStream` (what the benchmark row ``ros2`` measures)
and published as a ROS 2 node over rmw_zenoh (:mod:`ovis.services.ros2_node`), on
ovis's bus or on the ROS 2 side's router (``[ros2] connect``).

Each obstacle frame gives the obstacle poses and each robot's odometry, stamped with
the frame's capture time, and the RViz markers ``markers_rate_hz`` times a second; a
camera frame, ``image_rate_hz`` times a second by capture stamps (the others' images
are not decoded), gives the JPEG image with the camera's model. A calibration, as soon as it
is adopted, gives the camera's model and the floor → camera transform (kept for late
subscribers) and the floor mapping of the frames after it (built once per
calibration)."""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterable, Iterator

import zenoh

from ovis.common.calibration.file import Calibration
from ovis.common.config import ZenohConfig
from ovis.common.messages import Frame, FrameHeader, ObstacleFrame
from ovis.common.ros2.convert import RosMessage
from ovis.common.ros2.stream import RosStream
from ovis.common.ros2.topics import qos_of
from ovis.common.ros2.wire import WireError
from ovis.services.bus import zenoh_config
from ovis.services.ros2_node import RosNode
from ovis.services.service import Service

#: Seconds between checks that the ROS 2 side's router is there.
ROUTER_CHECK_S = 2.0


@contextlib.contextmanager
def ros_session(service: Service) -> Iterator[zenoh.Session]:
    """The node's own session, as a ROS 2 context has one: a peer of the ROS 2 router
    (``[ros2] connect``, as rmw_zenoh's sessions are), else joined as the service is;
    with timestamping on, which the publication caches of transient local topics need
    (rmw_zenoh's sessions have it too)."""
    connect = service.config.ros2.connect
    zc = ZenohConfig(mode="peer", connect=connect) if connect else service.config.zenoh
    conf = zenoh_config(zc)
    conf.insert_json5("timestamping/enabled", "true")
    session = zenoh.open(conf)
    try:
        yield session
    finally:
        session.close()


def main(service: Service) -> None:
    with ros_session(service) as session:
        node = RosNode(session, service.config.ros2)
        try:
            bridge(service, node)
        finally:
            node.close()


def bridge(service: Service, node: RosNode) -> None:
    stream = RosStream(service.config.ros2)
    lock = threading.Lock()
    router = RouterWatch(service, node.session)

    def send(messages: Iterable[RosMessage]) -> None:
        for message in messages:
            try:
                with lock:
                    node.publish(message, qos_of(message.topic))
            except WireError as exc:  # a name ROS 2 refuses: said, counted, the rest goes on
                service.error("ros2_name", f"not published on ROS 2: {exc}")

    def calibrated() -> bool:
        return service.calibration.version > 0 or service.config.starts_with_configured_camera

    def on_calibration(calib: Calibration) -> None:
        send(stream.calibration(calib, time.time_ns()))

    service.follow_calibration(on_calibration)
    if calibrated():
        on_calibration(service.calibration)
    box = service.inbox(
        service.topics.obstacles, service.config.service.queue_depth + 2, proven_by="pose"
    )

    def on_frame(sample: zenoh.Sample) -> None:
        payload = service.take(sample.payload, "frame", "frame")
        header = None if payload is None else service.decode(payload, FrameHeader, "frame")
        if header is not None and stream.image_due(header.stamp_ns):
            box.put((payload, time.time_ns()))

    if stream.images.hz != 0.0:  # no image nor camera info on ROS 2: frames not read
        service.session.declare_subscriber(service.topics.frames, on_frame)

    def handle(payload: bytes, _receipt_ns: int) -> None:
        msg = service.decode(payload, ObstacleFrame | Frame, "input")
        if isinstance(msg, ObstacleFrame):
            service.saw_frame(msg.seq, msg.stamp_ns, msg.stream)
            waiting = stream.waiting
            messages = stream.obstacles(msg)
            if stream.waiting > waiting:
                why = "no calibration yet (its floor's handedness is unknown)"
                service.error("no_calibration", f"obstacle frame {msg.seq} not on ROS 2: {why}")
                return
            send(messages)
        elif isinstance(msg, Frame):
            send(stream.image(msg))
        else:
            return
        service.sent()
        service.state = router.state()

    threading.Thread(target=router.run, name="ros2-router", daemon=True).start()
    service.serve(box, handle)


class RouterWatch:
    """Whether the ROS 2 side's router (``[ros2] connect``) is connected: its absence is
    counted (``ros2_router``) and is the service's state, not "ok"."""

    def __init__(self, service: Service, session: zenoh.Session) -> None:
        self.service = service
        self.session = session
        self.connect = service.config.ros2.connect
        self.missing = False

    def state(self) -> str:
        if self.missing:
            return f"no ROS 2 router answers at {', '.join(self.connect)}"
        return "ok"

    def run(self) -> None:
        if not self.connect:
            return
        while not self.service.stop.wait(ROUTER_CHECK_S):
            try:
                self.missing = not list(self.session.info.routers_zid())
            except zenoh.ZError:  # the session is closing
                return
            if self.missing:
                self.service.state = self.state()
                self.service.error("ros2_router", self.state() + " (is rmw_zenohd running?)")
