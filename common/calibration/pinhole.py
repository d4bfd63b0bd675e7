"""Calibration of the general (pinhole + Brown–Conrady) camera: GA, then least squares.

The paper's method (§4) carried over to :class:`~ovis.common.config.PinholeParams`:

1. **GA** over the threshold, the size filter A^f and every pinhole variable whose range
   in ``[calibration.pinhole]`` is not a single value (``fx, fy, cx, cy, k1, k2, p1, p2,
   k3``, the Rodrigues vector and the translation), minimising the mean DIPE (eq. 14)
   under the exact-count constraint (eq. 15). It is :class:`CalibrationProblem`'s
   fitness — the per-threshold blob cache, the size filter in cm² through the camera,
   the optimal blob-to-point matching — with the camera built from the pinhole
   variables (:meth:`PinholeCalibrationProblem.camera_for`).
2. **Polish**: with the GA's threshold and size filter (so its blobs and their matching)
   fixed, ``scipy.optimize.least_squares`` (trust-region reflective, bounded to the
   ranges, variables scaled to the unit box) minimises the pixel residuals
   ``(row, col)_predicted − (row, col)_detected`` of every control point over the same
   free variables; the matching is re-solved and the fit repeated if it changed. The
   polished camera is kept only if it stays feasible and lowers the mean DIPE.

A pinhole camera has 15 parameters and each control point gives two equations, so this
needs at least :data:`MIN_POINTS` control points; with few points, leave the distortion
fixed (single-value ranges) — e.g. 6 points determine a pose and four intrinsics
(12 equations, 10 unknowns) but not five distortion coefficients as well.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import NamedTuple

import msgspec
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from ovis.common.calibration.dipe import match_points
from ovis.common.calibration.file import Calibration, mm_or_none
from ovis.common.calibration.ga import GAResult, GenerationStats
from ovis.common.calibration.problem import CalibrationProblem
from ovis.common.calibration.solve import build_calibration, run_constrained_ga
from ovis.common.camera.pinhole import project
from ovis.common.config import (
    PINHOLE_VARIABLES,
    ConfigError,
    ControlPoint,
    OvisConfig,
    PinholeParams,
    PinholeRanges,
)

__all__ = [
    "MIN_POINTS",
    "PinholeCalibrationProblem",
    "PinholePolish",
    "calibrate_pinhole",
    "pinhole_values",
    "pinhole_with",
    "polish_pinhole",
]

#: Fewest control points a pinhole calibration accepts.
MIN_POINTS = 6

#: Residual (px) given to a point the camera cannot project (keeps the solver finite).
UNPROJECTABLE_PX = 1.0e3

#: Central-difference step of the Jacobian, in units of each variable's range.
_JAC_STEP = 1e-7


def pinhole_values(cam: PinholeParams) -> NDArray[np.float64]:
    """The camera's 15 variables in :data:`PINHOLE_VARIABLES` order."""
    return np.array(
        [cam.fx, cam.fy, cam.cx, cam.cy, cam.k1, cam.k2, cam.p1, cam.p2, cam.k3,
         *cam.rvec, *cam.tvec_cm],
        dtype=np.float64,
    )  # fmt: skip


def pinhole_with(cam: PinholeParams, values: NDArray[np.float64]) -> PinholeParams:
    """The camera with its 15 variables taken from ``values`` (…, 15).

    ``values`` of shape (P, 15) gives a population camera whose fields are (P, 1) arrays;
    of shape (15,), an ordinary camera (plain floats).
    """
    v = np.asarray(values, dtype=np.float64)
    f = [float(x) for x in v] if v.ndim == 1 else [v[:, i : i + 1] for i in range(v.shape[1])]
    return msgspec.structs.replace(
        cam,
        **dict(zip(("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"), f[:9], strict=True)),
        rvec=tuple(f[9:12]),
        tvec_cm=tuple(f[12:15]),
    )


