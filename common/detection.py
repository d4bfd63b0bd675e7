"""One frame → robot and obstacles on the floor, and the motion planner's inputs.

The paper's pipeline (§3) with a calibration: median step, binarization, 8-connected
labeling, size filter A^f (cm² on the floor, through the camera), Koplowitz–Bruckstein
perimeter and compactness (eq. 13); then each blob's centroid is back-projected onto the
plane of its class's top face (robot or obstacle height) to get its world position, its
radius is that of the disk of equal floor area, and the orientation of non-circular
shapes comes from second moments carried onto the floor.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal, NamedTuple

import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.config import CameraModel, ImageParams, PoseConfig
from ovis.common.labeling import filter_components, label_components
from ovis.common.perimeter import perimeter
from ovis.common.planner import planner_inputs
from ovis.common.pose import ROBOT_ID, Tracker, pick_robot
from ovis.common.preprocess import as_gray, binarize, smooth
from ovis.common.projection import PixelJacobian, pixel_footprint_cm2, pixel_jacobian
from ovis.common.shape import compactness, orientation

__all__ = [
    "Blobs",
    "DetectedObject",
    "Detection",
    "Detector",
    "PlannerEntry",
    "find_blobs",
    "measure_blobs",
    "size_filter_px",
    "world_shape",
]

#: Blobs less elongated than this (major/minor axis) get no heading.
ROUND_ELONGATION = 1.15


#: A finite number (decoding refuses NaN and ±inf).
Finite = Annotated[float, msgspec.Meta(ge=-1e12, le=1e12)]
NonNegative = Annotated[float, msgspec.Meta(ge=0.0, le=1e12)]


class DetectedObject(msgspec.Struct, kw_only=True):
    """One object seen in a frame: image measurements and world pose."""

    id: Annotated[int, msgspec.Meta(ge=0)]
    kind: Literal["robot", "obstacle"]
    row: Finite
    col: Finite
    area_px: NonNegative
    perimeter_px: NonNegative
    compactness: NonNegative
    x_cm: Finite
    y_cm: Finite
    z_cm: Finite
    radius_cm: NonNegative
    area_cm2: NonNegative
    heading_deg: Finite | None = None
    elongation: NonNegative = 1.0
    vx_cm_s: Finite = 0.0
    vy_cm_s: Finite = 0.0


class PlannerEntry(msgspec.Struct, kw_only=True):
    """Motion-planner inputs for one obstacle (model-notes §6)."""

    obstacle_id: Annotated[int, msgspec.Meta(ge=0)]
    distance_cm: Finite
    angle_deg: Annotated[float, msgspec.Meta(gt=-180.0, le=180.0)]


class Detection(msgspec.Struct, kw_only=True):
    """Everything found in one frame."""

    objects: list[DetectedObject]
    planner: list[PlannerEntry]


class Blobs(NamedTuple):
    """Size-filtered blobs of a frame, (n,) arrays of image measurements (pixels)."""

    row: NDArray[np.float64]
    col: NDArray[np.float64]
    area_px: NDArray[np.float64]
    perimeter_px: NDArray[np.float64]
    compactness: NDArray[np.float64]
    mu_rr: NDArray[np.float64]
    mu_cc: NDArray[np.float64]
    mu_rc: NDArray[np.float64]


def find_blobs(
    image: NDArray[np.uint8],
    params: ImageParams,
    camera: CameraModel,
    plane_cm: float,
    *,
    min_area_px: float = 0.0,
) -> Blobs:
    """Paper §3 on one frame: smooth, binarize, label, size-filter (cm² on ``plane_cm``)."""
    gray = as_gray(image)
    if gray.shape != (camera.rows, camera.cols):
        raise ValueError(
            f"frame is {gray.shape[1]}x{gray.shape[0]} (cols x rows) but the calibration "
            f"is for {camera.cols}x{camera.rows}"
        )
    binary = binarize(smooth(gray, params.median), params.threshold, params.polarity)
    return measure_blobs(binary, params, camera, plane_cm, min_area_px=min_area_px)


def size_filter_px(params: ImageParams, camera: CameraModel, plane_cm: float) -> float:
    """A lower bound, in pixels, of the blobs the size filter A^f (cm²) can keep anywhere
    in the frame: A^f over the largest pixel footprint (sampled on a 9×9 grid, with a 25 %
    margin). Smaller specks are skipped before they are measured."""
    r, c = np.meshgrid(np.linspace(0, camera.rows - 1, 9), np.linspace(0, camera.cols - 1, 9))
    largest = float(np.max(pixel_footprint_cm2(r, c, camera, plane_cm)))
    return params.size_filter_cm2 / (1.25 * largest) if largest > 0 else 0.0


def measure_blobs(
    binary: NDArray[np.uint8],
    params: ImageParams,
    camera: CameraModel,
    plane_cm: float,
    *,
    min_area_px: float = 0.0,
) -> Blobs:
    """Label a binary frame (8-connected), size-filter in cm² on ``plane_cm``, measure.

    ``min_area_px`` (see :func:`size_filter_px`) skips specks early; it must not exceed
    what the size filter would keep.
    """
    comp = label_components(binary, min_area_px=min_area_px)
    footprint = pixel_footprint_cm2(comp.row, comp.col, camera, plane_cm)
    keep = (footprint > 0) & (comp.area_px * footprint >= params.size_filter_cm2)
    comp = filter_components(comp, keep)
    perim = perimeter(comp, params.perimeter)
    return Blobs(
        comp.row,
        comp.col,
        comp.area_px,
        perim,
        compactness(comp.area_px, perim),
        comp.mu_rr,
        comp.mu_cc,
        comp.mu_rc,
    )


def world_shape(
    blobs: Blobs, j: PixelJacobian
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Floor area (cm²), major-axis heading (deg CCW from +X, in (−90, 90]) and elongation
    of each blob, given the pixel → floor Jacobian ``j`` at its centroid on its plane.

    The image second moments are carried to the floor through J (Σ_world = J·Σ_image·Jᵀ):
    perspective and unequal s_x, s_y shear a shape, so the image's principal axes are
    not the floor's.
    """
    a, b, c, d = j.dx_drow, j.dx_dcol, j.dy_drow, j.dy_dcol
    area_cm2 = blobs.area_px * j.area_cm2
    m_rr, m_cc, m_rc = blobs.mu_rr, blobs.mu_cc, blobs.mu_rc
    s_xx = a * a * m_rr + 2 * a * b * m_rc + b * b * m_cc
    s_yy = c * c * m_rr + 2 * c * d * m_rc + d * d * m_cc
    s_xy = a * c * m_rr + (a * d + b * c) * m_rc + b * d * m_cc
    angle, elongation = orientation(s_xx, s_yy, s_xy)
    heading = np.degrees(angle)
    return area_cm2, np.where(heading == -90.0, 90.0, heading), elongation


