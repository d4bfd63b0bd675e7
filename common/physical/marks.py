"""The floor marks as a user calibrates on them: their pixels measured in a picture of the
empty floor, and the camera's pose over the floor solved from them with a known lens.

A floor mark is a flat white disc at a known place on the floor (:class:`FloorMark`).
In the empty floor (:meth:`PhysicalWorld.clean` with ``solids=False``) each one is a
small bright blob; its pixel is the blob's centroid weighted by how much brighter than
the floor each pixel is (the anti-aliased rim counts by its coverage), which is where a
careful click or a blob detector puts it. Which blob is which mark is what the user knows
(the mark nearest to where the camera projects it); the pixel comes from the image only.

With the lens known (:func:`lens_of`: the configured pinhole camera's intrinsics, as
``ovis intrinsics`` measures them), :func:`calibrate_on_marks` solves the pose by
:func:`ovis.common.calibration.floor.solve_floor_pose`, exactly as ``ovis calibrate
--intrinsics CAM.yaml --points points.toml`` does with the measured points.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from ovis.common.calibration.file import Calibration
from ovis.common.calibration.floor import solve_floor_pose
from ovis.common.camera.intrinsics import CameraIntrinsics
from ovis.common.camera.pinhole import camera_matrix, distortion_coefficients
from ovis.common.camera.projection import project
from ovis.common.config import CameraModel, ControlPoint, OvisConfig, PinholeParams
from ovis.common.physical.model import PRINT_CM
from ovis.common.physical.scene import FloorMark

__all__ = [
    "MATCH_PX",
    "EmptyFloor",
    "calibrate_on_marks",
    "empty_floor",
    "lens_of",
    "measure_marks",
]

#: A blob is a mark's when its centroid lies within this many pixels of where the camera
#: projects the mark (beyond the mark's own projected radius).
MATCH_PX = 6.0
#: A mark is measured only when its disc lies this far (pixels) inside the image.
BORDER_PX = 2.0


class EmptyFloor(NamedTuple):
    """A picture of the empty floor and the marks on it."""

    image: NDArray[np.uint8]
    marks: list[FloorMark]


def lens_of(camera: PinholeParams) -> CameraIntrinsics:
    """The camera's lens (K and distortion) as an intrinsics file holds it, exact (RMS 0)."""
    return CameraIntrinsics(
        width=int(camera.cols),
        height=int(camera.rows),
        camera_matrix=tuple(tuple(float(v) for v in row) for row in camera_matrix(camera)),
        dist=tuple(float(v) for v in distortion_coefficients(camera)),
        rms_px=0.0,
    )


def empty_floor(config: OvisConfig, camera: CameraModel | None = None) -> EmptyFloor:
    """The physical world of ``config`` (its seed, ``[service] seed``, and camera, as the
    live source builds it) pictured empty by ``camera`` (default the configured one):
    the floor with its marks, no solid, no sensor noise."""
    from ovis.common.physical.scene import random_scene
    from ovis.common.physical.world import PhysicalWorld

    camera = config.camera if camera is None else camera
    scene = random_scene(config, config.service.seed, [config.camera])
    world = PhysicalWorld(scene, config, [camera])
    try:
        return EmptyFloor(world.clean(solids=False), scene.marks)
    finally:
        world.close()


def _blobs(floor: NDArray[np.uint8]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(row, col) of every bright blob of the empty floor, each the centroid weighted by
    its pixels' excess over the floor's level (its rim included: one pixel round it)."""
    grey = floor.astype(np.float32)
    level = float(np.median(grey))
    excess = np.clip(grey - level, 0.0, None)
    peak = float(excess.max())
    if peak <= 0.0:
        return np.zeros(0), np.zeros(0)
    binary = (excess > 0.5 * peak).astype(np.uint8)
    n, labels = cv2.connectedComponents(binary, connectivity=8)
    grown = cv2.dilate(labels.astype(np.float32), np.ones((3, 3), np.uint8)).astype(np.int64)
    rows, cols = np.indices(floor.shape, dtype=np.float64)
    w = excess.astype(np.float64).ravel()
    ids = grown.ravel()
    total = np.bincount(ids, weights=w, minlength=n)[1:]
    row = np.bincount(ids, weights=w * rows.ravel(), minlength=n)[1:] / total
    col = np.bincount(ids, weights=w * cols.ravel(), minlength=n)[1:] / total
    return row, col


def measure_marks(
    floor: NDArray[np.uint8], marks: Sequence[FloorMark], camera: CameraModel
) -> list[ControlPoint]:
    """The marks seen in ``floor`` (a grey picture of the empty floor) as control points
    at the centres of their top faces (the printed disc is ``PRINT_CM`` thick) with their
    measured pixels (``row``, ``col``); a mark with no blob near where
    ``camera`` projects it (outside the image, or hidden) is left out."""
    if not marks:
        return []
    row, col = _blobs(floor)
    x = np.array([m.x_cm for m in marks])
    y = np.array([m.y_cm for m in marks])
    z = np.full_like(x, PRINT_CM)  # the printed disc's top
    p = project(x, y, z, camera)
    if row.size == 0:
        return []
    cost = np.hypot(p.row[:, None] - row[None], p.col[:, None] - col[None])
    cost[~np.asarray(p.valid)] = np.inf
    mi, bi = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e9))
    # how far the mark's own rim reaches in the image: its radius at its place
    rim = project(x + np.array([m.radius_cm for m in marks]), y, z, camera)
    radius = np.hypot(rim.row - p.row, rim.col - p.col)
    reach = radius + MATCH_PX
    # a mark cut by the image border has its blob's centroid off its centre: left out
    edge = radius + BORDER_PX
    rows, cols = floor.shape[:2]
    whole = (p.row >= edge) & (p.row <= rows - 1 - edge) & (p.col >= edge)
    whole &= p.col <= cols - 1 - edge
    points = []
    for m, b in sorted(zip(mi, bi, strict=True)):
        if cost[m, b] <= reach[m] and whole[m]:
            mark = marks[m]
            points.append(
                ControlPoint(
                    name=mark.name,
                    x_cm=mark.x_cm,
                    y_cm=mark.y_cm,
                    z_cm=PRINT_CM,
                    row=float(row[b]),
                    col=float(col[b]),
                )
            )
    return points


def calibrate_on_marks(
    points: Sequence[ControlPoint], camera: PinholeParams, config: OvisConfig, *, source: str
) -> Calibration:
    """The camera's pose over the floor from the measured marks (:func:`measure_marks`),
    its lens fixed at ``camera``'s (:func:`lens_of`), with ``config``'s image and pose
    settings. Raises ``FloorPoseError`` when the marks cannot give a pose (too few seen)."""
    return solve_floor_pose(
        lens_of(camera),
        points,
        image_size=(int(camera.cols), int(camera.rows)),
        image=config.image,
        pose=config.pose,
        pixel_pitch_mm=camera.pixel_pitch_mm,
        source=source,
        lens_name="the configured camera's lens",
    )
