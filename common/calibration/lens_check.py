"""Is a floor pose what its lens and its control points explain? (known-lens poses)

With the lens fixed (``ovis calibrate --intrinsics``), a control point's pixel residual
after the pose fit has two sources: the lens model's own error — the intrinsics file's
RMS reprojection error, ``avg_reprojection_error`` — and how precisely the point's pixel
is known, ``point_px`` (RMS, px): nothing beyond the lens's error for a board's corners
(found by the detector that measured the lens), :data:`CLICK_PX` for a clicked point or
a marker corner unless told. One photo may be noisier than the lens's average (blur,
distance): the lens's share is taken :data:`VIEW_NOISE` times. So a point's residual
(a distance) is expected to have the RMS::

    e = sqrt((VIEW_NOISE · lens_rms)² + point_px²)

If the pose is right, the sum of the n squared residuals divided by e²/2 (the variance
per pixel axis) is chi-square with 2n − 6 degrees of freedom (two coordinates per point,
six pose parameters). The pose is **not explained** when the sum exceeds the
1 − :data:`ALPHA` quantile: a right pose fails this once in 1/ALPHA. As an RMS::

    allowed RMS = e · sqrt(χ²₁₋α(2n − 6) / 2n)

Not explained means a point is wrong or the lens is not this camera's. Which one:

* with 5 or more points, **leave-one-out**: the pose refitted without each point; the
  outlier is the point whose removal leaves the others best explained, when they then
  are (its held-out error says how far off it is; other points whose removal would
  also do are named beside it). With 4 points the other
  three fix the pose exactly, so no point can be singled out: the worst one is named;
* with no outlier and 5 or more points, the pose is refitted with the lens file's
  distortion left out and with one free scale on its focal length: when one of them
  explains the points, the lens file is named as the cause.

The lens file itself is checked too: it must state its fit's RMS (without it the pose
cannot be judged), and its distortion must have an inverse over the whole image (a
polynomial that folds back before the image's corners — an extrapolation beyond the
photos' corners — sends pixels there to no ray or to a wrong one).

Also recorded: the camera's height above the floor (z = 0) and its tilt from looking
straight down.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from ovis.common.calibration.quality import LensCheck
from ovis.common.camera.intrinsics import CameraIntrinsics, with_pose
from ovis.common.camera.pinhole import camera_centre_cm, rodrigues, undistort_normalised
from ovis.common.config import PinholeParams

__all__ = [
    "ALPHA",
    "BOARD_PX",
    "CLICK_PX",
    "VIEW_NOISE",
    "allowed_rms_px",
    "distortion_problems",
    "expected_px",
    "fit_statistic",
    "lens_file_problems",
    "pose_check",
    "viewing",
]

#: A right pose is refused once in 1/ALPHA.
ALPHA = 1e-3
#: How many times the lens's RMS one photo's points may be noisy.
VIEW_NOISE = 2.0
#: Default pixel precision (RMS, px) of a clicked point or a marker corner: a careful
#: click; whole-pixel coordinates alone are sqrt(1/6) px RMS off.
CLICK_PX = 0.5
#: Pixel precision of a board's corners beyond the lens's own error (the same detector).
BOARD_PX = 0.0
#: Pixels between two samples of the image border in the distortion check.
_BORDER_STEP_PX = 4


def expected_px(lens_rms_px: float, point_px: float) -> float:
    """The expected RMS residual of one point, ``e`` of the module docstring."""
    return math.hypot(VIEW_NOISE * lens_rms_px, point_px)


def allowed_rms_px(expected: float, n: int) -> float:
    """The largest RMS residual of ``n`` points that the expected error explains."""
    dof = 2 * n - 6
    return expected * math.sqrt(chi2.ppf(1 - ALPHA, dof) / (2 * n))


def fit_statistic(ssr_px2: float, expected: float, dof: int) -> float:
    """The chi-square test as a ratio: a sum of squared residuals (px²) over e²/2, divided
    by the 1 − ALPHA quantile of chi-square with ``dof`` degrees of freedom (≤ 1:
    explained; no degree of freedom: 0)."""
    if dof < 1:
        return 0.0
    return 2.0 * float(ssr_px2) / expected**2 / float(chi2.ppf(1 - ALPHA, dof))


def _ssr(residuals_px: NDArray[np.float64]) -> float:
    return float(np.sum(np.square(residuals_px)))


def lens_file_problems(intr: CameraIntrinsics, what: str = "the intrinsics file") -> list[str]:
    """Why the lens file cannot be trusted on its own: no fit quality, or a distortion
    that folds (see the module docstring)."""
    problems = []
    if intr.rms_px is None:
        problems.append(
            f"{what} states no fit quality (avg_reprojection_error), so the pose cannot be "
            "judged against it: make it with `ovis intrinsics`"
        )
    return problems + distortion_problems(intr, what)


def distortion_problems(intr: CameraIntrinsics, what: str = "the intrinsics file") -> list[str]:
    """Whether the lens's distortion has an inverse all along the image's border (so
    everywhere inside: it is radial-monotonic) — empty when it does."""
    w, h = intr.width, intr.height
    cols = np.append(np.arange(0, w, _BORDER_STEP_PX, dtype=np.float64), w - 1.0)
    rows = np.append(np.arange(0, h, _BORDER_STEP_PX, dtype=np.float64), h - 1.0)
    border_row = np.concatenate([np.zeros_like(cols), np.full_like(cols, h - 1), rows, rows])
    border_col = np.concatenate([cols, cols, np.zeros_like(rows), np.full_like(rows, w - 1)])
    und = undistort_normalised(border_row, border_col, with_pose(intr))
    if und.valid.all():
        return []
    i = int(np.flatnonzero(~und.valid)[0])
    k1, k2, _, _, k3 = intr.dist
    return [
        f"the distortion of {what} (k1 {k1:.4g}, k2 {k2:.4g}, k3 {k3:.4g}) folds back "
        f"inside the {w}x{h} image (no ray for pixel row {border_row[i]:g}, col "
        f"{border_col[i]:g}): a polynomial extrapolated beyond the photos' corners. "
        "Calibrate the lens again with the board in the corners of the image"
    ]


def viewing(cam: PinholeParams) -> tuple[float, float]:
    """(height of the camera above the floor z = 0 in cm, tilt of its optical axis from
    straight down in degrees)."""
    height = float(camera_centre_cm(cam)[2])
    axis = rodrigues(np.asarray(cam.rvec, dtype=np.float64))[2]  # optical axis in the world
    tilt = math.degrees(math.acos(float(np.clip(-axis[2], -1.0, 1.0))))
    return height, tilt


def _outlier(
    rest_ssr: NDArray[np.float64] | None, expected: float, n: int
) -> tuple[int | None, list[int]]:
    """Leave-one-out: the point whose removal leaves the others best explained, if that
    explains them, and any other point whose removal would too (less well)."""
    if rest_ssr is None:
        return None, []
    stats = np.array([fit_statistic(s, expected, 2 * (n - 1) - 6) for s in rest_ssr])
    best = int(np.argmin(stats))
    if stats[best] > 1.0:
        return None, []
    others = [int(i) for i in np.argsort(stats) if i != best and stats[i] <= 1.0]
    return best, others


def pose_check(
    *,
    names: Sequence[str],
    residuals_px: NDArray[np.float64],
    residuals_cm: Sequence[float | None],
    lens: CameraIntrinsics,
    cam: PinholeParams,
    point_px: float,
    rest_ssr: NDArray[np.float64] | None = None,
    held_out: Sequence[tuple[float, float | None]] | None = None,
    alternatives: Callable[[], Sequence[tuple[str, NDArray[np.float64], int]]] | None = None,
    what: str = "the intrinsics file",
) -> LensCheck:
    """Judge a known-lens pose (see the module docstring).

    ``residuals_px``/``_cm``: each point's in-sample residual; ``rest_ssr[i]`` the other
    points' sum of squared residuals with the pose refitted without point i, and
    ``held_out[i]`` point i's held-out error (px, cm) then (5+ points); ``alternatives``:
    what makes (what the refit changed, its residuals, its degrees of freedom) for the
    lens diagnosis, called only when the points are unexplained and no outlier is found
    (the refits cost many pose fits).
    """
    n = len(names)
    height, tilt = viewing(cam)
    rms = float(np.sqrt(np.mean(np.square(residuals_px))))
    worst = int(np.argmax(residuals_px))
    check = LensCheck(
        lens_rms_px=lens.rms_px,
        point_px=point_px,
        rms_px=rms,
        camera_height_cm=height,
        tilt_deg=tilt,
        residual_cm=list(residuals_cm),
        worst=names[worst],
        worst_px=float(residuals_px[worst]),
        worst_cm=residuals_cm[worst],
        problems=lens_file_problems(lens, what),
    )
    if lens.rms_px is None:
        check.explained = False
        return check
    e = expected_px(lens.rms_px, point_px)
    check.expected_px = e
    check.allowed_rms_px = allowed_rms_px(e, n)
    check.explained = fit_statistic(_ssr(residuals_px), e, 2 * n - 6) <= 1.0
    if check.explained:
        return check
    out, also = _outlier(rest_ssr, e, n)
    if out is not None and held_out is not None:
        check.outlier = names[out]
        check.outlier_px, check.outlier_cm = held_out[out]
        check.outlier_also = [names[i] for i in also]
    elif n > 4 and alternatives is not None:
        for change, res, dof in alternatives():
            if fit_statistic(_ssr(res), e, dof) <= 1.0:
                rms_alt = float(np.sqrt(np.mean(np.square(res))))
                check.hints.append(f"{change} the points are explained (RMS {rms_alt:.3g} px)")
    check.problems.append(_not_explained(check, n, what))
    return check


def _cm(value: float | None) -> str:
    return "" if value is None else f" = {value:.3g} cm on the floor"


def _not_explained(check: LensCheck, n: int, what: str) -> str:
    """The refusal: how far off, and the point (or the lens) to blame."""
    text = (
        f"the control points are not what the lens explains: residual RMS "
        f"{check.rms_px:.3g} px, at most {check.allowed_rms_px:.3g} px expected for {n} "
        f"points from the lens's RMS {check.lens_rms_px:.3g} px (×{VIEW_NOISE:g} for one "
        f"photo) and the points' precision {check.point_px:g} px"
    )
    if check.outlier is not None:
        also = ", ".join(check.outlier_also)
        return text + (
            f"; leave-one-out names {check.outlier}: {check.outlier_px:.3g} px"
            f"{_cm(check.outlier_cm)} from where the other points put it (fix or remove it"
            + (f"; without {also} the others fit too, less well)" if also else ")")
        )
    text += f"; worst point {check.worst}: {check.worst_px:.3g} px{_cm(check.worst_cm)}"
    if n == 4:
        return text + (
            " (with 4 points the three others fix the pose, so the wrong one cannot be "
            "singled out: check every point, or add a fifth)"
        )
    if check.hints:
        return text + f"; {'; '.join(check.hints)}: {what} does not fit this camera"
    return text + (
        f"; no single point explains it: check the points' floor positions and that {what} "
        "is this camera's at this resolution"
    )
