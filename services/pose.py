"""Pose service: blobs → robot and obstacles on the floor, identities across frames,
velocities and the motion planner's inputs (paper §5.2); publishes one
:class:`ObstacleFrame` per frame on the obstacle topic ``ovis/<arena>/obstacles``, and
the stream's health on ``ovis/<arena>/health`` every status period, and at once when the
capture says its source was lost or is back (``ovis/<arena>/source``)."""

from __future__ import annotations

import threading
import time

# The matcher (tracks to blobs) and the edge model of measured heights load with the
# process, not on the frame that first needs them (a stall there makes the stage skip
# frames); the modules that use them load them lazily for the processes that never do.
import scipy.optimize
import scipy.spatial
import scipy.special  # noqa: F401
import zenoh

from ovis.common.calibration.file import Calibration
from ovis.common.messages import BlobList, SourceState
from ovis.common.pipeline.health import SERVICE_STATE, SourceWatch, StreamWatch
from ovis.common.pipeline.stages import obstacle_frame
from ovis.common.world.detection import Detector
from ovis.services.service import Service
from ovis.services.trust import signer_for


def main(service: Service) -> None:
    calib = service.calibration
    # measured heights: the solids are fitted beside the frames, none waits for a fit
    detector = Detector(calib.camera, calib.image, calib.pose, background_fits=True)
    detector.robots.prepare(calib.camera)  # the marker planes' tables, before any frame
    detector.prepare()

    def recalibrate(c: Calibration) -> None:
        detector.robots.prepare(c.camera)  # the new tables first: no frame waits for them
        detector.recalibrate(c.camera, c.image, c.pose)
        detector.prepare()

    service.follow_calibration(recalibrate)
    signer = signer_for(service.config, "pose")  # consumers believe what this key signed
    publish = service.publisher(service.topics.obstacles, signer=signer)

    def handle(payload: bytes, _receipt_ns: int) -> None:
        msg = service.decode(payload, BlobList, "blobs")
        if msg is None:
            return
        service.saw_frame(msg.seq, msg.stamp_ns, msg.stream)
        version = service.calibration.version
        out = obstacle_frame(msg, detector, version, service.topics.arena, time.time_ns())
        service.last_latency_ms = out.frame_age_ms
        service.publish_result(publish, out)  # the state is "ok" from the first frame on

    inbox = service.inbox(service.topics.blobs)
    threading.Thread(target=service.serve, args=(inbox, handle), daemon=True).start()
    publish_health = service.publisher(service.topics.health, drop=False, signer=signer)
    watch = StreamWatch(service.config.service.frame_timeout_s)
    source = SourceWatch()
    news = threading.Event()  # the source was lost or is back: publish the health now

    def on_source(sample: zenoh.Sample) -> None:
        msg = service.receive(sample.payload, "small", SourceState, "source")
        if msg is not None and source.hear(msg, time.monotonic()):
            news.set()

    service.session.declare_subscriber(service.topics.source, on_source)
    threading.Thread(target=lambda: (service.stop.wait(), news.set()), daemon=True).start()
    counters = service.counters
    said: str | None = None  # the verdict last logged
    while not service.stop.is_set():
        news.wait(service.config.service.status_period_s)
        news.clear()
        if service.stop.is_set():
            break
        status = service.status()
        dropped = status.dropped
        since = counters.seconds_since_frame()
        if watch.update(since, source.lost(time.monotonic())):
            log = service.log.info if watch.state in ("ok", "waiting") else service.log.warning
            if watch.state == "source lost":
                log("source lost: %s", watch.reason)
            else:
                log(
                    "frames %s (last seq %s, %.1f s ago)",
                    watch.state,
                    counters.last_seq,
                    since or 0.0,
                )
            service.state = SERVICE_STATE[watch.state]
        if status.state != said and status.state in ("degraded", "failing", "ok"):
            if said is not None or status.state != "ok":  # a change of the verdict
                log = service.log.info if status.state == "ok" else service.log.warning
                log("%s%s", status.state, f": {status.reason}" if status.reason else "")
            said = status.state
        publish_health(
            watch.message(
                last_seq=counters.last_seq,
                seconds_since_frame=since,
                last_frame_age_ms=service.last_latency_ms,
                frames_dropped=dropped,
                calibration_version=service.calibration.version,
                verdict=(status.state, status.reason),
            )
        )