class PinholeCalibrationProblem(CalibrationProblem):
    """Fitness of GA strings ``(threshold, size filter, 15 pinhole variables)``.

    The GA itself runs over the free variables only (:attr:`free`); :meth:`expand`
    fills in the fixed ones. See :class:`CalibrationProblem` for the fitness.
    """

    def __init__(
        self, image: NDArray[np.uint8], points: Sequence[ControlPoint], config: OvisConfig
    ) -> None:
        if not isinstance(config.camera, PinholeParams):
            raise ConfigError('a pinhole calibration needs camera.model = "pinhole"')
        if len(points) < MIN_POINTS:
            raise ConfigError(
                f"a pinhole calibration needs at least {MIN_POINTS} control points "
                f"(two equations each for up to 15 parameters), got {len(points)}"
            )
        super().__init__(image, points, config)
        ranges = config.calibration.pinhole or PinholeRanges()
        nominal = pinhole_values(config.camera)
        cam_bounds = []
        for name, value in zip(PINHOLE_VARIABLES, nominal, strict=True):
            pair = getattr(ranges, name)
            cam_bounds.append((value, value) if pair is None else tuple(pair))
        self.bounds = np.array(
            [self.threshold_bounds(), config.calibration.size_filter_cm2, *cam_bounds],
            dtype=np.float64,
        )
        self.variables = ("threshold", "size_filter_cm2", *PINHOLE_VARIABLES)
        #: which of the 17 values the GA and the polish tune (threshold, A^f always)
        self.free = self.bounds[:, 1] > self.bounds[:, 0]
        self.free[:2] = True
        self._fixed = self.bounds[:, 0].copy()

    def camera_for(self, values: NDArray[np.float64]) -> PinholeParams:  # type: ignore[override]
        return pinhole_with(self.config.camera, np.asarray(values)[..., 2:])

    def nominal_values(self) -> NDArray[np.float64]:
        return np.concatenate([[0.0, 0.0], pinhole_values(self.config.camera)])

    def expand(self, free_values: NDArray[np.float64]) -> NDArray[np.float64]:
        """Full (…, 17) values from the free ones (…, F)."""
        free_values = np.asarray(free_values, dtype=np.float64)
        out = np.broadcast_to(self._fixed, (*free_values.shape[:-1], self._fixed.size)).copy()
        out[..., self.free] = free_values
        return out

    def free_fitness(self, free_values: NDArray[np.float64]) -> NDArray[np.float64]:
        """The GA's objective over the free variables."""
        return self.fitness(self.expand(free_values))


class PinholePolish(NamedTuple):
    """What the least-squares polish did (mean DIPE in px before and after)."""

    values: NDArray[np.float64]  # (17,) polished values (== start when not improved)
    start_dipe_px: float
    dipe_px: float
    improved: bool
    nfev: int
    rms_px: float  # RMS residual length of the least-squares optimum


def _residuals(
    problem: PinholeCalibrationProblem,
    values: NDArray[np.float64],
    blob_row: NDArray[np.float64],
    blob_col: NDArray[np.float64],
) -> NDArray[np.float64]:
    """(P, 2N) residuals predicted − detected (rows, then cols) of (P, 17) values."""
    cam = problem.camera_for(values)
    X, Y, Z = (problem.points_xyz[:, i][None, :] for i in range(3))
    pred = project(X, Y, Z, cam)
    d_row = np.where(pred.valid, pred.row - blob_row, UNPROJECTABLE_PX)
    d_col = np.where(pred.valid, pred.col - blob_col, UNPROJECTABLE_PX)
    return np.concatenate([d_row, d_col], axis=1)


def _fit(
    problem: PinholeCalibrationProblem,
    start: NDArray[np.float64],
    blob_row: NDArray[np.float64],
    blob_col: NDArray[np.float64],
):
    """Bounded least squares over the free camera variables, blobs fixed."""
    tune = problem.free.copy()
    tune[:2] = False  # threshold and size filter stay
    lo, hi = problem.bounds[tune, 0], problem.bounds[tune, 1]
    width = hi - lo
    k = int(tune.sum())

    def to_values(u: NDArray[np.float64]) -> NDArray[np.float64]:
        v = np.repeat(start[None, :], u.shape[0], axis=0)
        v[:, tune] = lo + u * width
        return v

    def fun(u: NDArray[np.float64]) -> NDArray[np.float64]:
        return _residuals(problem, to_values(u[None, :]), blob_row, blob_col)[0]

    def jac(u: NDArray[np.float64]) -> NDArray[np.float64]:
        h = _JAC_STEP
        up = np.minimum(u + h, 1.0)
        down = np.maximum(u - h, 0.0)
        eye = np.eye(k, dtype=bool)
        rows = np.vstack([np.where(eye, up, u), np.where(eye, down, u)])
        r = _residuals(problem, to_values(rows), blob_row, blob_col)
        return ((r[:k] - r[k:]) / (up - down)[:, None]).T

    u0 = np.clip((start[tune] - lo) / width, 0.0, 1.0)
    res = least_squares(
        fun, u0, jac=jac, method="trf", bounds=(0.0, 1.0), x_scale=1.0,
        ftol=1e-15, xtol=1e-15, gtol=1e-15, max_nfev=200 * (k + 1),
    )  # fmt: skip
    r = res.fun.reshape(2, -1)
    rms = float(np.sqrt(np.mean(r[0] ** 2 + r[1] ** 2)))
    return to_values(res.x[None, :])[0], rms, int(res.nfev)


