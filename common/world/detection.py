"""One frame → robot and obstacles on the floor, and the motion planner's inputs.

The paper's pipeline (§3) with a calibration: median step, binarization, 8-connected
labeling, size filter A^f (cm² on the floor, through the camera; the background is never
an object, :mod:`ovis.common.vision.objects`), Koplowitz–Bruckstein
perimeter and compactness (eq. 13); then each blob's centroid is back-projected onto the
plane of its class's top face (robot or obstacle height) to get its world position, its
radius is that of the disk of equal floor area, and the orientation of non-circular
shapes comes from second moments carried onto the floor.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Annotated, Literal, NamedTuple

import cv2
import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.camera.plane_table import PlaneTables
from ovis.common.camera.projection import PixelJacobian, pixel_footprint_cm2, pixel_jacobian
from ovis.common.config import CameraModel, ImageParams, PinholeParams, PoseConfig
from ovis.common.vision.contrast import NEUTRAL, ObjectWindow
from ovis.common.vision.frames import ImageError, as_gray
from ovis.common.vision.labeling import Borders, filter_components, label_components
from ovis.common.vision.markers import Markers
from ovis.common.vision.objects import background
from ovis.common.vision.outline import BlobPatches, Patch, SmoothedDiff
from ovis.common.vision.perimeter import perimeter
from ovis.common.vision.segmentation import background_image, read_roi, segment_gray
from ovis.common.vision.shape import compactness, orientation
from ovis.common.world.heights import (
    SolidObjects,
    SolidTracker,
    heights_unavailable,
    measurable,
    robot_row,
)
from ovis.common.world.marker_search import (
    marker_search_image,
    marker_side_px,
    markers_around,
    top_side_cm,
)
from ovis.common.world.planner import planner_inputs
from ovis.common.world.plans import RobotPlan, robot_plans
from ovis.common.world.pose import ROBOT_ID, Tracker, pick_robot, robot_ids
from ovis.common.world.robots import RobotState, RobotTracker, UnknownMarker
from ovis.common.world.unmarked import UnmarkedRobot

__all__ = [
    "Blobs",
    "DetectedObject",
    "Detection",
    "Detector",
    "PlannerEntry",
    "binarize_frame",
    "find_blobs",
    "measure_blobs",
    "measure_blobs_and_maps",
    "median_and_binary",
    "plane_maps",
    "size_filter_px",
    "size_plane_cm",
    "solid_pixels",
    "world_shape",
]

#: Blobs less elongated than this (major/minor axis) get no heading.
ROUND_ELONGATION = 1.15

#: ``DetectedObject.kind`` by "is the robot".
_KINDS = np.array(["obstacle", "robot"], dtype=object)
#: ``DetectedObject.z_source`` (heights measured) by "its height is measured".
_Z_SOURCE = np.array(["configured", "one camera"], dtype=object)
#: ``DetectedObject.z_unmeasured`` by why: declared, pending, not measurable.
_WHY = np.array(["declared", "pending", "not measurable"], dtype=object)


#: The largest magnitude a number of a detection may have (decoding refuses larger ones).
LARGEST = 1e12
#: A finite number (decoding refuses NaN and ±inf).
Finite = Annotated[float, msgspec.Meta(ge=-LARGEST, le=LARGEST)]
NonNegative = Annotated[float, msgspec.Meta(ge=0.0, le=LARGEST)]


class DetectedObject(msgspec.Struct):
    """One object seen in a frame: image measurements and world pose (built positionally,
    in field order, by :meth:`Detector.from_blobs`: cheaper than keywords for hundreds
    of objects)."""

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
    #: whether ``heading_deg`` is the robot's front (a marker's, or an unmarked robot's
    #: resolved from its motion, :mod:`ovis.common.world.unmarked`); false: an axis, either
    #: end (obstacles, and an unmarked robot that has not moved yet)
    heading_resolved: bool = False
    #: whether ``vx_cm_s``/``vy_cm_s`` are measured: the object tracked over two frames'
    #: capture times; false in its first frame (they are then 0, not a measurement) and
    #: for frames without capture times (taken to be 1 s apart: a guess, not a measurement)
    velocity_measured: bool = False
    #: where ``z_cm`` comes from: "configured" (its class's height, ``[pose]``), "marker"
    #: (a marked robot's ``marker_height_cm``), "one camera" (measured from this camera's
    #: view of its silhouette), "cameras" (triangulated from several, by fusion)
    z_source: Literal["configured", "marker", "one camera", "cameras"] = "configured"
    #: the measured height's uncertainty (1σ, cm); None when not measured
    z_sigma_cm: NonNegative | None = None
    #: with heights measured, why ``z_cm`` is the configured one: "declared" (the class's
    #: height is declared, ``pose.declared_heights``), "not measurable" (too uncertain
    #: here: near the camera's nadir, walls too thin or hidden), "pending" (its fit is
    #: still to come; ``x_cm``, ``y_cm`` are then a rough footprint from its outline's
    #: side facing the camera's foot, or its centroid on its class's plane where no side
    #: faces it)
    z_unmeasured: Literal["", "declared", "not measurable", "pending"] = ""
    #: covariance of (x_cm, y_cm, z_cm), cm², row by row (9 numbers), from the fit of its
    #: silhouette (heights measured; "not measurable": about the footprint at ``z_fit_cm``,
    #: widened by the step to it from the fit's own height; "pending": where its rough
    #: footprint may be, its height anywhere within a fit's range); None otherwise
    covariance_cm2: Annotated[list[Finite], msgspec.Meta(min_length=9, max_length=9)] | None = None
    #: the solid's fitted shape (heights measured): "cylinder", "box", "prism3", "prism5",
    #: "prism6"; "" when not fitted
    shape: Literal["", "cylinder", "box", "prism3", "prism5", "prism6"] = ""
    #: where the height is "not measurable" by this camera alone (its σ,
    #: ``covariance_cm2``'s last, over ``pose.height_sigma_max_cm``): the height its
    #: footprint ``x_cm``, ``y_cm`` rests on (the fit's own, or the one it is held at),
    #: while ``z_cm`` is the configured one; fusion weighs it with other cameras' by the
    #: covariance (:mod:`ovis.common.fusion.merge`); None otherwise
    z_fit_cm: Finite | None = None


class PlannerEntry(msgspec.Struct):
    """Motion-planner inputs for one obstacle (model-notes §6)."""

    obstacle_id: Annotated[int, msgspec.Meta(ge=0)]
    distance_cm: Finite
    angle_deg: Annotated[float, msgspec.Meta(gt=-180.0, le=180.0)]


class Detection(msgspec.Struct, kw_only=True):
    """Everything found in one frame. With marked robots (``pose.robots``): ``robots``
    (filtered poses, :mod:`ovis.common.world.robots`), ``robot_plans`` (per robot,
    :mod:`ovis.common.world.plans`), the markers no robot carries, and how many markers
    were cut by the image border; ``planner`` is then the first robot's, against the
    obstacles."""

    objects: list[DetectedObject]
    planner: list[PlannerEntry]
    robots: list[RobotState] = []
    robot_plans: list[RobotPlan] = []
    unknown_markers: list[UnknownMarker] = []
    markers_at_border: int = 0


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
    #: (n, 4) top, left, height, width of each blob's bounding box (px), when known
    box: NDArray[np.int64] | None = None
    #: (n, 3) area (px²), centroid row and column of each blob with its holes filled
    filled: NDArray[np.float64] | None = None
    #: the label stage's border chains and each blob's outer one among them, when known
    borders: Borders | None = None
    border: NDArray[np.int64] | None = None


def find_blobs(
    image: NDArray[np.uint8],
    params: ImageParams,
    camera: CameraModel,
    plane_cm: float,
    *,
    min_area_px: float = 0.0,
) -> Blobs:
    """Paper §3 on one frame: smooth, binarize, label, size-filter (cm² on ``plane_cm``)."""
    binary = binarize_frame(image, params, camera)
    return measure_blobs(binary, params, camera, plane_cm, min_area_px=min_area_px)


def binarize_frame(
    image: NDArray[np.uint8],
    params: ImageParams,
    camera: CameraModel,
    window: ObjectWindow | None = None,
) -> NDArray[np.uint8]:
    """The paper's median step and binarization of a frame of the calibration's size
    (``window``: the local-contrast window carried between frames,
    :class:`~ovis.common.vision.contrast.ObjectWindow`)."""
    return segment_gray(_frame_gray(image, camera), params, window)


def median_and_binary(
    image: NDArray[np.uint8],
    params: ImageParams,
    camera: CameraModel,
    window: ObjectWindow | None = None,
) -> tuple[NDArray[np.uint8], NDArray[np.uint8], NDArray[np.uint8]]:
    """The frame as grey, its 3×3 median and :func:`binarize_frame`'s binary image, from
    one median filter: the paper's smoothing step and the marker search both start from
    it."""
    gray = _frame_gray(image, camera)
    median3 = cv2.medianBlur(gray, 3)
    return gray, median3, segment_gray(gray, params, window, median3=median3)


def solid_pixels(
    gray: NDArray[np.uint8],
    background: NDArray[np.uint8],
    params: ImageParams,
    spots: NDArray[np.uint8] | None,
    smoothed: SmoothedDiff | None = None,
) -> NDArray[np.uint8]:
    """Object pixels of a frame when heights are measured: at least ``threshold − 128``
    brighter than the empty floor (:func:`~ovis.common.vision.outline.object_mask`, the
    mask the fitted outlines come from), within the region of interest. ``smoothed``:
    a sequence of frames' buffers (:class:`~ovis.common.vision.outline.SmoothedDiff`;
    the mask is then one of them, valid until the next frame)."""
    level = float(params.threshold - NEUTRAL)
    mask = (smoothed if smoothed is not None else SmoothedDiff()).mask(
        gray, background, level, spots
    )
    if params.roi:
        mask &= (read_roi(params, gray.shape) > 0).astype(np.uint8)
    return mask


def _frame_gray(image: NDArray[np.uint8], camera: CameraModel) -> NDArray[np.uint8]:
    """The frame as grey, refused unless it has the calibration's size."""
    gray = as_gray(image)
    if gray.shape != (camera.rows, camera.cols):
        raise ImageError(
            f"frame is {gray.shape[1]}x{gray.shape[0]} (cols x rows) but the calibration "
            f"is for {camera.cols}x{camera.rows}; calibrate on a frame of this camera"
        )
    return gray


