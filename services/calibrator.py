"""Calibration worker: a Zenoh queryable on ``ovis/<arena>/calibrate``.

A query runs the GA (paper §4) on the latest frame, or on the frame named in the query,
with the configured control points (a points file, or for the simulated arena the
frame's ground truth, which the capture sends just after the frame: the latest frame
that has it, and a named frame's is waited for up to ``TRUTH_WAIT_S``); in the physical
world the pose is solved on its floor marks instead (:mod:`ovis.common.pipeline.floor_marks`)
and judged on that frame; the result,
checked by :func:`calibration_problem`, is saved atomically as a new version of the
store (with its epoch), published on ``ovis/<arena>/calibration`` and returned in the
reply, once it passed the quality gate (:mod:`ovis.common.calibration.gate`: a candidate
much worse than the current calibration, or that does not see what it sees, is kept
aside in ``rejected/``, the reply and the status say why, and the current calibration
stays). ``ovis/<arena>/calibration`` is also a queryable returning the current
calibration: the stages take only its answer (they ask it on every publication and
every few seconds).

One calibration runs at a time, within the limits of ``[service]`` (``max_population``,
``max_evaluations``, ``calibration_budget_s``); a query while it runs is answered at
once ("busy", with its progress and ETA); a cancel request or SIGTERM stops it after
the current generation.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import msgspec
import numpy as np
import zenoh
from numpy.typing import NDArray

from ovis.common.calibration.calibrate import calibrate
from ovis.common.calibration.errors import InfeasibleCalibrationError
from ovis.common.calibration.file import Calibration, dipe_text
from ovis.common.calibration.ga import GenerationStats
from ovis.common.calibration.rejected import save_rejected
from ovis.common.calibration.store import CalibrationStore, StoreWriteError
from ovis.common.calibration.validity import (
    calibration_problem,
    setup_problem,
    simulated_setup,
)
from ovis.common.config import ControlPoint, load_points
from ovis.common.messages import (
    ENCODING,
    CalibrateReply,
    CalibrateRequest,
    CalibrationUpdate,
    Frame,
    FrameHeader,
    ServiceStatus,
    TruthFrame,
    encode,
)
from ovis.common.pipeline.candidate import judge_candidate
from ovis.common.pipeline.floor_marks import FloorMarksCalibration
from ovis.common.pipeline.following import label
from ovis.common.pipeline.limits import frame_payload_problem
from ovis.common.pipeline.recalibration import (
    CalibrationCancelledError,
    CalibrationJob,
    FrameKeeper,
    calibrate_reply,
    config_for_request,
    points_for,
    too_big,
)
from ovis.common.pipeline.saving import cannot_save_status, cannot_save_text
from ovis.common.vision.frames import ImageError
from ovis.services.inbox import Inbox
from ovis.services.service import Service
from ovis.services.trust import signer_for

INITIAL_RETRY_S = 2.0


def initial_calibration(
    service: Service,
    can_start: threading.Event,
    job: CalibrationJob,
    run_calibration: Callable[[CalibrateRequest], CalibrateReply],
    answer_next: Callable[[float], bool],
) -> None:
    """Calibrate on the newest usable frame once ``can_start`` is set (frames flow; the
    floor marks need none), retrying every ``INITIAL_RETRY_S`` until it works (a scene
    may be infeasible, the disk full, for a while); queries meanwhile are answered
    (``answer_next``: "busy" while it runs, and one that calibrates is the first
    calibration)."""
    service.log.info("no saved calibration: calibrating on the first usable frame")
    said, next_try = "", 0.0
    while not service.stop.is_set():
        if answer_next(0.2):
            return
        if time.monotonic() < next_try or not can_start.is_set() or not job.claim():
            continue
        try:
            reply = run_calibration(CalibrateRequest())
        finally:
            job.done()
        if reply.ok:
            return
        if reply.error != said:  # a state that lasts (a full disk) is said once
            service.log.warning("initial calibration failed: %s; retrying", reply.error)
            said = reply.error
        next_try = time.monotonic() + INITIAL_RETRY_S


def restored(service: Service, store: CalibrationStore, saved: Calibration) -> Calibration:
    """The newest valid version, saved again as the store's next version when newer
    ones were skipped: stages take only a calibration newer than theirs (a lower version
    would be a replay to them), and one may hold a version whose file is now invalid."""
    try:
        again = store.save(saved)
    except StoreWriteError as exc:  # stages holding a newer version keep it
        service.error("cannot_save", f"cannot save: {exc}")
        return saved
    service.log.info("restored %s as %s (newer versions skipped)", label(saved), label(again))
    return again


def main(service: Service) -> None:
    cfg = service.config
    store = CalibrationStore(cfg.service.state_dir, keep=cfg.service.keep_calibrations)
    saved, problems = store.latest(
        lambda calib: calibration_problem(calib, cfg) or setup_problem(calib, cfg)
    )
    for problem in problems:  # the newest valid version is used: these were newer
        service.error("bad_saved_calibration", f"skipped {problem}")
    try:
        epoch = store.epoch()
    except StoreWriteError as exc:  # the status says so while it lasts (store.problem)
        epoch = ""
        service.error("cannot_save", f"cannot save: {exc}")
    rejected = [""]  # why the last candidate was refused, until one is published

    def amend_status(status: ServiceStatus) -> ServiceStatus:
        """What the counters cannot say: the store cannot save, or a refused candidate."""
        status = cannot_save_status(status, store.problem)
        if rejected[0] and status.state == "ok":
            return msgspec.structs.replace(status, state="rejected candidate", reason=rejected[0])
        return status

    service.amend_status = amend_status
    if saved is not None:
        service.calibration = msgspec.structs.replace(saved, epoch=saved.epoch or epoch)
        service.log.info("loaded calibration %s from %s", label(service.calibration), store.folder)
        if problems and epoch:
            service.calibration = restored(service, store, service.calibration)
    file_points: list[ControlPoint] | None = None
    if cfg.service.points != "simulator":
        file_points = load_points(cfg.service.points).points
    keeper = FrameKeeper(needs_truth=file_points is None)
    # the physical world: the floor marks, measured in the empty floor (not the objects)
    on_marks = None
    if file_points is None and cfg.simulator.world == "physical":
        on_marks = FloorMarksCalibration(cfg)

    def on_frame(sample: zenoh.Sample) -> None:
        # Only the header is decoded here (cheap); the image when a calibration needs it.
        # A frame is kept only if it has the camera's size and as many bytes as it says.
        payload = service.take(sample.payload, "frame", "frame")
        header = None if payload is None else service.decode(payload, FrameHeader, "frame")
        if payload is None or header is None:
            return
        camera = service.calibration.camera
        if not service.refused("bad_frame", frame_payload_problem(header, len(payload), camera)):
            service.saw_frame(header.seq, header.stamp_ns, header.stream)
            keeper.add_frame(header.seq, payload)

    def on_truth(sample: zenoh.Sample) -> None:
        truth = service.receive(sample.payload, "small", TruthFrame, "truth")
        if truth is not None:
            keeper.add_truth(truth)

    # Truth first: a frame whose truth was published before we listened is never usable.
    service.session.declare_subscriber(service.topics.truth, on_truth)
    service.session.declare_subscriber(service.topics.frames, on_frame)
    signer = signer_for(cfg, "calibrator")  # its word is what this key signed
    publish = service.publisher(service.topics.calibration, drop=False, signer=signer)

    def on_current(query: zenoh.Query) -> None:
        if service.fits(query.payload, "small", "calibration_query") and (
            service.calibration.version > 0
        ):
            key = service.topics.calibration
            payload = encode(CalibrationUpdate(calibration=service.calibration))
            query.reply(
                key,
                payload,
                encoding=zenoh.Encoding(ENCODING),
                attachment=signer.attachment(key, payload),
            )

    service.session.declare_queryable(service.topics.calibration, on_current)

    def refuse(calib: Calibration, seq: int, problem: str) -> CalibrateReply:
        """Keep a candidate the gate refused aside; the reply says why."""
        rejected[0] = f"{problem} (frame {seq})"
        service.error("rejected_candidate", rejected[0])
        try:
            kept = str(save_rejected(store.folder, calib, problem))
        except OSError as exc:
            kept = ""
            service.error("processing", f"cannot keep the rejected candidate: {exc}")
        return CalibrateReply(
            ok=False, frame_seq=seq, dipe_px=calib.dipe_px, saved_to=kept, error=problem
        )

    job = CalibrationJob()
    accepted = Inbox(depth=2)  # (query, request): at most one, the job being claimed

    def reply_to(query: zenoh.Query, reply: CalibrateReply) -> None:
        query.reply(service.topics.calibrate, encode(reply), encoding=zenoh.Encoding(ENCODING))

    def on_calibrate(query: zenoh.Query) -> None:
        """Every query is answered at once here (bad, too big, cancel, busy), or
        accepted for the loop, which answers when the calibration is done."""
        try:
            payload = service.take(query.payload, "small", "calibrate_request")
            request = CalibrateRequest() if payload == b"" else None
            if payload:
                request = service.decode(payload, CalibrateRequest, "calibrate_request")
            if request is None:
                reply_to(
                    query, CalibrateReply(ok=False, error=f"bad request: {service.last_error}")
                )
            elif request.cancel:
                cancelled = job.cancel("cancelled by a query")
                text = "cancelling the running calibration" if cancelled else "nothing to cancel"
                reply_to(query, CalibrateReply(ok=False, error=text))
            elif problem := too_big(config_for_request(cfg, request)):
                service.error("calibrate_request_too_big", problem)
                reply_to(query, CalibrateReply(ok=False, error=problem))
            elif not job.claim():
                reply_to(query, job.busy_reply())
            else:
                accepted.put((query, request))
        except Exception as exc:  # never let a query kill the calibrator
            service.error("processing", f"calibrate query failed: {type(exc).__name__}: {exc}")

    def not_saved(seq: int | None, problem: str) -> CalibrateReply:
        """The reply (and the count) when the store cannot be written: no calibration
        is used that a restart would lose."""
        text = cannot_save_text(problem, label(service.calibration))
        service.error("cannot_save", f"calibration refused: {text}")
        return CalibrateReply(ok=False, frame_seq=-1 if seq is None else seq, error=text)

    def after_generation(stats: GenerationStats) -> None:
        if service.stop.is_set():
            job.cancel("the calibrator is stopping")
        job.after_generation(stats.generation)

    def run_calibration(request: CalibrateRequest) -> CalibrateReply:
        run_cfg = config_for_request(cfg, request)
        problem = too_big(run_cfg)
        if problem is not None:
            return CalibrateReply(ok=False, error=problem)
        if (problem := store.writable()) is not None:  # said at once, not after the GA
            return not_saved(None, problem)
        if on_marks is not None:
            return run_on_marks(request)
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
        service.state = f"calibrating on frame {seq}"
        job.start(seq, run_cfg.ga.generations, cfg.service.calibration_budget_s)
        try:
            image = frame.image()
            calib, _ = calibrate(
                image,
                points,
                run_cfg,
                source=f"frame {seq}",
                on_generation=after_generation,
            )
        except (
            InfeasibleCalibrationError,
            ImageError,
            ValueError,
            CalibrationCancelledError,
        ) as exc:
            service.error("calibration", f"calibration on frame {seq} failed: {exc}")
            return CalibrateReply(ok=False, frame_seq=seq, error=str(exc))
        finally:
            service.state = "ok"
        # on the simulator's truth: the simulated camera's calibration (`ovis up` never
        # takes it for a real camera's)
        calib = msgspec.structs.replace(calib, simulated=file_points is None)
        return adopt(calib, image, seq, request.force, f"frame {seq}")

    def run_on_marks(request: CalibrateRequest) -> CalibrateReply:
        """The physical world: the pose solved on its floor marks (needs no frame), judged
        on the newest frame, or before any came on the empty floor."""
        assert on_marks is not None
        service.state = "calibrating on the floor marks"
        job.start(-1, 1, cfg.service.calibration_budget_s)
        try:
            calib = on_marks()
        except ValueError as exc:
            service.error("calibration", f"calibration on the floor marks failed: {exc}")
            return CalibrateReply(ok=False, error=str(exc))
        finally:
            service.state = "ok"
        seq, image = -1, on_marks.floor
        picked = keeper.pick(request.frame_seq) if keeper.first_frame.is_set() else None
        if picked is not None and picked.payload is not None and picked.seq is not None:
            frame = service.decode(picked.payload, Frame, "frame")
            if frame is not None:
                seq, image = picked.seq, frame.image()
        return adopt(calib, image, seq, request.force, "the floor marks")

    def adopt(
        calib: Calibration, image: NDArray[np.uint8], seq: int, force: bool, made_on: str
    ) -> CalibrateReply:
        """Publish ``calib`` (made on ``made_on``) as the new calibration once it passed
        the checks and the gate (judged on ``image``, frame ``seq``); or the reply why not."""
        if calib.simulated:  # the set-up it was made on: another run's never takes it
            calib = msgspec.structs.replace(calib, simulated_for=simulated_setup(cfg))
        problem = calibration_problem(calib, cfg)
        if problem is not None:  # never published: the stages would refuse it anyway
            service.error("calibration", f"calibration on {made_on}: {problem}")
            return CalibrateReply(ok=False, frame_seq=seq, error=problem)
        current = service.calibration if service.calibration.version > 0 else None
        problem = judge_candidate(calib, current, image, force)
        if problem is not None:
            return refuse(calib, seq, problem)
        try:
            calib = store.save(calib)
        except StoreWriteError as exc:
            return not_saved(seq, str(exc))
        for stale in store.not_deleted:  # kept on disk: the store grows until it works
            service.error("store", f"cannot delete the old calibration {stale}")
        service.calibration = calib
        rejected[0] = ""
        publish(CalibrationUpdate(calibration=calib))
        service.sent()
        service.log.info(
            "calibration %s on %s: DIPE %s in %.2f s",
            label(calib),
            made_on,
            dipe_text(calib.dipe_px, calib.dipe_mm),
            calib.elapsed_s,
        )
        return calibrate_reply(calib, seq, str(store.path(calib.version)))

    def answer_next(timeout: float) -> bool:
        """Run the query accepted next (waiting up to ``timeout`` for one) and answer it;
        True when it made a calibration."""
        item = accepted.get(timeout=timeout)
        if item is None:
            return False
        query, request = item
        try:
            reply = run_calibration(request)
            reply_to(query, reply)
            return reply.ok
        except Exception as exc:
            service.error("processing", f"calibrate query failed: {type(exc).__name__}: {exc}")
            return False
        finally:
            job.done()
            del query, item  # the reply is final when the query is dropped

    service.session.declare_queryable(service.topics.calibrate, on_calibrate)
    service.state = "ok" if service.calibration.version > 0 else "no calibration"
    service.ready()
    if saved is None and cfg.service.auto_calibrate:
        # the floor marks need no frame: the stages have a calibration before the first
        no_frame_needed = threading.Event()
        no_frame_needed.set()
        can_start = keeper.first_frame if on_marks is None else no_frame_needed
        initial_calibration(service, can_start, job, run_calibration, answer_next)
    while not service.stop.is_set():
        answer_next(0.2)
