"""Pose service: blobs → robot and obstacles on the floor, identities across frames,
velocities and the motion planner's inputs (paper §5.2); publishes one
:class:`ObstacleFrame` per frame on the obstacle topic ``ovis/<arena>/obstacles``."""

from __future__ import annotations

import time

import numpy as np

from ovis.common.detection import Blobs, Detector
from ovis.common.messages import BlobList, ObstacleFrame
from ovis.services.runtime import Service

FIELDS = Blobs._fields


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
        columns = {
            f: np.array([getattr(b, f) for b in msg.blobs], dtype=np.float64) for f in FIELDS
        }
        det = detector.from_blobs(Blobs(**columns), stamp_s=msg.stamp_ns / 1e9)
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
            )
        )
        service.sent()
        service.state = "ok"

    service.consume(service.topics.blobs, handle)
    service.stop.wait()