def size_plane_cm(pose: PoseConfig) -> float:
    """The plane the size filter measures areas on: the obstacles' top plane with
    configured heights, the floor with measured ones (a solid's silhouette carried onto
    the floor covers at least its footprint, whatever its height)."""
    return 0.0 if pose.heights == "measured" else float(pose.obstacle_height_cm)


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
    return measure_blobs_and_maps(binary, params, camera, (plane_cm,), min_area_px=min_area_px)[0]


def measure_blobs_and_maps(
    binary: NDArray[np.uint8],
    params: ImageParams,
    camera: CameraModel,
    planes_cm: tuple[float, ...],
    *,
    min_area_px: float = 0.0,
    tables: PlaneTables | None = None,
    size_plane_cm: float | None = None,
) -> tuple[Blobs, list[PixelJacobian]]:
    """:func:`measure_blobs` (size filter on ``size_plane_cm``, by default
    ``planes_cm[0]``, never the background:
    :func:`~ovis.common.vision.objects.background`), and the pixel → plane map
    at every kept blob on each of ``planes_cm``, all from one back-projection (the size
    filter needs the first anyway; the pose wants the obstacle and the robot plane)."""
    comp = label_components(binary, min_area_px=min_area_px)
    behind = background(comp)
    if behind.any():
        comp = filter_components(comp, ~behind)
    size_plane = planes_cm[0] if size_plane_cm is None else size_plane_cm
    extra = size_plane not in planes_cm
    maps = plane_maps(
        comp.row, comp.col, camera, (*planes_cm, size_plane) if extra else planes_cm, tables
    )
    footprint = maps[planes_cm.index(size_plane) if not extra else -1].area_cm2
    if extra:
        maps = maps[:-1]
    keep = (footprint > 0) & (comp.area_px * footprint >= params.size_filter_cm2)
    if params.max_size_cm2 is not None:
        keep &= comp.area_px * footprint <= params.max_size_cm2
    comp = filter_components(comp, keep)
    perim = perimeter(comp, params.perimeter)
    blobs = Blobs(
        comp.row,
        comp.col,
        comp.area_px,
        perim,
        compactness(comp.area_px, perim),
        comp.mu_rr,
        comp.mu_cc,
        comp.mu_rc,
        np.column_stack([comp.top, comp.left, comp.height, comp.width]),
        comp.filled,
        comp.borders,
        comp.border,
    )
    return blobs, [PixelJacobian(*(f[keep] for f in m)) for m in maps]