def _dipe(problem: PinholeCalibrationProblem, values: NDArray[np.float64]) -> float:
    ev = problem.evaluate(values[None, :])
    return float(ev.fitness[0]) if ev.feasible[0] else float("inf")


def polish_pinhole(
    problem: PinholeCalibrationProblem, values: NDArray[np.float64], *, rounds: int = 3
) -> PinholePolish:
    """Least-squares polish of the GA's best ``values`` (17,) (see the module docstring).

    The blobs are those of ``values``' threshold and size filter, matched to the points
    by eq. 14's optimal assignment; after a fit the matching is re-solved and, if it
    changed, the fit repeated (up to ``rounds`` times). Never returns a worse or
    infeasible camera than the start.
    """
    start = np.asarray(values, dtype=np.float64)
    start_px = _dipe(problem, start)
    if not np.isfinite(start_px) or problem.free[2:].sum() == 0:
        return PinholePolish(start.copy(), start_px, start_px, False, 0, float("nan"))
    ev = problem.evaluate(start[None, :])
    blob_row, blob_col = ev.blob_row[0].copy(), ev.blob_col[0].copy()
    current, nfev, rms = start, 0, float("nan")
    for _ in range(max(1, rounds)):
        current, rms, n = _fit(problem, current, blob_row, blob_col)
        nfev += n
        cam = problem.camera_for(current)
        pred = project(*problem.points_xyz.T, cam)
        if not pred.valid.all():
            break
        m = match_points(pred.row[None, :], pred.col[None, :], blob_row[None, :], blob_col[None, :])
        order = m.blob_index[0]
        if np.array_equal(order, np.arange(order.size)):
            break
        blob_row, blob_col = blob_row[order], blob_col[order]
    end_px = _dipe(problem, current)
    if not end_px < start_px:
        return PinholePolish(start.copy(), start_px, start_px, False, nfev, rms)
    return PinholePolish(current, start_px, end_px, True, nfev, rms)


def calibrate_pinhole(
    image: NDArray[np.uint8],
    points: Sequence[ControlPoint],
    config: OvisConfig,
    *,
    on_generation: Callable[[GenerationStats], None] | None = None,
    source: str = "",
    dedupe: bool = True,
    polish: bool | None = None,
) -> tuple[Calibration, GAResult]:
    """GA + least-squares calibration of a pinhole camera on one frame.

    ``polish`` (default: ``config.ga.polish``) runs :func:`polish_pinhole` after the GA.
    Returns the calibration (its camera the polished one when that is better; threshold
    and size filter centred as configured; ``polished``, ``ga_dipe_*`` and
    ``polish_dipe_*`` filled in as for the paper model) and the GA run (whose
    ``best_values``/``best_fitness`` are the full 17 values and mean DIPE of the GA
    alone). Raises :class:`InfeasibleCalibrationError` when no string sees one object
    per point.
    """
    t0 = time.perf_counter()
    problem = PinholeCalibrationProblem(image, points, config)
    result = run_constrained_ga(
        problem,
        problem.free_fitness,
        problem.bounds[problem.free],
        on_generation=on_generation,
        dedupe=dedupe,
    )
    ga_values = problem.expand(result.best_values)
    result = result._replace(best_values=ga_values)
    best = ga_values
    improved = False
    if config.ga.polish if polish is None else polish:
        polished = polish_pinhole(problem, ga_values)
        best, improved = polished.values, polished.improved
    elapsed = time.perf_counter() - t0
    calib = build_calibration(
        problem, result._replace(best_values=best), elapsed=elapsed, source=source
    )
    # The GA's own camera and the polished one, both at the final image settings.
    pitch = config.camera.d_x_mm
    final = np.array([calib.image.threshold, calib.image.size_filter_cm2])
    ga_px = _dipe(problem, np.concatenate([final, ga_values[2:]]))
    ga_px = ga_px if np.isfinite(ga_px) else None
    return msgspec.structs.replace(
        calib,
        # build_calibration records what the GA chose from the values it is given.
        ga_threshold=int(np.rint(ga_values[0])),
        ga_size_filter_cm2=float(ga_values[1]),
        polished=improved,
        ga_dipe_px=ga_px,
        ga_dipe_mm=None if ga_px is None else mm_or_none(ga_px * pitch),
        polish_dipe_px=calib.dipe_px if improved else None,
        polish_dipe_mm=calib.dipe_mm if improved else None,
    ), result