class Detector:
    """Frame → :class:`Detection` with a calibration, keeping obstacle ids across frames."""

    def __init__(self, camera: CameraModel, image: ImageParams, pose: PoseConfig) -> None:
        self.camera = camera
        self.image = image
        self.pose = pose
        self.tracker = Tracker(pose.track_gate_cm)
        self._last_stamp: float | None = None
        self.min_area_px = size_filter_px(image, camera, pose.obstacle_height_cm)

    def recalibrate(self, camera: CameraModel, image: ImageParams, pose: PoseConfig) -> None:
        """Use a new calibration; obstacle identities are kept."""
        self.camera, self.image, self.pose = camera, image, pose
        self.tracker.gate_cm = pose.track_gate_cm
        self.min_area_px = size_filter_px(image, camera, pose.obstacle_height_cm)

    def detect(
        self,
        frame: NDArray[np.uint8],
        *,
        goal_xy: tuple[float, float] | None = None,
        goal_angle_deg: float | None = None,
        stamp_s: float | None = None,
    ) -> Detection:
        """Find the robot and obstacles; planner inputs when a goal is known.

        The goal defaults to the calibration's ``pose.goal_cm``/``goal_angle_deg``.
        ``stamp_s`` is the frame's capture time (s); without it frames are taken to be
        the paper's Δt = 1 s apart. Obstacle velocities are in cm/s.
        """
        return self.from_blobs(
            find_blobs(
                frame,
                self.image,
                self.camera,
                self.pose.obstacle_height_cm,
                min_area_px=self.min_area_px,
            ),
            goal_xy=goal_xy,
            goal_angle_deg=goal_angle_deg,
            stamp_s=stamp_s,
        )

    def from_blobs(
        self,
        blobs: Blobs,
        *,
        goal_xy: tuple[float, float] | None = None,
        goal_angle_deg: float | None = None,
        stamp_s: float | None = None,
    ) -> Detection:
        """The pose half of :meth:`detect`, from already measured blobs."""
        cam, pose = self.camera, self.pose
        comp = blobs
        n = comp.area_px.size
        # The floor map at each centroid on both planes (robot, obstacle), in one go.
        heights = np.array([[pose.robot_height_cm], [pose.obstacle_height_cm]])
        both = pixel_jacobian(comp.row[None, :], comp.col[None, :], cam, heights)
        robot = pick_robot(blobs.compactness, comp.area_px * both.area_cm2[0], pose)
        is_robot = np.arange(n) == robot
        z = np.where(is_robot, pose.robot_height_cm, pose.obstacle_height_cm)
        j = PixelJacobian(*(np.where(is_robot, f[0], f[1]) for f in both))
        area_cm2, heading, elongation = world_shape(blobs, j)
        radius = np.sqrt(area_cm2 / np.pi)
        ok = j.valid
        obstacle = ok & ~is_robot
        ids = np.full(n, -1, dtype=np.int64)
        vel = np.zeros((n, 2))
        ids[is_robot] = ROBOT_ID
        obs_xy = np.column_stack([j.x_cm, j.y_cm])[obstacle]
        ids[obstacle], step = self.tracker.update(obs_xy)
        now = stamp_s if stamp_s is not None else (self._last_stamp or 0.0) + 1.0
        dt = now - self._last_stamp if self._last_stamp is not None else 1.0
        self._last_stamp = now
        vel[obstacle] = step / dt if dt > 0 else 0.0
        objects = [
            DetectedObject(
                id=int(ids[i]),
                kind="robot" if is_robot[i] else "obstacle",
                row=float(comp.row[i]),
                col=float(comp.col[i]),
                area_px=float(comp.area_px[i]),
                perimeter_px=float(blobs.perimeter_px[i]),
                compactness=float(blobs.compactness[i]),
                x_cm=float(j.x_cm[i]),
                y_cm=float(j.y_cm[i]),
                z_cm=float(z[i]),
                radius_cm=float(radius[i]),
                area_cm2=float(area_cm2[i]),
                heading_deg=float(heading[i]) if elongation[i] >= ROUND_ELONGATION else None,
                elongation=float(elongation[i]),
                vx_cm_s=float(vel[i, 0]),
                vy_cm_s=float(vel[i, 1]),
            )
            for i in np.flatnonzero(ok)
        ]
        objects.sort(key=lambda o: o.id)
        return Detection(objects=objects, planner=self._plan(objects, goal_xy, goal_angle_deg))

    def _plan(
        self,
        objects: list[DetectedObject],
        goal_xy: tuple[float, float] | None,
        goal_angle_deg: float | None,
    ) -> list[PlannerEntry]:
        if goal_xy is None and goal_angle_deg is None:
            goal_xy, goal_angle_deg = self.pose.goal_cm, self.pose.goal_angle_deg
        robots = [o for o in objects if o.kind == "robot"]
        obstacles = [o for o in objects if o.kind == "obstacle"]
        if not robots or not obstacles or (goal_xy is None and goal_angle_deg is None):
            return []
        r = robots[0]
        at_goal = (
            goal_xy is not None and math.hypot(goal_xy[0] - r.x_cm, goal_xy[1] - r.y_cm) < 1e-9
        )
        if goal_angle_deg is None and at_goal:
            return []
        inputs = planner_inputs(
            (r.x_cm, r.y_cm),
            [(o.x_cm, o.y_cm, o.radius_cm) for o in obstacles],
            goal_xy=goal_xy,
            goal_angle_deg=goal_angle_deg,
        )
        return [
            PlannerEntry(obstacle_id=o.id, distance_cm=float(d), angle_deg=float(a))
            for o, d, a in zip(obstacles, inputs.distance_cm, inputs.angle_deg, strict=True)
        ]