def plane_maps(
    row: NDArray[np.float64],
    col: NDArray[np.float64],
    camera: CameraModel,
    planes_cm: tuple[float, ...],
    tables: PlaneTables | None = None,
) -> list[PixelJacobian]:
    """The pixel → plane map at each (row, col) on each of ``planes_cm``, from one
    back-projection of all of them; for a pinhole camera, from ``tables`` when given
    (a frame's many blobs would otherwise each iterate its lens undistortion)."""
    if tables is not None and isinstance(camera, PinholeParams):
        return [tables.jacobian(row, col, camera, z) for z in planes_cm]
    heights = np.asarray(planes_cm, dtype=np.float64)[:, None]
    maps = pixel_jacobian(row[None, :], col[None, :], camera, heights)
    return [PixelJacobian(*(f[k] for f in maps)) for k in range(len(planes_cm))]


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


def _unseen(marked: _MarkedFrame, pose: PoseConfig) -> list[int]:
    """The id of the one configured marked robot no blob stands for this frame (its
    marker hidden or unreadable), as a list; empty when every robot has its blob or
    several have none (then which box is which cannot be told). That robot is then the
    solid nearest the configured robot size and height (:func:`robot_row`), as an
    unmarked robot is."""
    seen = {r.id for r, k in zip(marked.robots, marked.rep, strict=True) if k >= 0}
    missing = [r.id for r in pose.robots if r.id not in seen]
    return missing if len(missing) == 1 else []


class _MarkedFrame(NamedTuple):
    """Marked robots of one frame and their blobs: ``owner`` (n,) index into ``robots``
    (−1: nobody's), ``rep`` the blob standing for each robot (−1: none), ``keep`` the
    blobs to report."""

    robots: list[RobotState]
    unknown: list[UnknownMarker]
    owner: NDArray[np.int64]
    rep: list[int]
    keep: NDArray[np.bool_]
    at_border: int

    @classmethod
    def none(cls, n: int) -> _MarkedFrame:
        return cls([], [], np.full(n, -1, dtype=np.int64), [], np.ones(n, dtype=bool), 0)

    def in_rows(self, rows: Sequence[int], has: list[bool], n: int) -> _MarkedFrame:
        """The same robots with their blobs at ``rows`` of ``n`` rows (the robots that
        have a blob, ``has``, in order); every row is reported."""
        owner = np.full(n, -1, dtype=np.int64)
        rep = [-1] * len(self.robots)
        it = iter(rows)
        for k, h in enumerate(has):
            if h:
                rep[k] = next(it)
                owner[rep[k]] = k
        keep = np.ones(n, dtype=bool)
        return _MarkedFrame(self.robots, self.unknown, owner, rep, keep, self.at_border)

    def fill(
        self,
        ids: NDArray[np.int64],
        xy: NDArray[np.float64],
        z: NDArray[np.float64],
        heading: NDArray[np.object_],
        vel: NDArray[np.float64],
        resolved: NDArray[np.bool_],
        measured: NDArray[np.bool_],
    ) -> None:
        """Write each robot's id and filtered pose into its blob's columns (in place)."""
        for robot, k in zip(self.robots, self.rep, strict=True):
            if k >= 0:
                ids[k], z[k], heading[k] = robot.id, robot.z_cm, robot.heading_deg
                resolved[k], measured[k] = True, robot.velocity_measured
                xy[k] = robot.x_cm, robot.y_cm
                vel[k] = robot.vx_cm_s, robot.vy_cm_s


