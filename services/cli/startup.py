"""`ovis up`'s checks before it starts anything: the router's endpoint is free, the
source opens and delivers a frame (which gives the frame size), and there is a
calibration for that source and size (scaled when only the size differs). A failure is
one line and exit code 2, and nothing has been started."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import msgspec

from ovis.services.cli.errors import UserError

__all__ = ["PROBE_S", "calibration_for_run", "check_endpoint", "source_size", "with_keys"]

#: How long the source may take to deliver its first frame at start.
PROBE_S = 8.0


def check_endpoint(listen: str) -> None:
    """Stop (exit 2) when another process listens on the router's endpoint: this run
    would join that system instead of starting its own."""
    from ovis.services.bus import endpoint_in_use

    taken = endpoint_in_use(listen)
    if taken:
        raise UserError(
            f"the router endpoint {listen} is taken ({taken}): another `ovis up` or "
            "router runs there; give --listen tcp/127.0.0.1:PORT with a free port "
            "(nothing was started)"
        )


def _recorded_size(cfg: Any) -> tuple[int, int] | None:
    """(width, height) of the first frame a replay of the session publishes (None: it
    holds none): ovis's own frames or another tool's image channel (``--topic``)."""
    from ovis.common.recording.foreign import frame_size
    from ovis.common.recording.session import RecordingError

    try:
        return frame_size(cfg.service.source, cfg.service.source_topic or None)
    except RecordingError as exc:
        raise UserError(f"{exc} (nothing was started)") from None


def _first_frame(cfg: Any) -> tuple[int, int]:
    """(width, height) of the source's first frame: opened, read once, closed, within
    :data:`PROBE_S` (exit 2 with the source's reason otherwise)."""
    import cv2.utils.logging as cv_log

    from ovis.common.capture.sources import SourceError
    from ovis.services.ros2_source import open_source

    spec = cfg.service.source
    outcome: list[tuple[int, int] | str] = []
    # OpenCV's own warnings (a camera it cannot open) would add lines to the one error
    cv_log.setLogLevel(cv_log.LOG_LEVEL_ERROR)

    def probe() -> None:
        try:
            src = open_source(spec, cfg, loop=False)
            try:
                image, _ = src.read()
            finally:
                src.close()
            outcome.append((image.shape[1], image.shape[0]))
        except SourceError as exc:
            outcome.append(str(exc))
        except Exception as exc:  # a source library failing in its own way
            outcome.append(f"{spec}: {type(exc).__name__}: {exc}")

    worker = threading.Thread(target=probe, name="source-probe", daemon=True)
    worker.start()
    worker.join(PROBE_S)
    if not outcome:
        raise UserError(
            f"{spec} delivered no frame within {PROBE_S:g} s: check that it is connected "
            "and delivers images (nothing was started)"
        )
    if isinstance(outcome[0], str):
        raise UserError(f"{outcome[0]} (nothing was started)")
    return outcome[0]


def source_size(cfg: Any) -> tuple[int, int] | None:
    """(width, height) of the source's frames: the configured camera's for the
    simulator, the first frame's for anything else; None for a simulated grid camera
    or a recording with no ovis frame (nothing to check here)."""
    from ovis.services.replay import is_recording

    spec = cfg.service.source
    if spec == "sim":
        return cfg.camera.cols, cfg.camera.rows
    if spec.startswith("grid:"):
        return None
    if is_recording(spec):
        return _recorded_size(cfg)
    return _first_frame(cfg)


def _stored_calibration(cfg: Any):
    """The state folder's newest calibration when it stands for this real source: not
    the simulator's, unless it is the recording's own (``--source SESSION.mcap``: the
    one the recorded system used counts whatever made it); else exit 2."""
    from ovis.common.calibration.frame_size import HOW_TO_CALIBRATE, made_on_simulator
    from ovis.common.calibration.store import CalibrationStore

    store = CalibrationStore(cfg.service.state_dir)
    calib, _ = store.latest()
    source = cfg.service.source
    if calib is not None and (not made_on_simulator(calib) or _recordings_own(source, calib)):
        return calib, f"calibration v{calib.version} of {store.folder}"
    held = (
        f"the newest in {store.folder} is the simulator's"
        if calib is not None
        else f"{store.folder} holds none"
    )
    raise UserError(
        f"{source} needs a calibration of its own camera ({held}; the simulator's "
        f"camera is never used for real frames): {HOW_TO_CALIBRATE}"
    )


def _recordings_own(source: str, calib: Any) -> bool:
    """Whether ``calib`` is the calibration the recording ``source`` carries (the one
    :func:`~ovis.common.recording.calibration.adopt_recorded_calibration` stored), not
    merely one found beside it; False for any other source."""
    from ovis.common.recording.session import recorded_calibration
    from ovis.services.replay import is_recording

    return is_recording(source) and recorded_calibration(source) == calib


def calibration_for_run(cfg: Any, given: Path | None, size: tuple[int, int] | None):
    """The calibration the services start with, fitted to the frames, and what to say
    about it (lines); (None, []) for the simulator with no --calibration (its
    calibrator calibrates on the first frame). A given or scaled calibration is stored
    as the state folder's newest version (the calibrator hands it to the stages). A
    real source without a calibration for it, a size that does not fit, or a
    calibration this arena cannot use: exit 2."""
    from ovis.common.calibration.file import load_calibration
    from ovis.common.calibration.frame_size import FrameSizeError, fit_to_frames
    from ovis.common.calibration.store import CalibrationStore
    from ovis.common.calibration.validity import calibration_problem, simulated_setup

    if given is not None:
        calib, name = load_calibration(given), str(given)
    elif cfg.service.simulated_source:
        return None, []
    else:
        calib, name = _stored_calibration(cfg)
    lines: list[str] = []
    if size is not None:
        try:
            calib, note = fit_to_frames(calib, *size, source=cfg.service.source, name=name)
        except FrameSizeError as exc:
            raise UserError(f"{exc} (nothing was started)") from None
        if note:
            lines.append(note)
    problem = calibration_problem(calib, services_config(cfg, calib))
    if problem is not None:
        raise UserError(f"{name}: {problem} (nothing was started)")
    if given is not None and calib.simulated and cfg.service.simulated_source:
        # given for this simulated run: its set-up's, whatever it was made on
        calib = msgspec.structs.replace(calib, simulated_for=simulated_setup(cfg))
    if given is not None or lines:
        store = CalibrationStore(cfg.service.state_dir)
        calib = store.save(calib)
        what = "the scaled calibration" if lines else f"calibration {given}"
        lines.append(f"{what} stored as version {calib.version} in {store.folder}")
    return calib, lines


def services_config(cfg: Any, calib: Any) -> Any:
    """The services' configuration: for a real source, its camera is the calibration's
    (the frame size, and what every stage checks a calibration against); the simulator
    keeps its own camera, which renders the frames."""
    if calib is None or cfg.service.simulated_source:
        return cfg
    return msgspec.structs.replace(cfg, camera=calib.camera)


def with_keys(cfg: Any) -> Any:
    """The keys of the calibrator, the pose stage, fusion and the planner made (or, from an
    earlier run, loaded) in the state folder's ``keys/`` before anything starts, and the services'
    configuration naming that folder (absolute): every process it starts signs or
    verifies with them, none takes a key from the bus. A folder that cannot be written
    stops the start (exit 2)."""
    from ovis.common.trust.keys import ROLES, KeyFileError, keys_dir, load_or_create_private

    folder = keys_dir(cfg).resolve()
    trust = msgspec.structs.replace(
        cfg.trust,
        keys_dir=str(folder),
        calibrator_public="",
        pose_public="",
        fusion_public="",
        planner_public="",
    )
    try:
        for role in ROLES:
            load_or_create_private(folder / f"{role}.key")
    except KeyFileError as exc:
        raise UserError(f"{exc} (nothing was started)") from None
    return msgspec.structs.replace(cfg, trust=trust)
