"""Capture service: frames from the configured source, stamped with a sequence number,
the capture time and the stream's identity (random, new at each start), published on
``ovis/<arena>/frames`` (and, for the simulated arena, the ground truth on
``ovis/<arena>/truth``).

A source that fails is reopened after waits that grow while it stays away
(:mod:`ovis.common.capture.backoff`); a folder or video that ended with looping off is
lost for good. Each loss is recorded (:mod:`ovis.common.pipeline.gaps`), said at once
and then every ``SOURCE_REPEAT_S`` on ``ovis/<arena>/source`` (the pose stage folds it
into the stream's health), and shown in the status: state "source lost", the reason,
the losses so far."""

from __future__ import annotations

import secrets
import threading
import time

import msgspec
import zenoh

from ovis.common.capture.backoff import Backoff
from ovis.common.capture.sources import FrameSource, SourceEndedError, SourceError
from ovis.common.messages import Frame, ServiceStatus, TruthFrame
from ovis.common.pipeline.gaps import SourceGaps
from ovis.common.pipeline.health import SOURCE_REPEAT_S
from ovis.common.pipeline.pacing import Pacer
from ovis.services.replay import capture_from_recording, is_recording
from ovis.services.ros2_source import open_source
from ovis.services.service import Service


def announce_source(service: Service, gaps: SourceGaps, changed: threading.Event) -> None:
    """Publish the source's state on ``ovis/<arena>/source`` when ``changed`` is set,
    and every ``SOURCE_REPEAT_S`` while the source is lost, until the service stops."""
    publish = service.publisher(service.topics.source, drop=False)
    while not service.stop.is_set():
        changed.wait(SOURCE_REPEAT_S)
        if not (changed.is_set() or gaps.lost):
            continue
        changed.clear()
        try:
            publish(gaps.message(time.time_ns()))
        except zenoh.ZError:  # the session is closing
            return


def main(service: Service) -> None:
    cfg = service.config.service
    gaps, backoff, changed = SourceGaps(), Backoff(), threading.Event()
    # frames a source on its own clock missed (their instant passed while it was busy
    # rendering the one before: the physical world) count as dropped here
    missed = [0, None]  # [missed by sources closed before, the source now]

    def amend_status(status: ServiceStatus) -> ServiceStatus:
        now = missed[0] + getattr(missed[1], "missed", 0)
        status = msgspec.structs.replace(status, dropped=status.dropped + now)
        return gaps.amend(status, time.time_ns())

    service.amend_status = amend_status
    threading.Thread(
        target=announce_source, args=(service, gaps, changed), name="source", daemon=True
    ).start()

    def prerendering(done: int, total: int) -> None:
        service.state = f"prerendering {done}/{total}"
        if done == total or done % max(1, total // 4) == 0:
            service.log.info("prerendered %d/%d frames", done, total)

    def lost(exc: SourceError, then: str) -> None:
        if gaps.lose(str(exc), time.time_ns(), ended=isinstance(exc, SourceEndedError)):
            service.log.warning("source lost: %s", exc)
        changed.set()
        service.error("source", f"{exc}; {then}")

    if is_recording(cfg.source):  # a session file: its frames bit-exact, recorded pace
        capture_from_recording(service, lambda why: lost(SourceEndedError(why), "lost for good"))
        return
    publish_frame = service.publisher(service.topics.frames)
    publish_truth = service.publisher(service.topics.truth)
    pacer = Pacer(cfg.fps)
    source: FrameSource | None = None
    seq = 0
    stream = secrets.token_hex(8)  # sequence numbers start again with a new stream
    service.log.info("stream %s", stream)

    service.ready()
    try:
        while not service.stop.is_set():
            try:
                if source is None:
                    source = open_source(cfg.source, service.config, progress=prerendering)
                    missed[1] = source
                    service.log.info("capturing from %s", source.description)
                    service.state = "ok"
                image, truth = source.read()
            except SourceEndedError as exc:  # nothing more will come: idle until stopped
                lost(exc, "lost for good")
                service.stop.wait()
                break
            except SourceError as exc:
                wait = backoff.next_wait()
                lost(exc, f"next attempt in {wait:g} s")
                if source is not None:
                    missed[0] += getattr(source, "missed", 0)
                    missed[1] = None
                    source.close()
                    source = None
                service.stop.wait(wait)
                continue
            backoff.reset()
            # a simulated camera on a shared trigger says when it exposed its frame
            stamp = truth.stamp_ns if truth is not None and truth.stamp_ns else time.time_ns()
            stamp = getattr(source, "capture_ns", None) or stamp  # a ROS 2 camera's own
            frame = Frame.from_image(
                image,
                seq=seq,
                stamp_ns=stamp,
                source=source.description,
                copy=False,
                stream=stream,
            )
            publish_frame(frame)  # first: the truth is for checking, not on the frame's path
            if truth is not None:
                publish_truth(TruthFrame(seq=seq, objects=truth.objects, stamp_ns=stamp))
            service.saw_frame(seq, stamp, stream)
            service.sent()
            seq += 1
            back = gaps.delivered(time.time_ns())
            if back is not None:
                changed.set()
                service.log.info("source back after %.1f s (lost: %s)", back.seconds, back.reason)
            # a source on its own clock (the physical world) waits for its frames itself
            service.stop.wait(0.0 if getattr(source, "self_paced", False) else pacer.delay())
    finally:
        if source is not None:
            source.close()