def _without_robots(found: SolidObjects, marked: _MarkedFrame) -> SolidObjects:
    """``found`` less the marked robots' own solids: in each robot's blob (its centroid
    within the robot's radius), the solid standing nearest its marker's pose (the others
    there are obstacles its silhouette merged with; kept, the robot's own would be
    reported as an obstacle where it stands); a blob still waiting for its fit is all
    the robot's (which of its rows would be the robot cannot be told yet)."""
    drop = np.zeros(found.blob.size, dtype=bool)
    for robot, b in zip(marked.robots, marked.rep, strict=True):
        rows = np.flatnonzero(found.blob == b) if b >= 0 else np.zeros(0, dtype=np.int64)
        if not rows.size:
            continue
        if found.pending[rows].any():
            drop[rows] = True
            continue
        d = np.hypot(found.xy[rows, 0] - robot.x_cm, found.xy[rows, 1] - robot.y_cm)
        drop[rows[int(d.argmin())]] = True
    if not drop.any():
        return found
    keep = ~drop
    return SolidObjects(*(column[keep] for column in found))


def _then(first: NDArray, more: NDArray) -> NDArray:
    """``first``'s rows, then ``more``'s (most frames have none: ``first`` itself)."""
    return np.concatenate([first, more]) if len(more) else first


def _column(values: list[object]) -> NDArray[np.object_]:
    """A 1-D object array of ``values`` (numpy would make lists of equal length a 2-D
    array)."""
    out = np.empty(len(values), dtype=object)
    out[:] = values
    return out


class _Rows(NamedTuple):
    """A frame's objects as columns, one row each, before identities: image
    measurements, footprint centre, height, size, heading (deg, NaN: none), which is a
    robot and which to report, the marked robots' frame (its indices into the rows),
    the unmarked robot's row (−1: none) and, with measured heights, the height's
    columns (``z_source`` … ``shape``, in :class:`DetectedObject`'s order)."""

    row: NDArray[np.float64]
    col: NDArray[np.float64]
    area_px: NDArray[np.float64]
    perimeter_px: NDArray[np.float64]
    compactness: NDArray[np.float64]
    xy: NDArray[np.float64]
    z: NDArray[np.float64]
    radius: NDArray[np.float64]
    area_cm2: NDArray[np.float64]
    heading: NDArray[np.float64]
    elongation: NDArray[np.float64]
    is_robot: NDArray[np.bool_]
    ok: NDArray[np.bool_]
    marked: _MarkedFrame
    robot: int
    extra: dict[str, NDArray[np.object_]] | None


class _HeightColumns(NamedTuple):
    """The columns of a frame's rows with measured heights that its solids fix
    (:meth:`Detector._height_columns`): the robot's row (−1: none), which rows are
    robots, heights, radii, areas, headings, elongations, which to report and the
    height's columns (``z_source`` … ``z_fit_cm``)."""

    robot: int
    is_robot: NDArray[np.bool_]
    z: NDArray[np.float64]
    radius: NDArray[np.float64]
    area_cm2: NDArray[np.float64]
    heading: NDArray[np.float64]
    elongation: NDArray[np.float64]
    ok: NDArray[np.bool_]
    extra: dict[str, NDArray[np.object_]]


class _KeptColumns(NamedTuple):
    """The last frame's :class:`_HeightColumns`, kept while the solid tracker reports
    the same solids (its reports' ``height`` array, the same object) under the same
    ``[pose]``; their headings taken again when its ``yaw_deg`` array is another."""

    height: NDArray[np.float64]
    yaw: NDArray[np.float64]
    pose: PoseConfig
    columns: _HeightColumns


def _first_robot_planner(plans: list[RobotPlan]) -> list[PlannerEntry]:
    """The legacy planner list: the first robot's obstacles, when it has a goal."""
    if not plans:
        return []
    return [
        PlannerEntry(e.target_id, e.distance_cm, e.angle_deg)
        for e in plans[0].entries
        if e.target_kind == "obstacle" and e.angle_deg is not None
    ]


