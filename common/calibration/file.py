"""The calibration file: a self-contained JSON record of one GA calibration.

It holds every constant and calibrated value that detection needs (camera, image
pipeline, pose rule), the DIPE (eq. 14) at the top level and per control point, and how
it was obtained (GA settings, ranges, convergence history). Files are written
atomically (temporary file in the same folder, fsync, rename), so a crash mid-save never
leaves a half-written calibration behind.
"""

from __future__ import annotations

import math
from datetime import UTC, datetime
from pathlib import Path
from typing import Literal

import msgspec

from ovis.common.atomic import write_atomic
from ovis.common.calibration.quality import AccuracyReport, PointFit
from ovis.common.config import (
    CalibrationRanges,
    CameraModel,
    GAConfig,
    ImageParams,
    OvisConfig,
    PoseConfig,
)

__all__ = [
    "Calibration",
    "CalibrationFileError",
    "GenerationRecord",
    "PointResidual",
    "calibration_from_config",
    "dipe_text",
    "load_calibration",
    "mm_or_none",
    "now_iso",
    "save_calibration",
]


class CalibrationFileError(ValueError):
    """A calibration file that cannot be used; the message names the problem."""


class PointResidual(PointFit, kw_only=True):
    """One control point: where it was detected and projected, and its DIPE."""

    dipe_px: float
    dipe_mm: float | None  # None: the pixel pitch is unknown


class GenerationRecord(msgspec.Struct):
    """One GA generation: best and mean feasible fitness (px), best so far, feasible share."""

    generation: int
    best_px: float
    mean_px: float | None
    best_so_far_px: float
    feasible_fraction: float


class Calibration(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """A calibration: everything `ovis detect` needs, and how good it is."""

    format: Literal["ovis-calibration"] = "ovis-calibration"
    version: int = 1
    created: str = ""
    dipe_px: float
    #: the DIPE on the image plane in mm: None when the pixel pitch is unknown (a real
    #: camera's pinhole without ``pixel_pitch_mm``), so that no mm figure is made up
    dipe_mm: float | None
    dipe_max_px: float
    dipe_max_mm: float | None
    camera: CameraModel  # the paper model or a pinhole (its `model` field says which)
    image: ImageParams
    pose: PoseConfig
    points: list[PointResidual] = []
    ga: GAConfig | None = None
    ranges: CalibrationRanges | None = None
    history: list[GenerationRecord] = []
    evaluations: int = 0
    elapsed_s: float = 0.0
    source_image: str = ""
    #: what the GA itself chose, before the threshold and size filter were centred
    ga_threshold: int | None = None
    ga_size_filter_cm2: float | None = None
    #: the run of thresholds that see exactly one object per control point
    feasible_thresholds: tuple[int, int] | None = None
    #: hybrid refinement (ovis.common.calibration.refine; `[ga] polish`): whether `camera` is the
    #: least-squares polish of the GA's, the mean DIPE of the GA's camera alone and of
    #: the polished one (both at the final threshold and size filter; both are reported
    #: whichever one `camera` holds)
    polished: bool = False
    ga_dipe_px: float | None = None
    ga_dipe_mm: float | None = None
    polish_dipe_px: float | None = None
    polish_dipe_mm: float | None = None
    #: held-out errors and which parameters the data determine (ovis.common.calibration.accuracy)
    accuracy: AccuracyReport | None = None
    #: the calibrator's identity: its store's random id (``CalibrationStore.epoch``), so
    #: that a version is only compared with versions of the same store ("" in files made
    #: by ``ovis calibrate`` and before epochs existed)
    epoch: str = ""
    #: made on the simulator's ground truth (the calibrator with points "simulator"): the
    #: simulated camera's, never taken for a real camera's (``ovis up`` checks it)
    simulated: bool = False
    #: with ``simulated``: the simulated set-up it was made on (its world and a digest of
    #: the camera that renders it: :func:`~ovis.common.calibration.validity.simulated_setup`),
    #: so that a run of another world or camera does not take it for its own; "" in
    #: files from before this was recorded
    simulated_for: str = ""

    def __post_init__(self) -> None:
        for name in ("dipe_px", "dipe_mm", "dipe_max_px", "dipe_max_mm"):
            value = getattr(self, name)
            if value is None and name.endswith("_mm"):
                continue
            if value is None or not math.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be a finite non-negative number, got {value}")
        if self.version < 0:
            raise ValueError(f"version must be >= 0 (0: not calibrated), got {self.version}")


def dipe_text(px: float, mm: float | None) -> str:
    """``"0.123 px = 0.0012 mm"``, or the pixels alone when the pixel pitch is unknown."""
    if mm is None or not math.isfinite(mm):
        return f"{px:.3f} px"
    return f"{px:.3f} px = {mm:.4f} mm"


def mm_or_none(value: float) -> float | None:
    """A length in mm, or None where it is NaN (pixel pitch unknown)."""
    value = float(value)
    return value if math.isfinite(value) else None


def now_iso() -> str:
    """Current UTC time, ISO 8601 with seconds."""
    return datetime.now(UTC).isoformat(timespec="seconds")


def save_calibration(path: Path | str, calibration: Calibration) -> None:
    """Save a calibration as indented JSON, atomically."""
    write_atomic(path, msgspec.json.format(msgspec.json.encode(calibration), indent=2) + b"\n")


def load_calibration(path: Path | str) -> Calibration:
    """Load and validate a calibration file; errors name the file and the bad field."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise CalibrationFileError(
            f"calibration file {path} does not exist; run `ovis calibrate` to make one"
        ) from None
    except OSError as exc:
        raise CalibrationFileError(f"cannot read calibration file {path}: {exc}") from None
    try:
        return msgspec.json.decode(raw, type=Calibration)
    except msgspec.ValidationError as exc:
        raise CalibrationFileError(f"calibration file {path} is invalid: {exc}") from None
    except msgspec.DecodeError as exc:
        raise CalibrationFileError(f"calibration file {path} is not valid JSON: {exc}") from None


def calibration_from_config(config: OvisConfig) -> Calibration:
    """Version 0: the configured (nominal, uncalibrated) camera and image settings, what
    a service uses until a calibration is published."""
    no_dipe = dict.fromkeys(("dipe_px", "dipe_mm", "dipe_max_px", "dipe_max_mm"), 0.0)
    return Calibration(
        version=0,
        camera=config.camera,
        image=config.image,
        pose=config.pose,
        source_image="configuration (not calibrated)",
        **no_dipe,
    )
