"""Capture service: frames from the configured source, stamped with a sequence number,
the capture time and the stream's identity (random, new at each start), published on
``ovis/<arena>/frames`` (and, for the simulated arena, the ground truth on
``ovis/<arena>/truth``). A source that fails is retried."""

from __future__ import annotations

import secrets
import time

from ovis.common.capture.sources import FrameSource, SourceError, open_source
from ovis.common.messages import Frame, TruthFrame
from ovis.common.pipeline.pacing import Pacer
from ovis.services.replay import capture_from_recording, is_recording
from ovis.services.service import Service

RETRY_S = 2.0


def main(service: Service) -> None:
    cfg = service.config.service
    if is_recording(cfg.source):  # a session file: its frames bit-exact, recorded pace
        capture_from_recording(service)
        return
    publish_frame = service.publisher(service.topics.frames)
    publish_truth = service.publisher(service.topics.truth)
    pacer = Pacer(cfg.fps)
    source: FrameSource | None = None
    seq = 0
    stream = secrets.token_hex(8)  # sequence numbers start again with a new stream
    service.log.info("stream %s", stream)

    def prerendering(done: int, total: int) -> None:
        service.state = f"prerendering {done}/{total}"
        if done == total or done % max(1, total // 4) == 0:
            service.log.info("prerendered %d/%d frames", done, total)

    service.ready()
    try:
        while not service.stop.is_set():
            try:
                if source is None:
                    source = open_source(cfg.source, service.config, progress=prerendering)
                    service.log.info("capturing from %s", source.description)
                    service.state = "ok"
                image, truth = source.read()
            except SourceError as exc:
                again = "retrying" if source is None else "reopening"
                service.state = "source unavailable"
                service.error("source", f"{exc}; {again} in {RETRY_S:g} s")
                if source is not None:
                    source.close()
                    source = None
                service.stop.wait(RETRY_S)
                continue
            # a simulated camera on a shared trigger says when it exposed its frame
            stamp = truth.stamp_ns if truth is not None and truth.stamp_ns else time.time_ns()
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
            service.stop.wait(pacer.delay())
    finally:
        if source is not None:
            source.close()
