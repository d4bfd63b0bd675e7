"""Pose service: blobs → robot and obstacles on the floor, identities across frames,
velocities and the motion planner's inputs (paper §5.2); publishes one
:class:`ObstacleFrame` per frame on the obstacle topic ``ovis/<arena>/obstacles``."""

from __future__ import annotations

import threading
import time

from ovis.common.messages import BlobList, MarkerCorners, ObstacleFrame, StreamHealth
from ovis.common.world.detection import Detector
from ovis.services.runtime import Service


def main(service: Service) -> None:
    calib = service.calibration
    detector = Detector(calib.camera, calib.image, calib.pose)

    service.follow_calibration(lambda c: detector.recalibrate(c.camera, c.image, c.pose))
    publish = service.publisher(service.topics.obstacles)

    def handle(payload: bytes, _receipt_ns: int) -> None:
        msg = service.decode(payload, BlobList, "blobs")
        if msg is None:
            return
        service.saw_frame(msg.seq, msg.stamp_ns)
        floor = top = None
        if msg.maps is not None and msg.calibration_version == service.calibration.version:
            floor, top = msg.maps.obstacle.jacobian(), msg.maps.robot.jacobian()
        markers = MarkerCorners.to_markers(msg.markers, msg.markers_at_border)
        det = detector.from_blobs(
            msg.to_blobs(), floor=floor, top=top, stamp_s=msg.stamp_ns / 1e9, markers=markers
        )
        now = time.time_ns()
        robot = next((o for o in det.objects if o.kind == "robot"), None)
        publish(
            ObstacleFrame(
                seq=msg.seq,
                stamp_ns=msg.stamp_ns,
                published_ns=now,
                frame_age_ms=(now - msg.stamp_ns) / 1e6,
                calibration_version=service.calibration.version,
                robot=robot,
                obstacles=[o for o in det.objects if o.kind == "obstacle"],
                planner=det.planner,
                arena=service.topics.arena,
                robots=det.robots,
                robot_plans=det.robot_plans,
                unknown_markers=det.unknown_markers,
                markers_at_border=det.markers_at_border,
            )
        )
        service.sent()
        service.last_latency_ms = (now - msg.stamp_ns) / 1e6

    inbox = service.inbox(service.topics.blobs)
    threading.Thread(target=service.serve, args=(inbox, handle), daemon=True).start()
    publish_health = service.publisher(service.topics.health, drop=False)
    period = service.config.service.status_period_s
    timeout = service.config.service.frame_timeout_s
    last_state = "waiting"
    while not service.stop.wait(period):
        st = service.status()
        since = (
            None
            if service.last_receipt_ns is None
            else ((time.time_ns() - service.last_receipt_ns) / 1e9)
        )
        state = "waiting" if since is None else "ok" if since <= timeout else "stalled"
        if state != last_state:
            log = service.log.warning if state == "stalled" else service.log.info
            log("frames %s (last seq %s, %.1f s ago)", state, service.last_seq, since or 0.0)
            service.state = {"ok": "ok", "stalled": "no frames", "waiting": "waiting"}[state]
            last_state = state
        publish_health(
            StreamHealth(
                state=state,
                published_ns=time.time_ns(),
                last_seq=-1 if service.last_seq is None else service.last_seq,
                seconds_since_frame=since,
                last_frame_age_ms=service.last_latency_ms,
                frames_dropped=st.dropped,
                calibration_version=service.calibration.version,
            )
        )