class Detector:
    """Frame → :class:`Detection` with a calibration, keeping obstacle ids across frames."""

    def __init__(
        self,
        camera: CameraModel,
        image: ImageParams,
        pose: PoseConfig,
        *,
        background_fits: bool = False,
    ) -> None:
        self.camera = camera
        #: measured heights: fit the solids on a thread of their own, never making a
        #: frame wait for a fit (a live stage; :class:`SolidTracker`)
        self.background_fits = background_fits
        self.image = image
        self.pose = pose
        self.tracker = Tracker(pose.track_gate_cm)
        self.tracker.reserve(robot_ids(pose))
        self.robots = RobotTracker(pose)
        self.unmarked = UnmarkedRobot(pose)
        self.tables = PlaneTables()
        self.window = ObjectWindow()  # the local-contrast window, settled over the frames
        self._smoothed = SmoothedDiff()  # measured heights: the smoothed D's buffers
        self._last_stamp: float | None = None
        self.solids: SolidTracker | None = None
        self._kept_columns: _KeptColumns | None = None
        self._setup_heights()
        self.min_area_px = size_filter_px(image, camera, size_plane_cm(pose))
        self.marker_side_px = marker_side_px(pose, camera)
        self.top_side_cm = top_side_cm(pose, camera)

    def _setup_heights(self) -> None:
        """Measured heights' solid tracker (raises ValueError when they cannot be
        measured with this calibration's image settings)."""
        if self.pose.heights != "measured":
            self.close()
            return
        why = heights_unavailable(self.image)
        if why is not None:
            raise ValueError(why)
        if self.solids is None:
            self.solids = SolidTracker(
                self.camera, self.image, self.pose, self.tables, background=self.background_fits
            )
        else:
            self.solids.reconfigure(self.camera, self.image, self.pose)

    def close(self) -> None:
        """Stop measuring heights (the solid tracker's fitting thread, if any)."""
        if self.solids is not None:
            self.solids.close()
        self.solids = None

    def prepare(self) -> None:
        """Make the pixel → plane tables the frames will need now (at start, on a new
        calibration): with measured heights, the floor's (every outline is carried onto
        it), so that the first frame does not pay for it."""
        if self.solids is not None:
            self.tables.prepare(self.camera, [0.0], wait=True)

    def recalibrate(self, camera: CameraModel, image: ImageParams, pose: PoseConfig) -> None:
        """Use a new calibration; obstacle and robot identities are kept, except that an
        obstacle holding an id a newly configured robot has gets a new one (ids are unique
        across kinds, :meth:`Tracker.reserve`)."""
        self.camera, self.image, self.pose = camera, image, pose
        self.tracker.gate_cm = pose.track_gate_cm
        self.tracker.reserve(robot_ids(pose))
        self.robots.reconfigure(pose)
        self.unmarked.pose = pose
        self.window = ObjectWindow()
        self._setup_heights()
        self.min_area_px = size_filter_px(image, camera, size_plane_cm(pose))
        self.marker_side_px = marker_side_px(pose, camera)
        self.top_side_cm = top_side_cm(pose, camera)

    def detect(
        self,
        frame: NDArray[np.uint8],
        *,
        goal_xy: tuple[float, float] | None = None,
        goal_angle_deg: float | None = None,
        stamp_s: float | None = None,
        fit_all: bool = False,
    ) -> Detection:
        """Find the robot and obstacles; planner inputs when a goal is known.

        The goal defaults to the calibration's ``pose.goal_cm``/``goal_angle_deg``.
        ``stamp_s`` is the frame's capture time (s); without it frames are taken to be
        the paper's Δt = 1 s apart (and no velocity is flagged measured). Obstacle
        velocities are in cm/s. ``fit_all``: with measured heights, fit every blob that
        needs it in this frame (a single frame, offline), not ``pose.fits_per_frame``.
        """
        gray = median3 = None
        if self.pose.robots:
            gray, median3, binary = median_and_binary(frame, self.image, self.camera, self.window)
            if self.solids is not None:
                binary = self._solid_pixels(gray)
        elif self.solids is not None:
            gray = _frame_gray(frame, self.camera)
            binary = self._solid_pixels(gray)
        else:
            binary = binarize_frame(frame, self.image, self.camera, self.window)
        # measured heights without marked robots need the class planes only for blobs
        # waiting for their fit (worked out then, :meth:`_solid_rows`)
        planes = (self.pose.obstacle_height_cm, self.pose.robot_height_cm)
        blobs, maps = measure_blobs_and_maps(
            binary,
            self.image,
            self.camera,
            planes if self._class_planes() else (),
            min_area_px=self.min_area_px,
            tables=self.tables,
            size_plane_cm=size_plane_cm(self.pose),
        )
        floor, top = maps if maps else (None, None)
        patches = None
        if self.solids is not None and gray is not None:
            patches = self._patches(gray, blobs, None if self.image.roi else binary)
        markers = None
        if self.pose.robots and gray is not None and median3 is not None:
            at_blobs = (self.top_side_cm, top.area_cm2)
            side_px = self.marker_side_px
            image = marker_search_image(gray, median3, self.pose, side_px)
            solids = self.solids is not None
            markers = markers_around(image, blobs, self.pose, side_px, at_blobs, solids)
        return self.from_blobs(
            blobs,
            floor=floor,
            top=top,
            goal_xy=goal_xy,
            goal_angle_deg=goal_angle_deg,
            stamp_s=stamp_s,
            markers=markers,
            patches=patches,
            fit_all=fit_all,
        )

    def _solid_pixels(self, gray: NDArray[np.uint8]) -> NDArray[np.uint8]:
        """Object pixels for measured heights (:func:`solid_pixels`)."""
        assert self.solids is not None
        background = background_image(self.image, gray.shape)
        self.solids.use_background(background)
        return solid_pixels(gray, background, self.image, self.solids.spots, self._smoothed)

    def _patches(
        self, gray: NDArray[np.uint8], blobs: Blobs, mask: NDArray[np.uint8] | None
    ) -> BlobPatches:
        """Each blob's patch of the frame less the empty floor (cut when asked for), with
        the frame's object mask cut with it (``mask``: :func:`solid_pixels`' without a
        region of interest; its outline then needs no smoothing of its own) and the
        blob's outer border as the label stage traced it in that mask."""
        assert self.solids is not None and blobs.box is not None
        background = background_image(self.image, gray.shape)
        self.solids.use_background(background)
        return BlobPatches(
            gray, background, blobs.box, mask=mask, borders=blobs.borders, border=blobs.border
        )

    def from_blobs(
        self,
        blobs: Blobs,
        *,
        floor: PixelJacobian | None = None,
        top: PixelJacobian | None = None,
        goal_xy: tuple[float, float] | None = None,
        goal_angle_deg: float | None = None,
        stamp_s: float | None = None,
        markers: Markers | None = None,
        patches: Sequence[Patch] | None = None,
        fit_all: bool = False,
        frame_shape: tuple[int, int] | None = None,
    ) -> Detection:
        """The pose half of :meth:`detect`, from already measured blobs.

        ``floor`` and ``top`` are the pixel → plane maps at the blobs' centroids on the
        obstacle plane and on the robot's top plane when already known
        (:func:`measure_blobs_and_maps`); else they are back-projected here. ``markers``
        are the frame's decoded markers (used when ``pose.robots`` is configured).
        ``patches``: each blob's patch of the frame less the empty floor (measured
        heights; without them no blob is fitted). ``frame_shape``: the frame's (rows,
        cols) where the patches come from another process (the pose stage): the empty
        floor's bright spots are then found here as :meth:`detect` finds them, so that the
        outlines fitted are the ones it fits (a floor mark is no edge).
        """
        cam, pose = self.camera, self.pose
        comp = blobs
        n = comp.area_px.size
        if (floor is None or top is None) and self._class_planes():
            planes = (pose.obstacle_height_cm, pose.robot_height_cm)
            floor, top = plane_maps(comp.row, comp.col, cam, planes, self.tables)
        now = stamp_s if stamp_s is not None else (self._last_stamp or 0.0) + 1.0
        dt = now - self._last_stamp if self._last_stamp is not None else 1.0
        self._last_stamp = now
        marked = _MarkedFrame.none(n)
        if pose.robots:
            marked = self._marked(markers or Markers.none(), top, now)
        if self.solids is not None:
            if patches is not None and frame_shape is not None:
                self.solids.use_background(background_image(self.image, frame_shape))
            rows = self._solid_rows(blobs, floor, top, marked, patches, fit_all, dt)
        else:
            rows = self._blob_rows(blobs, floor, top, marked)
        return self._report(rows, now, dt, stamp_s, goal_xy, goal_angle_deg)

    def _class_planes(self) -> bool:
        """Whether each frame needs its blobs on their classes' planes (configured
        heights, marked robots); else only a blob waiting for its fit does."""
        return self.solids is None or bool(self.pose.robots)

    def _blob_rows(
        self, blobs: Blobs, floor: PixelJacobian, top: PixelJacobian, marked: _MarkedFrame
    ) -> _Rows:
        """One row per blob, each on its class's top plane (configured heights)."""
        pose, n = self.pose, blobs.area_px.size
        robot = -1  # the unmarked robot's blob
        if pose.robots:
            is_robot = marked.owner >= 0
        else:
            robot = pick_robot(blobs.compactness, blobs.area_px * top.area_cm2, pose)
            is_robot = np.zeros(n, dtype=bool)
            if robot >= 0:
                is_robot[robot] = True
        z = np.where(is_robot, pose.robot_height_cm, pose.obstacle_height_cm)
        j = floor
        if is_robot.any():  # the robot on its top plane, everything else on the obstacles'
            pairs = zip(floor, top, strict=True)
            j = PixelJacobian(*(np.where(is_robot, t, f) for f, t in pairs))
        area_cm2, heading, elongation = world_shape(blobs, j)
        xy = np.empty((n, 2))
        xy[:, 0], xy[:, 1] = j.x_cm, j.y_cm
        return _Rows(
            blobs.row,
            blobs.col,
            blobs.area_px,
            blobs.perimeter_px,
            blobs.compactness,
            xy,
            z,
            np.sqrt(area_cm2 / np.pi),
            area_cm2,
            heading,
            elongation,
            is_robot,
            j.valid & marked.keep,
            marked,
            robot,
            None,
        )

    def _solid_rows(
        self,
        blobs: Blobs,
        floor: PixelJacobian | None,
        top: PixelJacobian | None,
        marked: _MarkedFrame,
        patches: Sequence[Patch] | None,
        fit_all: bool,
        dt_s: float,
    ) -> _Rows:
        """One row per solid (measured heights, :mod:`ovis.common.world.heights`), then
        one per marked robot's blob (on its marker's plane, as configured). ``floor``,
        ``top``: the blobs on the obstacles' and the robot's plane, None where not worked
        out (no marked robots: then the obstacles' when a blob waits for its fit)."""
        assert self.solids is not None
        pose = self.pose
        filled = blobs.filled
        if filled is None:
            filled = np.column_stack([blobs.area_px, blobs.row, blobs.col])

        def obstacle_plane() -> PixelJacobian:
            if floor is not None:
                return floor
            planes = (pose.obstacle_height_cm,)
            return plane_maps(blobs.row, blobs.col, self.camera, planes, self.tables)[0]

        skip = marked.owner >= 0
        reps = [k for k in marked.rep if k >= 0]
        skip[reps] = False  # a robot's own blob is fitted too: an obstacle may share it
        moments = np.column_stack([blobs.mu_rr, blobs.mu_cc, blobs.mu_rc])
        found = self.solids.update(
            filled, patches, obstacle_plane, skip, fit_all=fit_all, moments=moments, dt_s=dt_s
        )
        if reps:
            found = _without_robots(found, marked)
        rep = np.array(reps, dtype=np.int64)
        blob = np.concatenate([found.blob, rep]) if reps else found.blob
        kept = self._kept_columns
        if kept is not None and kept.height is found.height and kept.pose is pose:
            cols = kept.columns  # the same solids as last frame: what they report is fixed
            if kept.yaw is not found.yaw_deg:  # … but a follow turned one
                cols = cols._replace(heading=found.yaw_deg)
                self._kept_columns = kept._replace(yaw=found.yaw_deg, columns=cols)
        else:
            cols = self._height_columns(found, marked, blobs, top, rep)
            # without marked robots the columns depend only on the solids (a robot's
            # rows come with its blob)
            cacheable = not pose.robots and not found.pending.any()
            kept = _KeptColumns(found.height, found.yaw_deg, pose, cols) if cacheable else None
            self._kept_columns = kept
        if not pose.robots:  # the unmarked robot turns: its solid is followed so
            self.solids.note_robot(found, cols.robot)
        row, col, xy = found.row, found.col, found.xy
        if reps:  # the marked robots' rows after the solids' (most frames have none)
            assert top is not None  # marked robots: worked out
            row, col = _then(row, blobs.row[rep]), _then(col, blobs.col[rep])
            xy = _then(xy, np.column_stack([top.x_cm[rep], top.y_cm[rep]]))
        m, n = found.blob.size, blob.size
        return _Rows(
            row,
            col,
            blobs.area_px[blob],
            blobs.perimeter_px[blob],
            blobs.compactness[blob],
            xy,
            cols.z,
            cols.radius,
            cols.area_cm2,
            cols.heading,
            cols.elongation,
            cols.is_robot,
            cols.ok,
            marked.in_rows(range(m, n), [k >= 0 for k in marked.rep], n),
            cols.robot,
            cols.extra,
        )

    def _height_columns(
        self,
        found: SolidObjects,
        marked: _MarkedFrame,
        blobs: Blobs,
        top: PixelJacobian | None,
        rep: NDArray[np.int64],
    ) -> _HeightColumns:
        """The columns of a frame's rows (:meth:`_solid_rows`) other than where they are
        in the image and on the floor: which is the robot, heights and where they come
        from, sizes, headings; the solids' rows, then the marked robots' (their blobs
        ``rep``) as configured heights put them (their filter moves them)."""
        pose = self.pose
        m = found.blob.size
        n = m + rep.size
        robot = robot_row(found, pose) if not pose.robots or _unseen(marked, pose) else -1
        is_robot = np.zeros(n, dtype=bool)
        is_robot[m:] = True
        if robot >= 0:
            is_robot[robot] = True
        top_area = top_heading = top_elong = np.zeros(0)
        top_ok = np.zeros(0, dtype=bool)
        if rep.size:
            assert top is not None  # marked robots: worked out
            top_area, top_heading, top_elong = (a[rep] for a in world_shape(blobs, top))
            top_ok = top.valid[rep]
        length, width = found.size[:, 0], found.size[:, 1]
        elongation = np.where(
            (found.shape == "box") & (width > 0), length / np.where(width > 0, width, 1.0), 1.0
        )
        ok = _then(np.ones(m, dtype=bool), top_ok)
        class_height = np.where(is_robot, pose.robot_height_cm, pose.obstacle_height_cm)
        declared = np.where(
            is_robot, "robot" in pose.declared_heights, "obstacle" in pose.declared_heights
        )
        known = _then(measurable(found, pose), np.zeros(rep.size, dtype=bool))
        use = known & ~declared
        h = _then(found.height, np.full(rep.size, np.nan))
        sigma = _then(found.height_sigma, np.full(rep.size, np.nan))
        pending = _then(found.pending, np.zeros(rep.size, dtype=bool))
        why = _WHY[np.where(declared, 0, np.where(pending, 1, 2))]
        cov = _then(found.covariance, np.full((rep.size, 3, 3), np.nan))
        # a height the outline leaves all but free has a variance no message can carry
        # (nor any use has): no covariance then, as for a solid not fitted
        fitted = (np.abs(cov) <= LARGEST).all(axis=(1, 2))  # NaN compares false
        shape = _then(found.shape, np.full(rep.size, "", dtype=object))
        weak = fitted & ~use & ~declared & ~pending & np.isfinite(h)
        extra = {
            "z_source": _Z_SOURCE[use.astype(np.int64)],
            "z_sigma_cm": np.where(use, sigma, None),
            "z_unmeasured": np.where(use, "", why),
            "covariance_cm2": _column(
                [c.ravel().tolist() if f else None for c, f in zip(cov, fitted, strict=True)]
            ),
            "shape": shape.astype(object),
            "z_fit_cm": np.where(weak, h, None),
        }
        return _HeightColumns(
            robot,
            is_robot,
            np.where(use, h, class_height),
            _then(found.radius, np.sqrt(top_area / np.pi)),
            _then(found.area_cm2, top_area),
            _then(found.yaw_deg, top_heading),
            _then(elongation, top_elong),
            ok,
            extra,
        )

    def _report(
        self,
        rows: _Rows,
        now: float,
        dt: float,
        stamp_s: float | None,
        goal_xy: tuple[float, float] | None,
        goal_angle_deg: float | None,
    ) -> Detection:
        """Identities, velocities, the robots' poses and the planner's inputs of a frame's
        rows (objects), and the detection."""
        pose, marked, robot = self.pose, rows.marked, rows.robot
        is_robot, ok, xy, z = rows.is_robot, rows.ok, rows.xy, rows.z.copy()
        n = is_robot.size
        obstacle = ok & ~is_robot
        ids = np.full(n, ROBOT_ID, dtype=np.int64)
        vel = np.zeros((n, 2))
        track = self.tracker.track(xy[obstacle])
        ids[obstacle] = track.ids
        measured = np.zeros(n, dtype=bool)
        if dt > 0:
            vel[obstacle], measured[obstacle] = track.step / dt, track.tracked
        shown = rows.heading.astype(object)
        shown[(rows.elongation < ROUND_ELONGATION) | np.isnan(rows.heading)] = None
        resolved = np.zeros(n, dtype=bool)
        if pose.robots:  # each robot's blob where its marker and filter put it
            marked.fill(ids, xy, z, shown, vel, resolved, measured)
            if robot >= 0:  # the one robot whose marker is not seen: by its size
                ids[robot] = _unseen(marked, pose)[0]
        elif robot >= 0 and ok[robot]:  # the unmarked robot: heading oriented, velocity
            x, y = xy[robot].tolist()
            motion = self.unmarked.update(x, y, shown[robot], now)
            shown[robot], resolved[robot] = motion.heading_deg, motion.resolved
            vel[robot] = motion.vx_cm_s, motion.vy_cm_s
            measured[robot] = motion.velocity_measured
        if stamp_s is None:  # frames taken to be 1 s apart: a velocity, but not measured
            measured[:] = False
            marked.robots[:] = [
                msgspec.structs.replace(r, velocity_measured=False) for r in marked.robots
            ]
        # Objects in id order (the robot first), built column by column.
        out = np.arange(n)[ok]
        out = out[ids[out].argsort(kind="stable")]
        columns = {
            "id": ids,
            "kind": _KINDS[is_robot.astype(np.int64)],
            "row": rows.row,
            "col": rows.col,
            "area_px": rows.area_px,
            "perimeter_px": rows.perimeter_px,
            "compactness": rows.compactness,
            "x_cm": xy[:, 0],
            "y_cm": xy[:, 1],
            "z_cm": z,
            "radius_cm": rows.radius,
            "area_cm2": rows.area_cm2,
            "heading_deg": shown,
            "elongation": rows.elongation,
            "vx_cm_s": vel[:, 0],
            "vy_cm_s": vel[:, 1],
            "heading_resolved": resolved,
            "velocity_measured": measured,
        }
        fields = list(DetectedObject.__struct_fields__[: len(columns)])
        if rows.extra is not None:
            extra = dict(rows.extra)
            if pose.robots:  # a marked robot's height is its marker's
                owned = np.zeros(n, dtype=bool)
                owned[[k for k in marked.rep if k >= 0]] = True
                extra["z_source"] = np.where(owned, "marker", extra["z_source"])
                for name in ("z_sigma_cm", "covariance_cm2", "z_fit_cm"):
                    extra[name] = np.where(owned, None, extra[name])
                extra["z_unmeasured"] = np.where(owned, "", extra["z_unmeasured"])
            columns |= extra
            fields += list(extra)
        elif pose.robots:
            owned = np.zeros(n, dtype=bool)
            owned[[k for k in marked.rep if k >= 0]] = True
            columns["z_source"] = np.where(owned, "marker", "configured").astype(object)
            fields.append("z_source")
        # positional, in field order (the extra columns follow the first ones in order)
        objects = list(map(DetectedObject, *(columns[f][out].tolist() for f in fields)))
        if not pose.robots:
            planner = self._plan(
                ids[out],
                is_robot[out],
                xy[out, 0],
                xy[out, 1],
                rows.radius[out],
                goal_xy,
                goal_angle_deg,
            )
            return Detection(objects=objects, planner=planner)
        obstacle_xyr = np.column_stack([xy[obstacle], rows.radius[obstacle]])
        plans = robot_plans(marked.robots, ids[obstacle], obstacle_xyr, pose)
        return Detection(
            objects=objects,
            planner=_first_robot_planner(plans),
            robots=marked.robots,
            robot_plans=plans,
            unknown_markers=marked.unknown,
            markers_at_border=marked.at_border,
        )

    def _marked(self, markers: Markers, top: PixelJacobian, now: float) -> _MarkedFrame:
        """Robots from this frame's markers, and which blobs are whose: a blob whose
        centroid (on the robot plane) lies within a robot's radius is that robot's (the
        nearest such blob stands for it; the rest, e.g. bits of its marker, are dropped)."""
        robots, unknown = self.robots.update(markers, self.camera, now)
        n = top.x_cm.size
        # a few robots: plain Python over (blob, robot) pairs costs less than the dozen
        # array calls of a distance matrix
        owner = [-1] * n
        rep = [-1] * len(robots)
        if robots and n:
            xs, ys = top.x_cm.tolist(), top.y_cm.tolist()
            nearest = [math.inf] * n
            for k, robot in enumerate(robots):
                x, y, radius = robot.x_cm, robot.y_cm, robot.radius_cm
                for i in range(n):
                    d = math.hypot(xs[i] - x, ys[i] - y)  # NaN off the plane: never within
                    if d <= radius and d < nearest[i]:
                        nearest[i], owner[i] = d, k
            best = [math.inf] * len(robots)
            for i, k in enumerate(owner):  # per robot, its nearest own blob
                if k >= 0 and nearest[i] < best[k]:
                    best[k], rep[k] = nearest[i], i
        owned = np.array(owner, dtype=np.int64)
        keep = owned < 0
        keep[[k for k in rep if k >= 0]] = True
        return _MarkedFrame(robots, unknown, owned, rep, keep, markers.partial)

    def _plan(
        self,
        ids: NDArray[np.int64],
        is_robot: NDArray[np.bool_],
        x_cm: NDArray[np.float64],
        y_cm: NDArray[np.float64],
        radius_cm: NDArray[np.float64],
        goal_xy: tuple[float, float] | None,
        goal_angle_deg: float | None,
    ) -> list[PlannerEntry]:
        """Planner inputs of the obstacles, in the order given, from the robot."""
        if goal_xy is None and goal_angle_deg is None:
            goal_xy, goal_angle_deg = self.pose.goal_cm, self.pose.goal_angle_deg
        robot = np.flatnonzero(is_robot)
        if not robot.size or robot.size == ids.size or (goal_xy is None and goal_angle_deg is None):
            return []
        r = (float(x_cm[robot[0]]), float(y_cm[robot[0]]))
        at_goal = goal_xy is not None and math.hypot(goal_xy[0] - r[0], goal_xy[1] - r[1]) < 1e-9
        if goal_angle_deg is None and at_goal:
            return []
        obstacle = ~is_robot
        inputs = planner_inputs(
            r,
            np.column_stack([x_cm, y_cm, radius_cm])[obstacle],
            goal_xy=goal_xy,
            goal_angle_deg=goal_angle_deg,
        )
        return list(
            map(
                PlannerEntry,
                ids[obstacle].tolist(),
                inputs.distance_cm.tolist(),
                inputs.angle_deg.tolist(),
            )
        )
