"""A camera's expected position error at a floor point: its pixel error pushed through
the back-projection Jacobian (cm per px there, see
:func:`ovis.common.camera.projection.pixel_jacobian`). Far from the camera, or seen
obliquely, one pixel covers more floor, so that camera's sighting weighs less. Also a
camera's detections as columns (:func:`detection_columns`) and as sightings
(:func:`sightings_of`: covariances, blobs cut by the image border left out)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ovis.common.camera.projection import disks_in_image, pixel_jacobian, project
from ovis.common.config import CameraModel
from ovis.common.fusion.border import BorderTable, floor_seen
from ovis.common.fusion.sightings import (
    COLUMNS,
    CXX,
    CXY,
    CYY,
    MARKER,
    R,
    Sightings,
    X,
    Y,
    Z,
    detection_row,
)
from ovis.common.fusion.tables import TableSet

__all__ = ["AccuracyMap", "detection_columns", "position_covariance", "sightings_of"]

FloatArray = NDArray[np.float64]

#: a blob (no marker) whose disk comes closer than this (pixels) to the image border is
#: taken as cut by it: its centre is biased towards the inside, so it is left out (the
#: overlapping camera sees it whole)
CUT_MARGIN_PX = 0.5


def position_covariance(
    x_cm: ArrayLike, y_cm: ArrayLike, z_cm: ArrayLike, cam: CameraModel, pixel_sigma_px: float
) -> FloatArray:
    """``(n, 2, 2)`` covariance (cm²) of the floor position ``cam`` measures at the
    points ``(x, y)`` on the plane ``z``, for an isotropic pixel error of
    ``pixel_sigma_px``: ``σ² J Jᵀ`` with ``J = ∂(X, Y)/∂(row, col)``. Points the camera
    does not see get an infinite covariance (no weight)."""
    x, y, z = np.broadcast_arrays(
        *(np.atleast_1d(np.asarray(v, float)) for v in (x_cm, y_cm, z_cm))
    )
    p = project(x, y, z, cam)
    jac = pixel_jacobian(p.row, p.col, cam, z)
    J = np.stack(
        [
            np.stack([jac.dx_drow, jac.dx_dcol], axis=-1),
            np.stack([jac.dy_drow, jac.dy_dcol], axis=-1),
        ],
        axis=-2,
    ).reshape(-1, 2, 2)
    cov = pixel_sigma_px**2 * J @ np.swapaxes(J, -1, -2)
    ok = (np.asarray(p.valid) & np.asarray(jac.valid)).reshape(-1) & np.isfinite(cov).all((1, 2))
    cov[~ok] = np.diag([np.inf, np.inf])
    return cov


class AccuracyMap:
    """:func:`position_covariance` of one camera tabulated on a floor grid of
    ``step_cm`` per plane height (built on first use of a height, one vectorised call),
    so that a frame's sightings cost a look-up, not a back-projection each: the
    covariance changes smoothly over a few cm. Points off the grid are computed. It
    also holds the camera's :class:`~ovis.common.fusion.border.BorderTable` (is a blob
    wholly inside the image), built with it."""

    def __init__(self, cam: CameraModel, pixel_sigma_px: float, step_cm: float = 2.0) -> None:
        self.cam, self.sigma, self.step = cam, pixel_sigma_px, step_cm
        self.border = BorderTable(cam)
        self._grids: dict[float, tuple[float, float, FloatArray]] = {}
        self._heights: list[float] = []
        #: this camera's tables, for :func:`sightings_of` on its own
        self.tables = TableSet()

    def _grid(self, z: float) -> tuple[float, float, FloatArray]:
        key = round(z, 1)
        grid = self._grids.get(key)
        if grid is None:
            x, y, _ = floor_seen(self.cam, key)
            if x.size == 0:
                grid = (0.0, 0.0, np.full((0, 0, 2, 2), np.inf))
            else:
                x0, y0 = float(x.min()) - self.step, float(y.min()) - self.step
                gx = np.arange(x0, float(x.max()) + 2 * self.step, self.step)
                gy = np.arange(y0, float(y.max()) + 2 * self.step, self.step)
                X, Y = np.meshgrid(gx, gy, indexing="ij")
                cov = position_covariance(X.ravel(), Y.ravel(), key, self.cam, self.sigma)
                grid = (x0, y0, cov.reshape(len(gx), len(gy), 2, 2))
            self._grids[key] = grid
        return grid

    def prepare(self, *heights_cm: float) -> None:
        """Build the grids and border tables of these plane heights now (at start, not
        on a frame)."""
        for z in heights_cm:
            self._grid(z)
        self.border.prepare(*heights_cm)
        self._heights += [float(z) for z in heights_cm if float(z) not in self._heights]

    def heights(self) -> list[float]:
        """The plane heights prepared (tabulated), in order."""
        return list(self._heights)

    def cov_grid(self, z: float) -> tuple[float, float, float, int, int, FloatArray] | None:
        """The covariance grid of plane ``z`` laid flat: origin, step, shape and the
        ``(nx·ny, 3)`` covariances (xx, xy, yy) row by row; None if it is empty."""
        x0, y0, cov = self._grid(z)
        if not cov.size:
            return None
        nx, ny = cov.shape[:2]
        flat = np.stack([cov[..., 0, 0], cov[..., 0, 1], cov[..., 1, 1]], axis=-1)
        return x0, y0, self.step, nx, ny, flat.reshape(-1, 3)

    def whole(
        self, x_cm: ArrayLike, y_cm: ArrayLike, z_cm: ArrayLike, radius_cm: ArrayLike
    ) -> NDArray[np.bool_]:
        """Per disk: wholly inside the image, :data:`CUT_MARGIN_PX` from its border."""
        return self.border.whole(x_cm, y_cm, z_cm, radius_cm, CUT_MARGIN_PX)

    def __call__(self, x_cm: ArrayLike, y_cm: ArrayLike, z_cm: ArrayLike) -> FloatArray:
        """``(n, 2, 2)`` covariances at the points (nearest grid node)."""
        x, y, z = np.broadcast_arrays(
            *(np.atleast_1d(np.asarray(v, float)) for v in (x_cm, y_cm, z_cm))
        )
        out = np.empty((x.size, 2, 2))
        for height in set(z.tolist()):
            sel = z == height
            x0, y0, cov = self._grid(height)
            i = np.rint((x[sel] - x0) / self.step)
            j = np.rint((y[sel] - y0) / self.step)
            on = (i >= 0) & (i < cov.shape[0]) & (j >= 0) & (j < cov.shape[1])
            if on.all():
                out[sel] = cov[i.astype(np.intp), j.astype(np.intp)]
                continue
            got = np.empty((int(sel.sum()), 2, 2))
            got[on] = cov[i[on].astype(np.intp), j[on].astype(np.intp)]
            got[~on] = position_covariance(x[sel][~on], y[sel][~on], height, self.cam, self.sigma)
            out[sel] = got
        return out


def detection_columns(camera: str, objects: list[dict[str, Any]]) -> Sightings:
    """Detections as mappings (``kind, x_cm, y_cm, z_cm, radius_cm``, optionally
    ``marker_id``, ``heading_deg`` and a measured height's ``covariance_cm2``,
    ``z_source``, ``z_unmeasured``, see :func:`detection_row`) as columns, their
    covariances not known yet (NaN) unless they came with them."""
    rows = [
        detection_row(o["x_cm"], o["y_cm"], o["z_cm"], o["radius_cm"],
                      heading_deg=o.get("heading_deg"), marker_id=o.get("marker_id"),
                      covariance_cm2=o.get("covariance_cm2"),
                      z_source=o.get("z_source", "configured"),
                      z_unmeasured=o.get("z_unmeasured", ""), z_fit_cm=o.get("z_fit_cm"))
        for o in objects
    ]  # fmt: skip
    return Sightings(
        (camera,),
        np.array(rows, float).reshape(-1, COLUMNS),
        np.array([o["kind"] == "robot" for o in objects], bool),
        resolved=False,
    )


def sightings_of(
    camera: str,
    cam: CameraModel | AccuracyMap,
    objects: list[dict[str, Any]] | Sightings,
    pixel_sigma_px: float,
) -> Sightings:
    """One camera's detections (columns, or mappings as :func:`detection_columns`
    takes) as sightings with that camera's position covariance at each (see
    :func:`position_covariance`; from the camera's :class:`AccuracyMap` when given one,
    then ``pixel_sigma_px`` is the map's), unless it came with its own (a fitted solid).
    A blob that the image border cuts (no marker, its disk not wholly inside the image,
    a fitted solid's top or foot, see :data:`CUT_MARGIN_PX`) is left out, and so is a
    detection with a position or radius that is not a finite number."""
    found = objects if isinstance(objects, Sightings) else detection_columns(camera, objects)
    if isinstance(cam, AccuracyMap):
        return cam.tables.resolve([found], {camera: cam}, CUT_MARGIN_PX)
    d = found.data.copy()
    keep = np.isfinite(d[:, [X, Y, Z, R]]).all(axis=1)
    blob = keep & np.isnan(d[:, MARKER])
    solid = np.isfinite(d[:, CXX])  # came with its covariance: a fitted solid
    for z, sel in ((d[:, Z], blob), (np.zeros(len(d)), blob & solid)):  # top, then foot
        if sel.any():
            b = d[sel]
            keep[sel] &= disks_in_image(b[:, X], b[:, Y], z[sel], b[:, R], cam, CUT_MARGIN_PX)
    d, robot, solid = d[keep], found.robot[keep], solid[keep]
    own = ~solid
    if own.any():
        b = d[own]
        cov = position_covariance(b[:, X], b[:, Y], b[:, Z], cam, pixel_sigma_px)
        d[own, CXX], d[own, CXY], d[own, CYY] = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    seen = np.isfinite(d[:, CXX : CYY + 1]).all(axis=1)
    return Sightings((camera,), d[seen], robot[seen])
