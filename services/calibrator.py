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

import collections
import threading
from collections.abc import Callable
from typing import Any

import msgspec
import zenoh

from ovis.common.calibration.file import dipe_text
from ovis.common.calibration.problem import InfeasibleCalibrationError, calibrate
from ovis.common.calibration.store import CalibrationStore
from ovis.common.camera.projection import camera_parameters
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
from ovis.common.sim.arena import control_points
from ovis.common.vision.preprocess import ImageError
from ovis.services.runtime import Inbox, Service

KEEP_FRAMES = 64
INITIAL_RETRY_S = 2.0
TRUTH_WAIT_S = 1.0  # how long a named frame's ground truth may trail the frame


def missing_frame(seq: int, first: int, last: int) -> str:
    """Why frame ``seq`` is not among the kept frames ``first``..``last``."""
    if seq < first:
        return f"frame {seq} is gone: the calibrator keeps the last {KEEP_FRAMES} ({first}–{last})"
    return (
        f"frame {seq} never reached the calibrator (it has {first}–{last}; a frame the bus "
        "dropped, or a number from another run); ask without a frame for the newest"
    )


def initial_calibration(
    service: Service,
    first_frame: threading.Event,
    run_calibration: Callable[[CalibrateRequest], CalibrateReply],
) -> None:
    """Calibrate on the newest usable frame once frames flow, retrying every
    ``INITIAL_RETRY_S`` until it works (a scene may be infeasible for a while); queries
    are served only after."""
    service.log.info("no saved calibration: calibrating on the first usable frame")
    while not service.stop.is_set():
        if not first_frame.wait(0.2):
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
    if saved is not None:
        service.calibration = saved
        service.log.info("loaded calibration v%d from %s", saved.version, store.folder)
    file_points: list[ControlPoint] | None = None
    if cfg.service.points != "simulator":
        file_points = load_points(cfg.service.points).points

    frames: collections.OrderedDict[int, bytes] = collections.OrderedDict()  # raw payloads
    truths: collections.OrderedDict[int, TruthFrame] = collections.OrderedDict()
    lock = threading.Condition()  # guards frames and truths; notified when either grows
    first_frame = threading.Event()
    needs_truth = file_points is None

    def keep(store_: collections.OrderedDict, seq: int, item: Any) -> None:
        with lock:
            store_[seq] = item
            while len(store_) > KEEP_FRAMES:
                store_.popitem(last=False)
            lock.notify_all()

    def newest_usable() -> int:
        """The newest frame with its control points: the capture publishes a frame just
        before its ground truth, so the very newest may not have it yet."""
        for seq in reversed(frames):
            if not needs_truth or seq in truths:
                return seq
        return next(reversed(frames))

    def on_frame(sample: zenoh.Sample) -> None:
        # Only the header is decoded here (cheap); the image when a calibration needs it.
        payload = sample.payload.to_bytes()
        header = service.decode(payload, FrameHeader, "frame")
        if header is not None:
            service.saw_frame(header.seq, header.stamp_ns)
            keep(frames, header.seq, payload)
            first_frame.set()

    def on_truth(sample: zenoh.Sample) -> None:
        truth = service.decode(sample.payload.to_bytes(), TruthFrame, "truth")
        if truth is not None:
            keep(truths, truth.seq, truth)

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
        with lock:
            if not frames:
                return CalibrateReply(ok=False, error="no frame received yet from capture")
            seq = request.frame_seq if request.frame_seq is not None else newest_usable()
            if needs_truth:  # its truth may still be on its way
                lock.wait_for(lambda: seq in truths or seq not in frames, TRUTH_WAIT_S)
            payload = frames.get(seq)
            truth = truths.get(seq)
            kept = next(iter(frames)), next(reversed(frames))
        if payload is None:
            return CalibrateReply(ok=False, frame_seq=seq, error=missing_frame(seq, *kept))
        frame = service.decode(payload, Frame, "frame")
        if frame is None:
            return CalibrateReply(
                ok=False, frame_seq=seq, error=f"frame {seq}: {service.last_error}"
            )
        if file_points is not None:
            points = file_points
        elif truth is not None:
            points = control_points(truth)
        else:
            return CalibrateReply(
                ok=False,
                frame_seq=seq,
                error=f"no control points: no ground truth for frame {seq} within "
                f"{TRUTH_WAIT_S:g} s (the simulator sends it); for a real camera set "
                "service.points to a points file",
            )
        ga = msgspec.structs.replace(
            cfg.ga,
            **{
                k: v
                for k, v in (
                    ("seed", request.seed),
                    ("population", request.population),
                    ("generations", request.generations),
                )
                if v is not None
            },
        )
        run_cfg = msgspec.structs.replace(cfg, ga=ga)
        service.state = f"calibrating on frame {seq}"
        try:
            calib, _ = calibrate(frame.image(), points, run_cfg, source=f"frame {seq}")
        except (InfeasibleCalibrationError, ImageError, ValueError) as exc:
            service.error("calibration", f"calibration on frame {seq} failed: {exc}")
            return CalibrateReply(ok=False, frame_seq=seq, error=str(exc))
        finally:
            service.state = "ok"
        calib = store.save(calib)
        service.calibration = calib
        publish(CalibrationUpdate(calibration=calib))
        service.sent()
        service.log.info(
            "calibration v%d on frame %d: DIPE %s in %.2f s",
            calib.version,
            seq,
            dipe_text(calib.dipe_px, calib.dipe_mm),
            calib.elapsed_s,
        )
        params = camera_parameters(calib.camera)
        params["threshold"] = float(calib.image.threshold)
        params["size_filter_cm2"] = calib.image.size_filter_cm2
        return CalibrateReply(
            ok=True,
            version=calib.version,
            frame_seq=seq,
            dipe_px=calib.dipe_px,
            dipe_mm=calib.dipe_mm,
            dipe_max_px=calib.dipe_max_px,
            elapsed_s=calib.elapsed_s,
            parameters=params,
            saved_to=str(store.path(calib.version)),
        )

    def answer(query: zenoh.Query) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        if payload:
            request = service.decode(payload, CalibrateRequest, "calibrate_request")
            if request is None:
                reply = CalibrateReply(ok=False, error=f"bad request: {service.last_error}")
            else:
                reply = run_calibration(request)
        else:
            reply = run_calibration(CalibrateRequest())
        query.reply(service.topics.calibrate, encode(reply), encoding=zenoh.Encoding(ENCODING))

    service.state = "ok" if service.calibration.version > 0 else "no calibration"
    service.ready()
    if saved is None and cfg.service.auto_calibrate:
        initial_calibration(service, first_frame, run_calibration)
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
