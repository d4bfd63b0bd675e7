"""Hybrid refinement: a local least-squares polish of the GA's camera (beyond the paper).

The GA (paper §4) searches the whole box of ranges on a 10-bit grid per variable: it
finds the right basin but stops on the grid (one step of s_x is 0.7 % of the scale,
about 1.5 px at the image edge). After it, the threshold and the size filter are fixed,
so the blobs and their matching to the control points are fixed too, and the rest is a
smooth problem: choose the continuous camera parameters
``Z0, λ, k1, k2, k3, s_x, s_y`` to minimise the per-point pixel residuals

    r_i = (row_pred,i − row_det,i, col_pred,i − col_det,i),   i = 1 … N,

bounded to the configured ranges (``scipy.optimize.least_squares``, trust-region
reflective). The variables are scaled to the unit box (``u = (x − lo)/(hi − lo)``) so that
k ~ 1e−6 and Z0 ~ 1e2 are on the same footing.

The polish never makes the DIPE (eq. 14, with its optimal matching) worse: if the
least-squares optimum has a larger mean DIPE than its start, or loses feasibility (the
size filter is in cm² through the camera), the start is kept.

:func:`fit_camera` is the general local fit, used also for leave-one-out refits
(:mod:`ovis.common.calibration.accuracy`) and for Levenberg–Marquardt from a random start
(:mod:`ovis.common.analysis.compare`), where the matching can be re-solved at every step as the
GA's fitness does.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from ovis.common.calibration.dipe import match_points, pixel_error_mm
from ovis.common.calibration.problem import CalibrationProblem, camera_with
from ovis.common.camera.paper_model import project
from ovis.common.config import CALIBRATED_VARIABLES

__all__ = [
    "CONTINUOUS",
    "CONTINUOUS_SLICE",
    "PRIOR_PX",
    "FitResult",
    "PolishResult",
    "dipe_of",
    "fit_camera",
    "matched_blobs",
    "polish",
    "refine_for_calibration",
    "residuals_px",
]

#: The continuous camera variables the polish tunes, in GA order (indices 2..8).
CONTINUOUS = CALIBRATED_VARIABLES[2:]
CONTINUOUS_SLICE = slice(2, 2 + len(CONTINUOUS))

#: Residual (px) given to a point the camera cannot project (keeps the solver finite).
UNPROJECTABLE_PX = 1.0e3
#: Weak pull of the polish towards the GA's values (px per whole range, see
#: :func:`fit_camera`): keeps the undetermined k's and λ where the GA put them.
PRIOR_PX = 0.01


class FitResult(NamedTuple):
    """A local fit: the full (9,) values, its residual cost and how the solver ended."""

    values: NDArray[np.float64]  # (9,) threshold, size filter kept; camera fitted
    rms_px: float  # RMS of the per-point residual lengths on the fitted points
    nfev: int
    success: bool
    message: str


class PolishResult(NamedTuple):
    """What the polish did: start and end DIPE (mean px over the points) and the values."""

    values: NDArray[np.float64]  # (9,) the polished values (== start if not improved)
    start_dipe_px: float
    dipe_px: float
    improved: bool  # False when the start was kept
    nfev: int


def dipe_of(problem: CalibrationProblem, values: NDArray[np.float64]) -> tuple[float, float]:
    """Mean DIPE (eq. 14) of ``values`` (9,) in px and mm, or (inf, inf) if infeasible."""
    ev = problem.evaluate(np.asarray(values, dtype=np.float64)[None, :])
    if not ev.feasible[0]:
        return float("inf"), float("inf")
    cam = camera_with(problem.config.camera, np.asarray(values, dtype=np.float64))
    pred = project(*problem.points_xyz.T, cam)
    mm = pixel_error_mm(
        ev.blob_row[0] - pred.row, ev.blob_col[0] - pred.col, cam.d_x_mm, cam.d_y_mm
    )
    return float(ev.dipe_px[0].mean()), float(np.mean(mm))


def matched_blobs(
    problem: CalibrationProblem, values: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(row, col) of the blob matched to each control point under ``values`` (9,).

    Raises ValueError when the values are infeasible (not one blob per point).
    """
    ev = problem.evaluate(np.asarray(values, dtype=np.float64)[None, :])
    if not ev.feasible[0]:
        raise ValueError(
            f"these values see {int(ev.count[0])} objects, not one per control point "
            f"({problem.n_points}); nothing to refine"
        )
    return ev.blob_row[0].copy(), ev.blob_col[0].copy()


