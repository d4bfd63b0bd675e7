"""Every camera's look-up tables in one: a world frame's detections, from all its
cameras, are given their covariances and border decisions in one vectorised pass.

Each camera's :class:`~ovis.common.fusion.accuracy.AccuracyMap` (as
:class:`CameraTables`: this module reads it, the accuracy module builds its tables with
this one) tabulates, per plane
height, the position covariance (nearest node) and the pixel of every floor node (the
border test, :mod:`~ovis.common.fusion.border`). Here those tables are laid end to end
with each one's origin, shape and offset, so that one gather serves detections of any
camera and height: a world frame costs about what one camera's frame costs, not one
such pass per camera. Detections whose table does not exist (a height not tabulated,
a point off the grid, a disk near the border decision) are computed directly, per
camera.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ovis.common.camera.projection import disks_in_image
from ovis.common.config import CameraModel
from ovis.common.fusion.border import (
    ANGLES_COS,
    ANGLES_SIN,
    MAX_PLANES,
    BorderTable,
    bilinear,
    room_px,
)
from ovis.common.fusion.sightings import CXX, CYY, MARKER, R, Sightings, X, Y, Z

__all__ = ["CameraTables", "TableSet"]

FloatArray = NDArray[np.float64]


class CameraTables(Protocol):
    """What a :class:`TableSet` reads of one camera: its model, its border table, the
    plane heights it tabulated and each one's covariance grid, and covariances computed
    where no table holds them (:class:`ovis.common.fusion.accuracy.AccuracyMap` is one;
    this module does not import it, which imports this one)."""

    cam: CameraModel
    border: BorderTable

    def heights(self) -> list[float]: ...

    def prepare(self, *heights_cm: float) -> None: ...

    def cov_grid(self, z: float) -> tuple[float, float, float, int, int, FloatArray] | None: ...

    def __call__(self, x_cm: ArrayLike, y_cm: ArrayLike, z_cm: ArrayLike) -> FloatArray: ...


def _laid_end_to_end(
    tables: list[tuple[float, float, float, int, int, FloatArray]],
) -> tuple[FloatArray, FloatArray]:
    """``(x0, y0, 1/step, nx, ny, offset)`` per table and the tables' rows one after the
    other."""
    params = np.zeros((len(tables), 6))
    offset = 0
    for k, (x0, y0, step, nx, ny, values) in enumerate(tables):
        params[k] = (x0, y0, 1.0 / step, nx, ny, offset)
        offset += len(values)
    flat = np.concatenate([t[5] for t in tables]) if tables else np.zeros(0)
    return params, flat


class TableSet:
    """The tables of a set of cameras' accuracy maps, for :meth:`resolve`. Rebuilt when
    a camera's map is replaced (recalibration) or has tabulated a new height."""

    def __init__(self) -> None:
        self._key: tuple = ()
        self._ids: dict[tuple[str, float], int] = {}
        self._cov = self._rc = (np.zeros((0, 6)), np.zeros((0, 3)))
        self._frame: dict[str, tuple[complex, float]] = {}

    def _refresh(self, maps: Mapping[str, CameraTables]) -> None:
        key = tuple((n, m, len(m.heights())) for n, m in maps.items())  # maps by identity
        if key == self._key:
            return
        cov, rc, self._ids = [], [], {}
        for name, m in maps.items():
            for z in m.heights():
                plane, grid = m.border.plane(z), m.cov_grid(z)
                if plane is None or grid is None:
                    continue
                self._ids[name, z] = len(cov)
                cov.append(grid)
                rc.append((plane.x0, plane.y0, plane.step, plane.nx, plane.ny, plane.rc))
        self._cov, self._rc = _laid_end_to_end(cov), _laid_end_to_end(rc)
        #: per camera: its last pixel (row + 1j·col) and the border table's re-check band
        self._frame = {n: (complex(m.cam.rows - 1.0, m.cam.cols - 1.0), m.border.band_px)
                       for n, m in maps.items()}  # fmt: skip
        self._key = key

    def resolve(
        self, parts: Sequence[Sightings], maps: Mapping[str, CameraTables], margin_px: float
    ) -> Sightings:
        """Cameras' detections (one part per camera) as sightings: each with its
        camera's covariance there, unless it came with its own (a solid fitted to its
        silhouette, heights measured); a detection that is not a finite number, a blob
        (no marker) whose disk is not wholly inside its camera's image ``margin_px`` from
        the border (a fitted solid: its top's disk and its foot's), and a point its camera
        cannot see are left out."""
        s = Sightings.joined(list(parts))
        d = s.data.copy()
        names = s.cameras
        if not len(d):
            return Sightings(names, d, s.robot, s.cam)
        self._refresh(maps)
        # a fitted solid (its camera sent its covariance): its measured height is no plane
        # worth a table, and its silhouette reaches from its top down to its foot
        solid = np.isfinite(d[:, CXX])
        keys = [(names[c], z) for c, z in zip(s.cam.tolist(), d[:, Z].tolist(), strict=True)]
        ids = [-1 if f else self._ids.get(k, -1) for k, f in zip(keys, solid.tolist(),
                                                                   strict=True)]  # fmt: skip
        wanted = {k for k, i, f in zip(keys, ids, solid.tolist(), strict=True) if i < 0 and not f}
        if wanted:  # a height not seen before: tabulated once (bounded)
            for n, z in wanted:
                if np.isfinite(z) and len(maps[n].heights()) < MAX_PLANES:
                    maps[n].prepare(z)
            self._refresh(maps)
            ids = [-1 if f else self._ids.get(k, -1) for k, f in zip(keys, solid.tolist(),
                                                                       strict=True)]  # fmt: skip
        tid = np.array(ids, np.intp)
        keep = np.isfinite(d[:, :4]).all(axis=1)
        blob = keep & np.isnan(d[:, MARKER])
        if blob.any():
            keep[blob] = self._whole(d[blob], tid[blob], s.cam[blob], names, maps, margin_px)
        foot = blob & keep & solid
        for c in set(s.cam[foot].tolist()):  # its foot wholly inside the image too
            sel = foot & (s.cam == c)
            keep[sel] = disks_in_image(d[sel, X], d[sel, Y], np.zeros(int(sel.sum())),
                                       d[sel, R], maps[names[c]].cam, margin_px)  # fmt: skip
        d, tid, cam, robot, solid = d[keep], tid[keep], s.cam[keep], s.robot[keep], solid[keep]
        if not solid.all():
            own = ~solid
            d[own, CXX : CYY + 1] = self._covariance(d[own], tid[own], cam[own], names, maps)
        seen = np.isfinite(d[:, CXX : CYY + 1]).all(axis=1)
        if not seen.all():
            d, robot, cam = d[seen], robot[seen], cam[seen]
        return Sightings(names, d, robot, cam)

    def _whole(self, d: FloatArray, tid: NDArray[np.intp], cam: NDArray[np.intp],
               names: Sequence[str], maps: Mapping[str, CameraTables],
               margin_px: float) -> NDArray[np.bool_]:  # fmt: skip
        """Border decisions of blobs (see :class:`~ovis.common.fusion.border.BorderTable`):
        the rim points bilinear in their camera's pixel table, those near the decision
        (and those with no table) projected."""
        params, flat = self._rc
        if not len(params):
            tid = np.full_like(tid, -1)
            params = np.array([[0.0, 0.0, 1.0, 2.0, 2.0, 0.0]])
            flat = np.zeros(4, complex)
        grid = tuple(params[np.maximum(tid, 0)].T[:, :, None])  # one grid per disk
        r = d[:, R : R + 1]
        rc, on = bilinear(flat, grid, d[:, X : X + 1] + r * ANGLES_COS,
                          d[:, Y : Y + 1] + r * ANGLES_SIN)  # fmt: skip
        frame = np.array([self._frame[n] for n in names])[cam]  # last pixel, band
        room = room_px(rc, on, frame[:, :1], margin_px)
        got = room >= 0
        unsure = (np.abs(room) <= frame[:, 1].real) | (tid < 0)
        for c in set(cam[unsure].tolist()):  # near the decision: as disks_in_image says
            sel = unsure & (cam == c)
            m = maps[names[c]]
            got[sel] = disks_in_image(d[sel, X], d[sel, Y], d[sel, Z], d[sel, R], m.cam,
                                      margin_px)  # fmt: skip
        return got

    def _covariance(
        self,
        d: FloatArray,
        tid: NDArray[np.intp],
        cam: NDArray[np.intp],
        names: Sequence[str],
        maps: Mapping[str, CameraTables],
    ) -> FloatArray:
        """``(n, 3)`` covariances (xx, xy, yy): nearest node of the camera's grid, or
        computed where there is none."""
        params, flat = self._cov
        if len(params):
            x0, y0, inv, nx, ny, off = params[np.maximum(tid, 0)].T
            i = np.rint((d[:, X] - x0) * inv)
            j = np.rint((d[:, Y] - y0) * inv)
            on = (tid >= 0) & (i >= 0) & (i < nx) & (j >= 0) & (j < ny)
            out = flat.take(np.where(on, off + i * ny + j, 0).astype(np.intp), axis=0)
        else:
            on, out = np.zeros(len(d), bool), np.zeros((len(d), 3))
        if not on.all():
            for c in set(cam[~on].tolist()):
                sel = ~on & (cam == c)
                cov = maps[names[c]](d[sel, X], d[sel, Y], d[sel, Z])
                out[sel] = np.stack([cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]], axis=1)
        return out
