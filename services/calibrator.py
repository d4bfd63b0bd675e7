"""Calibration worker: a Zenoh queryable on ``ovis/<arena>/calibrate``.

A query runs the GA (paper §4) on the latest frame, or on the frame named in the query,
with the configured control points (a points file, or for the simulated arena the
frame's ground truth, which the capture sends just after the frame: the latest frame
that has it, and a named frame's is waited for up to ``TRUTH_WAIT_S``); the result is
saved atomically as a new version, published on ``ovis/<arena>/calibration`` (the other
services switch to it without restarting) and returned in the reply.
``ovis/<arena>/calibration`` is also a queryable returning the current calibration, so
late starters pick it up.
"""

from __future__ import annotations

from collections.abc import Callable

import msgspec
import zenoh

from ovis.common.calibration.problem import InfeasibleCalibrationError, calibrate
from ovis.common.calibration.store import CalibrationStore
from ovis.common.calibration.validity import calibration_problem
from ovis.common.config import ControlPoint, load_points
from ovis.common.messages import (
    ENCODING,
    CalibrateReply,
    CalibrateRequest,
    CalibrationUpdate,
    Frame,
    FrameHeader,
    TruthFrame,
    encode,
)
from ovis.common.pipeline.following import label
from ovis.common.pipeline.recalibration import (
    FrameKeeper,
    calibrate_reply,
    config_for_request,
    points_for,
)
from ovis.common.vision.preprocess import ImageError
from ovis.services.inbox import Inbox
from ovis.services.service import Service

INITIAL_RETRY_S = 2.0


def initial_calibration(
    service: Service,
    keeper: FrameKeeper,
    run_calibration: Callable[[CalibrateRequest], CalibrateReply],
) -> None:
    """Calibrate on the newest usable frame once frames flow, retrying every
    ``INITIAL_RETRY_S`` until it works (a scene may be infeasible for a while); queries
    are served only after."""
    service.log.info("no saved calibration: calibrating on the first usable frame")
    while not service.stop.is_set():
        if not keeper.first_frame.wait(0.2):
            continue
        reply = run_calibration(CalibrateRequest())
        if reply.ok:
            return
        service.log.warning("initial calibration failed: %s; retrying", reply.error)
        service.stop.wait(INITIAL_RETRY_S)


def main(service: Service) -> None:
    cfg = service.config
    store = CalibrationStore(cfg.service.state_dir)
    saved, problems = store.latest()
    for problem in problems:
        service.error("bad_saved_calibration", f"skipped {problem}")
    epoch = store.epoch()
    if saved is not None and service.refused(
        "bad_saved_calibration", calibration_problem(saved, cfg)
    ):
        saved = None
    if saved is not None:
        service.calibration = msgspec.structs.replace(saved, epoch=saved.epoch or epoch)
        service.log.info("loaded calibration %s from %s", label(service.calibration), store.folder)
    file_points: list[ControlPoint] | None = None
    if cfg.service.points != "simulator":
        file_points = load_points(cfg.service.points).points
    keeper = FrameKeeper(needs_truth=file_points is None)

    def on_frame(sample: zenoh.Sample) -> None:
        # Only the header is decoded here (cheap); the image when a calibration needs it.
        payload = sample.payload.to_bytes()
        header = service.decode(payload, FrameHeader, "frame")
        if header is not None:
            service.saw_frame(header.seq, header.stamp_ns)
            keeper.add_frame(header.seq, payload)

    def on_truth(sample: zenoh.Sample) -> None:
        truth = service.decode(sample.payload.to_bytes(), TruthFrame, "truth")
        if truth is not None:
            keeper.add_truth(truth)

    # Truth first: a frame whose truth was published before we listened is never usable.
    service.session.declare_subscriber(service.topics.truth, on_truth)
    service.session.declare_subscriber(service.topics.frames, on_frame)
    publish = service.publisher(service.topics.calibration, drop=False)

    def on_current(query: zenoh.Query) -> None:
        if service.calibration.version > 0:
            query.reply(
                service.topics.calibration,
                encode(CalibrationUpdate(calibration=service.calibration)),
                encoding=zenoh.Encoding(ENCODING),
            )

    service.session.declare_queryable(service.topics.calibration, on_current)
    queries = Inbox(depth=8)
    service.session.declare_queryable(service.topics.calibrate, queries.put)

    def run_calibration(request: CalibrateRequest) -> CalibrateReply:
        picked = keeper.pick(request.frame_seq)
        if picked.seq is None:
            return CalibrateReply(ok=False, error=picked.error)
        seq = picked.seq
        if picked.payload is None:
            return CalibrateReply(ok=False, frame_seq=seq, error=picked.error)
        frame = service.decode(picked.payload, Frame, "frame")
        if frame is None:
            return CalibrateReply(
                ok=False, frame_seq=seq, error=f"frame {seq}: {service.last_error}"
            )
        points = points_for(seq, file_points, picked.truth)
        if isinstance(points, str):
            return CalibrateReply(ok=False, frame_seq=seq, error=points)
        run_cfg = config_for_request(cfg, request)
        service.state = f"calibrating on frame {seq}"
        try:
            calib, _ = calibrate(frame.image(), points, run_cfg, source=f"frame {seq}")
        except (InfeasibleCalibrationError, ImageError, ValueError) as exc:
            service.error("calibration", f"calibration on frame {seq} failed: {exc}")
            return CalibrateReply(ok=False, frame_seq=seq, error=str(exc))
        finally:
            service.state = "ok"
        problem = calibration_problem(calib, cfg)
        if problem is not None:  # never published: the stages would refuse it anyway
            service.error("calibration", f"calibration on frame {seq}: {problem}")
            return CalibrateReply(ok=False, frame_seq=seq, error=problem)
        calib = store.save(calib)
        service.calibration = calib
        publish(CalibrationUpdate(calibration=calib))
        service.sent()
        service.log.info(
            "calibration %s on frame %d: DIPE %.3f px (%.4f mm) in %.2f s",
            label(calib),
            seq,
            calib.dipe_px,
            calib.dipe_mm,
            calib.elapsed_s,
        )
        return calibrate_reply(calib, seq, str(store.path(calib.version)))

    def answer(query: zenoh.Query) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        request: CalibrateRequest | None = CalibrateRequest()
        if payload:
            request = service.decode(payload, CalibrateRequest, "calibrate_request")
        if request is None:
            reply = CalibrateReply(ok=False, error=f"bad request: {service.last_error}")
        else:
            reply = run_calibration(request)
        query.reply(service.topics.calibrate, encode(reply), encoding=zenoh.Encoding(ENCODING))

    service.state = "ok" if service.calibration.version > 0 else "no calibration"
    service.ready()
    if saved is None and cfg.service.auto_calibrate:
        initial_calibration(service, keeper, run_calibration)
    while not service.stop.is_set():
        query = queries.get(timeout=0.2)
        if query is None:
            continue
        try:
            answer(query)
        except Exception as exc:
            service.error("processing", f"calibrate query failed: {type(exc).__name__}: {exc}")
        finally:
            del query  # the reply is final when the query is dropped