def _residuals_batch(
    problem: CalibrationProblem,
    values: NDArray[np.float64],
    blob_row: NDArray[np.float64],
    blob_col: NDArray[np.float64],
    use: NDArray[np.bool_],
    order: NDArray[np.int64] | None,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Residuals (P, 2·n) of P value rows (P, 9) and the blob order used (n,).

    ``order`` gives the blob of each used point (default: the given order; ``-1``:
    re-solve the optimal matching on the first row and use it for every row).
    """
    cam = camera_with(problem.config.camera, values)
    xyz = problem.points_xyz[use]
    pred = project(xyz[:, 0], xyz[:, 1], xyz[:, 2], cam)  # (P, n)
    b_row, b_col = np.asarray(blob_row)[use], np.asarray(blob_col)[use]
    n = b_row.size
    if order is None:
        order = np.arange(n)
    elif order.size and order[0] < 0:
        if pred.valid[0].all():
            m = match_points(pred.row[:1], pred.col[:1], b_row[None, :], b_col[None, :])
            order = m.blob_index[0]
        else:
            order = np.arange(n)
    d_row = np.where(pred.valid, pred.row - b_row[order], UNPROJECTABLE_PX)
    d_col = np.where(pred.valid, pred.col - b_col[order], UNPROJECTABLE_PX)
    return np.concatenate([d_row, d_col], axis=1), order


def residuals_px(
    problem: CalibrationProblem,
    values: NDArray[np.float64],
    blob_row: NDArray[np.float64],
    blob_col: NDArray[np.float64],
    *,
    use: NDArray[np.bool_] | None = None,
    rematch: bool = False,
) -> NDArray[np.float64]:
    """Residuals (2·n,) predicted − detected (rows, then cols) of the used points, px.

    With ``rematch``, blobs are re-assigned to the points by the optimal matching of
    eq. 14 at these values (as the GA's fitness does) instead of the given order.
    Points the camera cannot project get :data:`UNPROJECTABLE_PX`.
    """
    use = np.ones(problem.n_points, dtype=bool) if use is None else np.asarray(use, bool)
    order = np.full(1, -1) if rematch else None
    v = np.asarray(values, dtype=np.float64)[None, :]
    return _residuals_batch(problem, v, blob_row, blob_col, use, order)[0][0]


#: Forward-difference step of the Jacobian, in units of each variable's range.
_JAC_STEP = 1e-6


def fit_camera(
    problem: CalibrationProblem,
    start: NDArray[np.float64],
    blob_row: NDArray[np.float64],
    blob_col: NDArray[np.float64],
    *,
    use: NDArray[np.bool_] | None = None,
    method: str = "trf",
    rematch: bool = False,
    max_nfev: int | None = None,
    prior_px: float = 0.0,
) -> FitResult:
    """Least-squares fit of the continuous camera variables from ``start`` (9,).

    ``method="trf"`` is bounded to the configured ranges (the polish); ``"lm"`` is
    MINPACK's Levenberg–Marquardt, unbounded (it needs at least as many residuals as
    variables: 2·n ≥ 7). The threshold and the size filter are kept from ``start``; the
    blobs (``blob_row``, ``blob_col``, one per control point) are fixed, and so is their
    matching unless ``rematch`` re-solves it at every evaluation. The Jacobian is a
    forward difference evaluated for all seven variables in one vectorised projection.

    ``prior_px`` > 0 adds the residuals ``prior_px · (u − u_start)`` (u: each variable
    on its range scaled to [0, 1]): moving a variable across its whole range then costs
    as much as a residual of ``prior_px`` pixels. Directions the data determine
    (hundreds of px per range) do not notice it; directions they do not determine (the
    k's, λ against s_x and s_y) stay at the start instead of drifting to a bound.
    """
    start = np.asarray(start, dtype=np.float64)
    use = np.ones(problem.n_points, dtype=bool) if use is None else np.asarray(use, bool)
    lo, hi = problem.bounds[CONTINUOUS_SLICE, 0], problem.bounds[CONTINUOUS_SLICE, 1]
    width = np.where(hi > lo, hi - lo, 1.0)
    u0 = (start[CONTINUOUS_SLICE] - lo) / width
    k = len(CONTINUOUS)
    bounded = method != "lm"

    def to_values(u: NDArray[np.float64]) -> NDArray[np.float64]:
        v = np.repeat(start[None, :], u.shape[0], axis=0)
        v[:, CONTINUOUS_SLICE] = lo + u * width
        return v

    def batch(u: NDArray[np.float64], order):
        return _residuals_batch(problem, to_values(u), blob_row, blob_col, use, order)

    first = np.full(1, -1) if rematch else None

    def fun(u: NDArray[np.float64]) -> NDArray[np.float64]:
        r = batch(u[None, :], first)[0][0]
        return np.concatenate([r, prior_px * (u - u0)]) if prior_px > 0 else r

    def jac(u: NDArray[np.float64]) -> NDArray[np.float64]:
        step = np.full(k, _JAC_STEP)
        if bounded:  # stay inside the box: step backwards at an upper bound
            step = np.where(u + step > 1.0, -step, step)
        rows = np.vstack([u[None, :], u[None, :] + np.diag(step)])
        r, order = batch(rows[:1], first)
        rp, _ = batch(rows[1:], order)  # same matching as the base point
        J = ((rp - r[0][None, :]) / step[:, None]).T
        return np.vstack([J, prior_px * np.eye(k)]) if prior_px > 0 else J

    if bounded:
        res = least_squares(
            fun, np.clip(u0, 0.0, 1.0), jac=jac, method=method, bounds=(0.0, 1.0),
            max_nfev=max_nfev,
        )  # fmt: skip
    else:
        res = least_squares(fun, u0, jac=jac, method="lm", max_nfev=max_nfev)
    r = res.fun[: 2 * int(use.sum())].reshape(2, -1)
    rms = float(np.sqrt(np.mean(r[0] ** 2 + r[1] ** 2)))
    values = to_values(res.x[None, :])[0]
    return FitResult(values, rms, int(res.nfev), bool(res.success), str(res.message))


def polish(problem: CalibrationProblem, values: NDArray[np.float64]) -> PolishResult:
    """Polish the GA's best ``values`` (9,) by bounded least squares on the pixel residuals.

    The blobs and their matching are those of ``values`` (its threshold and size filter).
    Returns the start unchanged (``improved = False``) when the fit would raise the mean
    DIPE or lose feasibility, so the polish never makes the calibration worse.
    """
    values = np.asarray(values, dtype=np.float64)
    start_px, _ = dipe_of(problem, values)
    if not np.isfinite(start_px):
        return PolishResult(values.copy(), start_px, start_px, False, 0)
    blob_row, blob_col = matched_blobs(problem, values)
    fit = fit_camera(problem, values, blob_row, blob_col, prior_px=PRIOR_PX)
    end_px, _ = dipe_of(problem, fit.values)
    if not end_px < start_px:
        return PolishResult(values.copy(), start_px, start_px, False, fit.nfev)
    return PolishResult(fit.values, start_px, end_px, True, fit.nfev)


def refine_for_calibration(
    problem: CalibrationProblem, values: NDArray[np.float64], *, apply: bool
) -> tuple[NDArray[np.float64], dict[str, float | bool]]:
    """Polish the GA's (centred) ``values`` and say how both fare, for the calibration file.

    Returns the values to keep (the polished ones if ``apply`` and the polish improved
    the DIPE, else ``values``) and the :class:`~ovis.common.calibration.file.Calibration`
    fields ``polished``, ``ga_dipe_px``/``mm`` and ``polish_dipe_px``/``mm``: both numbers
    are always reported, whichever camera is kept.
    """
    values = np.asarray(values, dtype=np.float64)
    ga_px, ga_mm = dipe_of(problem, values)
    result = polish(problem, values)
    pol_px, pol_mm = dipe_of(problem, result.values)
    keep = result.values if (apply and result.improved) else values
    fields: dict[str, float | bool] = {
        "polished": bool(apply and result.improved),
        "ga_dipe_px": ga_px,
        "ga_dipe_mm": ga_mm,
        "polish_dipe_px": pol_px,
        "polish_dipe_mm": pol_mm,
    }
    return keep, fields
