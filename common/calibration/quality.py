"""How good a calibration is, as stored in the calibration file (beyond the paper).

The paper judges a calibration by the DIPE of the points it was fitted to. These
records say what that number hides (computed by :mod:`ovis.common.calibration.accuracy`):

* :class:`HeldOut` — errors on points *not* used for the fit: leave-one-out over the
  control points, or extra check points (possibly on another frame), in pixels and in
  cm on the plane of each point;
* :class:`ParameterDetermination` — per calibrated parameter, whether the data
  determine it: how far sweeping it over its whole range moves the points, its
  standard error from the Jacobian of the pixel residuals, and its spread across GA
  restarts with other seeds;
* :class:`LensCheck` — for a pose fitted with a known lens, whether its residuals are
  what the lens's own error and the points' precision explain, and what to blame if not
  (computed by :mod:`ovis.common.calibration.lens_check`).

Only plain msgspec Structs live here (no computation), so that the calibration file
can hold them without importing the solvers.
"""

from __future__ import annotations

import msgspec

__all__ = [
    "AccuracyReport",
    "HeldOut",
    "HeldOutPoint",
    "LensCheck",
    "ParameterDetermination",
    "PointFit",
]


class PointFit(msgspec.Struct, kw_only=True):
    """A point of known position: where its blob was detected and where the calibration
    projects it (pixels)."""

    name: str
    x_cm: float
    y_cm: float
    z_cm: float
    detected_row: float
    detected_col: float
    predicted_row: float
    predicted_col: float


class HeldOutPoint(PointFit, kw_only=True):
    """One held-out point: how far the calibration misses it.

    ``error_px`` is the distance between the detected blob centroid and the projection
    of the point; ``error_cm`` is the distance on the plane Z = ``z_cm`` between the
    back-projected centroid and the point (None if the pixel does not see the plane).
    ``in_sample_px`` is the same point's residual when it *was* used for the fit
    (leave-one-out only).
    """

    error_px: float
    error_cm: float | None = None
    in_sample_px: float | None = None


class HeldOut(msgspec.Struct, kw_only=True):
    """Errors on held-out points: ``method`` is ``leave-one-out`` or ``check points``."""

    method: str
    source: str = ""
    points: list[HeldOutPoint] = []
    #: check points with no blob near their projection (not detected)
    missing: list[str] = []
    mean_px: float | None = None
    max_px: float | None = None
    mean_cm: float | None = None
    max_cm: float | None = None


class ParameterDetermination(msgspec.Struct, kw_only=True):
    """Whether the data determine one calibrated camera parameter.

    ``sweep_px``: largest movement (px) of a control point when the parameter alone
    goes from the low to the high end of its range. ``standard_error``: from the
    Jacobian of the pixel residuals, all other determinable parameters free
    (None when the parameter is not determinable at all). ``restart_min``/``max``: the
    values GA restarts with other seeds returned; ``restart_spread`` is their range as a
    fraction of the search range.
    """

    name: str
    value: float
    range_lo: float
    range_hi: float
    sweep_px: float
    standard_error: float | None = None
    relative_error: float | None = None  # standard_error / (range_hi − range_lo)
    restart_min: float | None = None
    restart_max: float | None = None
    restart_spread: float | None = None
    determined: bool = False


class LensCheck(msgspec.Struct, kw_only=True):
    """A known-lens floor pose judged against what its lens and its points explain
    (:mod:`ovis.common.calibration.lens_check`).

    ``lens_rms_px``: the intrinsics file's RMS reprojection error (None: not stated);
    ``point_px``: the control points' pixel precision (RMS); ``expected_px``: one
    point's expected RMS residual from both; ``allowed_rms_px``: the largest RMS residual
    of these points they explain; ``rms_px``: the residuals' RMS. ``residual_cm``: each
    point's pixel back-projected onto its plane vs. its position (in the order of the
    calibration's points; None where the pixel does not see the plane). ``outlier``: the
    point leave-one-out singles out, with its held-out error. ``problems``: why the pose
    is not believable (empty: it is); ``hints``: what explains the points instead.
    """

    lens_rms_px: float | None
    point_px: float
    rms_px: float
    camera_height_cm: float
    tilt_deg: float
    worst: str
    worst_px: float
    worst_cm: float | None = None
    residual_cm: list[float | None] = []
    expected_px: float | None = None
    allowed_rms_px: float | None = None
    explained: bool = False
    outlier: str | None = None
    outlier_px: float | None = None
    outlier_cm: float | None = None
    #: other points whose removal would leave the rest explained too (less well)
    outlier_also: list[str] = []
    problems: list[str] = []
    hints: list[str] = []


class AccuracyReport(msgspec.Struct, kw_only=True):
    """Held-out errors and parameter identifiability of one calibration."""

    leave_one_out: HeldOut | None = None
    check: HeldOut | None = None
    parameters: list[ParameterDetermination] = []
    #: residual scale (px) used for the standard errors: RMS of the least-squares fit,
    #: corrected for the number of determined parameters
    sigma_px: float | None = None
    #: condition number of the Jacobian (columns scaled to each parameter's range) over
    #: all continuous camera parameters, and over the determined ones only
    condition_all: float | None = None
    condition_determined: float | None = None
    #: strongest correlations between determined parameters: (a, b, correlation)
    correlations: list[tuple[str, str, float]] = []
    #: GA restarts with other seeds: their seeds and mean DIPE (px)
    restart_seeds: list[int] = []
    restart_dipe_px: list[float] = []
    #: plain-language findings
    notes: list[str] = []
    #: known-lens floor poses: the residuals judged against the lens and the points
    lens: LensCheck | None = None
