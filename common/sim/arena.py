"""The built-in simulated arena: moving robot and obstacles seen by the paper's camera.

Scene model
-----------
The paper's set-up (§2, §5; Figures 6 and 9) is a tilted overhead camera looking at a
flat floor on which one car-like robot and a few cylindrical obstacles move. The
simulator reproduces what the vision pipeline needs from it, and nothing more:

* **Objects** are flat top faces: an oriented rectangle (the robot, ``robot_size_cm`` =
  length × width, its long axis along the direction of motion) at
  ``pose.robot_height_cm`` and disks (obstacles, radii drawn in
  ``obstacle_radius_cm``) at ``pose.obstacle_height_cm``. Only the top faces are drawn,
  so the centre of each top face — the paper's control point — is exactly the centre
  of its blob's world footprint on the plane of that face (the sides of real objects
  would bias the centroid towards the camera's foot by an amount no model here has).
* **Motion**: each object moves at about ``speed_cm_per_frame`` (± 20 %, fixed per
  object) with a slowly wandering direction, bouncing (reflecting its velocity) off
  the arena bounds ``arena_x_cm × arena_y_cm``, off the image border and off the other
  objects. A move is only accepted if, afterwards, (a) the footprint lies inside the
  arena, (b) the projected outline of the top face lies inside the image with a
  margin of :data:`IMAGE_MARGIN_PX`, and (c) every pair of objects keeps a gap of at
  least :data:`MIN_GAP_CM` edge to edge, both between the footprints in the world and
  between the top faces as the camera sees them (their central projections from the
  camera centre onto the floor: a top face 7 cm up appears up to ~5 % farther from the
  camera's foot, so a world gap alone could let two blobs touch in the image). The
  invariants therefore hold in every frame, not just on average.
* **Photometry**, all through :func:`ovis.common.camera.projection.back_project` (either
  camera model, ``[camera] model``), so a perfectly
  calibrated camera sees exactly the truth: the floor has intensity
  ``floor_level × ℓ(row, col)`` and a top face ``object_level × ℓ``, where the lighting
  field ℓ is a linear gradient of relative amplitude ``lighting_gradient`` across the
  frame (direction chosen from the seed) times vignetting ``1 − vignetting·ρ²`` (ρ the
  distance from the principal point (c_x, c_y), 1 at the farthest corner). Coverage is
  anti-aliased by supersampling: ``supersample²`` sub-pixel samples per pixel, each
  back-projected onto the plane of the object's top face, inside the object's
  projected bounding box only. Then Gaussian blur (``blur_sigma_px``), Gaussian sensor
  noise (``noise_sigma``), pepper noise (a fraction ``pepper_fraction`` of pixels set
  to 0–30) and clutter: ``clutter_count`` small bright star-shaped specks on the floor
  (Z = 0) of area in ``clutter_area_cm2`` and intensity ``clutter_level``, placed anew
  each frame at least :data:`CLUTTER_CLEARANCE_CM` from every object (so they never
  touch an object's blob) — the "extraneous components" the paper's size filter A^f
  removes (§3).

Why: the GA calibration (paper §4) must detect *exactly* the control points, so the
scene is separable by construction — every fully covered object pixel is at least
``object_level·min ℓ − floor_level·max ℓ`` (≈ 70 grey levels with the presets) above
every floor pixel, and clutter is bright enough to pass the threshold but smaller than
the size filter's range — while noise, blur, pepper and clutter make that separation
something the GA has to find rather than get for free.

Determinism: the motion uses one ``numpy`` Generator seeded with ``seed``; each frame's
clutter and noise use Generators seeded with ``(seed, frame index, stream)``, so a
frame depends only on the seed and its index, however often it is rendered.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Literal, NamedTuple

import cv2
import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.atomic import write_atomic
from ovis.common.camera.paper_model import camera_centre_mm
from ovis.common.camera.projection import (
    back_project,
    camera_centre_cm,
    principal_point_rowcol,
    project,
)
from ovis.common.config import (
    CameraModel,
    CameraParams,
    ControlPoint,
    OvisConfig,
    PoseConfig,
    dump_toml,
)
from ovis.common.sim.painting import (
    PlaneTiles,
    finish_frame,
    marker_hand,
    outline,
    paint_marker,
    paint_shape,
    paint_top_face,
)
from ovis.common.sim.paths import place_still_obstacles, plan_paths
from ovis.common.vision.markers import marker_cells

__all__ = [
    "CLUTTER_CLEARANCE_CM",
    "IMAGE_MARGIN_PX",
    "MIN_GAP_CM",
    "Arena",
    "DatasetInfo",
    "FrameTruth",
    "SimObject",
    "control_points",
    "lighting_field",
    "write_dataset",
]

#: Smallest edge-to-edge gap (cm) between two objects, in the world and as seen.
MIN_GAP_CM = 3.0
#: Smallest distance (cm) from a clutter speck to any object's footprint.
CLUTTER_CLEARANCE_CM = 4.0
#: Smallest gap (cm) between two clutter specks (so they never merge into one blob).
CLUTTER_SPACING_CM = 2.0
#: Margin (pixels) between an object's projected outline and the image border.
IMAGE_MARGIN_PX = 3.0

_TURN_SIGMA_RAD = {"robot": math.radians(6.0), "obstacle": math.radians(3.0)}
_SPEED_SPREAD = 0.2  # per-object speed = speed · U(1 − s, 1 + s)
_PLACE_TRIES = 400  # random positions tried per object at start-up
_PLACE_RESTARTS = 50
_RANDOM_DIRECTIONS = 24  # directions tried when bouncing fails
_CLUTTER_TRIES = 40

# Generator streams per frame: seeded with (seed, frame index, stream).
_STREAM_LIGHT = 1
_STREAM_CLUTTER = 2
_STREAM_NOISE = 3
#: Planes whose back-projected samples a scene keeps (:class:`PlaneTiles`): its objects'
#: top heights and the floor; shapes on any other plane are back-projected as painted.
_KEPT_PLANES = 4

FloatArray = NDArray[np.float64]


class SimObject(msgspec.Struct, kw_only=True, frozen=True, omit_defaults=True):
    """Ground truth of one object in one frame (world cm, degrees).

    ``x_cm, y_cm`` is the centre of the top face (the footprint's: every object is an
    upright prism), ``z_cm`` its height; ``radius_cm`` is the radius of the disk of
    equal top-face area; ``heading_deg`` is the robot's long axis, counter-clockwise
    from +X (0 for disks; a box's or prism's yaw in the physical world);
    ``length_cm × width_cm`` is the rectangle (2r × 2r for disks).
    """

    id: int
    kind: Literal["robot", "obstacle"]
    x_cm: float
    y_cm: float
    z_cm: float
    radius_cm: float
    heading_deg: float
    shape: Literal["rect", "disk", "prism"]
    length_cm: float
    width_cm: float
    #: marked robots only (``pose.robots``): its marker, and its velocity at
    #: ``simulator.fps`` frames per second
    marker_id: int | None = None
    vx_cm_s: float = 0.0
    vy_cm_s: float = 0.0
    #: a regular prism's number of sides (the physical world, :mod:`ovis.common.physical`;
    #: its ``length_cm``/``width_cm`` are then the circumscribed disk's diameter)
    sides: int = 0


class FrameTruth(msgspec.Struct, kw_only=True, frozen=True):
    """Ground truth of one frame: its index and every object (robot first, by id);
    ``stamp_ns``, the instant it shows when its source keeps a clock shared by several
    cameras (the camera grid: cameras on one trigger), else None."""

    index: int
    objects: list[SimObject]
    stamp_ns: int | None = None


class DatasetInfo(msgspec.Struct, kw_only=True, frozen=True):
    """Paths written by :func:`write_dataset`."""

    out_dir: Path
    frames: list[Path]
    truth: Path
    points: Path
    #: check points: the last frame's objects (None with a single frame)
    checks: Path | None = None


class _TruthRecord(msgspec.Struct, kw_only=True):
    index: int
    file: str
    objects: list[SimObject]


class _TruthFile(msgspec.Struct, kw_only=True):
    seed: int
    preset: str
    camera: dict[str, object]
    frames: list[_TruthRecord]


def lighting_field(
    cam: CameraModel, *, gradient: float, vignetting: float, direction_rad: float
) -> NDArray[np.float32]:
    """Relative illumination ℓ of every pixel, shape ``(cam.rows, cam.cols)`` float32.

    ``ℓ = (1 + gradient·u) · (1 − vignetting·ρ²)`` where ``u ∈ [−½, ½]`` is the pixel's
    position across the frame along the direction ``direction_rad`` (measured in the
    (row, col) plane from +row towards +col) and ρ is the distance from the principal
    point (c_x, c_y), normalised to 1 at the farthest image corner.
    """
    rows, cols = int(cam.rows), int(cam.cols)
    r = np.arange(rows, dtype=np.float64)[:, None]
    c = np.arange(cols, dtype=np.float64)[None, :]
    cr, cc = math.cos(direction_rad), math.sin(direction_rad)
    along = r * cr + c * cc
    corners = [0.0, (rows - 1) * cr, (cols - 1) * cc, (rows - 1) * cr + (cols - 1) * cc]
    lo, hi = min(corners), max(corners)
    u = (along - 0.5 * (lo + hi)) / max(hi - lo, 1e-12)
    c_x, c_y = principal_point_rowcol(cam)  # (row, col) of the principal point
    corner_r2 = max(
        (rr - c_x) ** 2 + (cc_ - c_y) ** 2 for rr in (0.0, rows - 1.0) for cc_ in (0.0, cols - 1.0)
    )
    rho2 = ((r - c_x) ** 2 + (c - c_y) ** 2) / max(corner_r2, 1e-12)
    return ((1.0 + gradient * u) * (1.0 - vignetting * rho2)).astype(np.float32)


def _shape_gaps(
    x: float,
    y: float,
    heading: float,
    half_len: float,
    half_wid: float,
    is_rect: bool,
    ox: FloatArray,
    oy: FloatArray,
    oheading: FloatArray,
    ohalf_len: FloatArray,
    ohalf_wid: FloatArray,
    orect: NDArray[np.bool_],
) -> FloatArray:
    """Edge-to-edge distances (cm) from one shape to each of several others.

    Disks have ``half_len = half_wid = r``. Disk–disk and rectangle–disk distances are
    exact; rectangle–rectangle is conservative (the other one taken as its
    circumscribed disk). Negative where the shapes overlap.
    """
    dx, dy = ox - x, oy - y
    oradius = np.where(orect, np.hypot(ohalf_len, ohalf_wid), ohalf_len)
    if is_rect:
        # Other centres in this rectangle's frame.
        ch, sh = math.cos(heading), math.sin(heading)
        u, v = dx * ch + dy * sh, -dx * sh + dy * ch
        dist = np.hypot(
            np.maximum(np.abs(u) - half_len, 0.0), np.maximum(np.abs(v) - half_wid, 0.0)
        )
        return dist - oradius
    # This disk's centre in each other rectangle's frame (for disks the result is moot).
    ch, sh = np.cos(oheading), np.sin(oheading)
    u, v = -dx * ch - dy * sh, dx * sh - dy * ch
    to_rect = np.hypot(
        np.maximum(np.abs(u) - ohalf_len, 0.0), np.maximum(np.abs(v) - ohalf_wid, 0.0)
    )
    return np.where(orect, to_rect, np.hypot(dx, dy) - ohalf_len) - half_len


class MarkedRobots(NamedTuple):
    """What the simulator draws of each marked robot: marker id, side (cm), printed cells
    (see :func:`ovis.common.vision.markers.marker_cells`), and ``hand`` = ±1, which way
    the marker's right side is from its top as seen from above (chosen per camera so the
    image shows the marker unmirrored, as a real camera would)."""

    marker_ids: list[int]
    side_cm: list[float]
    cells: list[NDArray[np.bool_]]
    hand: float

    @classmethod
    def build(cls, pose: PoseConfig, robot_size_cm: tuple[float, float]) -> MarkedRobots:
        cells = [marker_cells(pose.marker_dictionary, r.marker_id) for r in pose.robots]
        for r, c in zip(pose.robots, cells, strict=True):
            quiet = r.marker_side_cm / c.shape[0]  # a white cell all round it
            if r.marker_side_cm + 2.0 * quiet > min(robot_size_cm):
                raise ValueError(
                    f"robot {r.name!r}: a marker of {r.marker_side_cm} cm plus its white "
                    f"margin does not fit on the simulated robot's top "
                    f"({robot_size_cm[0]} x {robot_size_cm[1]} cm, simulator.robot_size_cm)"
                )
        return cls(
            [r.marker_id for r in pose.robots], [r.marker_side_cm for r in pose.robots], cells, 1.0
        )


class Arena:
    """A simulated arena: one robot and ``n_obstacles`` disks moving under the camera.

    Parameters
    ----------
    config : OvisConfig
        ``config.camera`` is the true camera, ``config.pose`` gives the top-face heights
        and ``config.simulator`` the scene (see the module docstring).
    seed : int
        Non-negative seed; equal seeds give identical frames, byte for byte.

    Raises
    ------
    ValueError
        If the seed is negative, the camera is not above the objects, or the objects
        cannot be placed inside the arena and the image with the required gaps.
    """

    def __init__(self, config: OvisConfig, seed: int) -> None:
        if int(seed) < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed}")
        self._config = config
        self._seed = int(seed)
        self._cam = config.camera
        sim = config.simulator
        self._sim = sim
        self._rng = np.random.default_rng(self._seed)
        self._index = 0

        if isinstance(self._cam, CameraParams):
            cx_mm, cy_mm, cz_mm = camera_centre_mm(self._cam)
            cx_cm, cy_cm, cz = float(cx_mm) / 10.0, float(cy_mm) / 10.0, float(cz_mm) / 10.0
        else:  # any other model: its centre of projection
            cx_cm, cy_cm, cz = camera_centre_cm(self._cam)
        self._foot = (cx_cm, cy_cm)  # camera's foot, cm
        z_robot, z_obst = config.pose.robot_height_cm, config.pose.obstacle_height_cm
        if cz <= max(z_robot, z_obst) + 1.0:
            raise ValueError(
                f"camera centre height {cz:.1f} cm must be above the objects' top faces "
                f"(robot {z_robot} cm, obstacles {z_obst} cm)"
            )

        self._marked: MarkedRobots | None = None
        if config.pose.robots:
            self._setup_marked(cz)
        else:
            self._setup_one_robot(cz, z_robot, z_obst)
        light_rng = np.random.default_rng([self._seed, _STREAM_LIGHT])
        self._light = lighting_field(
            self._cam,
            gradient=sim.lighting_gradient,
            vignetting=sim.vignetting,
            direction_rad=float(light_rng.uniform(0.0, 2.0 * math.pi)),
        )
        self._light.setflags(write=False)
        self._planes: dict[float, PlaneTiles] = {}

    def _plane(self, z: float) -> PlaneTiles | None:
        """The samples of plane Z = ``z`` kept between frames (none past
        :data:`_KEPT_PLANES` planes)."""
        plane = self._planes.get(z)
        if plane is None and len(self._planes) < _KEPT_PLANES:
            plane = self._planes[z] = PlaneTiles(self._cam, z, self._sim.supersample)
        return plane

    def _setup_one_robot(self, cz: float, z_robot: float, z_obst: float) -> None:
        """The paper's scene: one unmarked robot and moving obstacles."""
        sim = self._sim
        n = 1 + sim.n_obstacles
        length, width = sim.robot_size_cm
        radii = self._rng.uniform(*sim.obstacle_radius_cm, size=sim.n_obstacles)
        self._kind = ["robot"] + ["obstacle"] * sim.n_obstacles
        self._ids = list(range(n))
        self._is_rect = np.array([True] + [False] * sim.n_obstacles)
        self._half_len = np.concatenate([[length / 2.0], radii])
        self._half_wid = np.concatenate([[width / 2.0], radii])
        self._z = np.array([z_robot] + [z_obst] * sim.n_obstacles, dtype=np.float64)
        # Central projection from the camera centre onto Z = 0 scales by cz / (cz − z).
        self._shadow = cz / (cz - self._z)
        self._speed = sim.speed_cm_per_frame * self._rng.uniform(
            1.0 - _SPEED_SPREAD, 1.0 + _SPEED_SPREAD, size=n
        )
        self._x = np.zeros(n)
        self._y = np.zeros(n)
        self._heading = np.zeros(n)
        self._direction = np.zeros(n)
        self._place_all()

    def _setup_marked(self, cz: float) -> None:
        """Marked robots (``pose.robots``) on crossing paths, still obstacles beside them
        (:mod:`ovis.common.sim.paths`)."""
        sim, pose = self._sim, self._config.pose
        marked = MarkedRobots.build(pose, sim.robot_size_cm)
        self._marked = marked._replace(hand=self._marker_hand(pose.robots[0].marker_height_cm))
        robots, m = pose.robots, sim.n_obstacles
        r_count = len(robots)
        length, width = sim.robot_size_cm
        radii = self._rng.uniform(*sim.obstacle_radius_cm, size=m)
        first_free = max(r.id for r in robots) + 1
        self._kind = ["robot"] * r_count + ["obstacle"] * m
        self._ids = [r.id for r in robots] + list(range(first_free, first_free + m))
        self._is_rect = np.array([True] * r_count + [False] * m)
        self._half_len = np.concatenate([np.full(r_count, length / 2.0), radii])
        self._half_wid = np.concatenate([np.full(r_count, width / 2.0), radii])
        z_top = [r.marker_height_cm for r in robots]
        self._z = np.array(z_top + [pose.obstacle_height_cm] * m, dtype=np.float64)
        self._shadow = cz / (cz - self._z)
        self._speed = np.zeros(r_count + m)  # nothing moves by bouncing
        reach = math.hypot(length, width) / 2.0
        fx, fy = self._foot

        def seen_at(z: float):
            s = cz / (cz - z)
            return lambda x, y: (fx + s * (x - fx), fy + s * (y - fy), s)

        ring = np.linspace(0.0, 2.0 * math.pi, 16, endpoint=False)
        z_robot = max(z_top)

        def robots_fit(x: FloatArray, y: FloatArray) -> bool:
            px = (x[:, None] + reach * np.cos(ring)).ravel()
            py = (y[:, None] + reach * np.sin(ring)).ravel()
            return self._in_image(px, py, z_robot)[0]

        def obstacle_fits(x: float, y: float, r: float) -> bool:
            return self._in_image(x + r * np.cos(ring), y + r * np.sin(ring), z_obst)[0]

        z_obst = pose.obstacle_height_cm
        area = {"arena_x_cm": sim.arena_x_cm, "arena_y_cm": sim.arena_y_cm, "gap_cm": MIN_GAP_CM}
        for attempt in range(_PLACE_RESTARTS):  # new paths when the obstacles find no room
            try:
                paths = plan_paths(
                    self._rng,
                    n=r_count,
                    reach_cm=reach,
                    speed_cm_per_frame=sim.speed_cm_per_frame,
                    seen=seen_at(z_robot),
                    fits_image=robots_fit,
                    **area,
                )
                ox, oy = place_still_obstacles(
                    self._rng,
                    paths,
                    radii,
                    reach_cm=reach,
                    seen_robot=seen_at(z_robot),
                    seen_obstacle=seen_at(z_obst),
                    fits_image=obstacle_fits,
                    **area,
                )
                break
            except ValueError as exc:
                crowded = "cover" in str(exc)  # too many robots: no draw will do
                if crowded or attempt == _PLACE_RESTARTS - 1:
                    raise
        self._paths = paths
        self._x = np.concatenate([np.zeros(r_count), ox])
        self._y = np.concatenate([np.zeros(r_count), oy])
        self._heading = np.zeros(r_count + m)
        self._direction = np.zeros(r_count + m)
        self._follow_paths()

    def _marker_hand(self, z: float) -> float:
        """:func:`marker_hand` of this camera at the arena's centre."""
        (x0, x1), (y0, y1) = self._sim.arena_x_cm, self._sim.arena_y_cm
        return marker_hand(self._cam, 0.5 * (x0 + x1), 0.5 * (y0 + y1), z)

    def _follow_paths(self) -> None:
        """Marked robots to where their paths are at the current frame."""
        r_count = len(self._paths.cx)
        x, y = self._paths.position(self._index)
        vx, vy = self._paths.velocity(self._index)
        self._x[:r_count], self._y[:r_count] = x, y
        self._heading[:r_count] = self._direction[:r_count] = np.arctan2(vy, vx)

    # ------------------------------------------------------------------ properties
    @property
    def truth_camera(self) -> CameraModel:
        """The camera the frames are rendered with (``config.camera``)."""
        return self._cam

    @property
    def config(self) -> OvisConfig:
        """The configuration the arena was built from."""
        return self._config

    @property
    def seed(self) -> int:
        """The seed the arena was built from."""
        return self._seed

    @property
    def index(self) -> int:
        """Index of the current frame (0 at start, +1 per :meth:`step`)."""
        return self._index

    @property
    def lighting(self) -> NDArray[np.float32]:
        """Relative illumination ℓ, ``(rows, cols)`` float32, read-only."""
        return self._light

    # ------------------------------------------------------------------ geometry
    def _outline(self, i: int, x: float, y: float, heading: float) -> tuple[FloatArray, FloatArray]:
        """World points (cm) on the outline of object ``i``'s top face."""
        return outline(bool(self._is_rect[i]), self._half_len[i], self._half_wid[i], x, y, heading)

    def _in_image(self, px: FloatArray, py: FloatArray, z: float) -> tuple[bool, int]:
        """Whether all points project inside the image margin; index of the worst one."""
        p = project(px, py, z, self._cam)
        m = IMAGE_MARGIN_PX
        out = np.maximum.reduce(
            [
                m - p.row,
                p.row - (self._cam.rows - 1 - m),
                m - p.col,
                p.col - (self._cam.cols - 1 - m),
            ]
        )
        out = np.where(p.valid, out, np.inf)
        worst = int(np.argmax(out))
        return bool(out[worst] <= 0.0), worst

    def _gaps(self, i: int, x: float, y: float, heading: float, others: FloatArray) -> FloatArray:
        """Smallest of the world and as-seen gaps (cm) from object ``i`` to ``others``."""
        if others.size == 0:
            return np.zeros(0)
        args = (
            self._heading[others],
            self._half_len[others],
            self._half_wid[others],
            self._is_rect[others],
        )
        world = _shape_gaps(
            x, y, heading, self._half_len[i], self._half_wid[i], bool(self._is_rect[i]),
            self._x[others], self._y[others], *args,
        )  # fmt: skip
        fx, fy = self._foot
        s, so = self._shadow[i], self._shadow[others]
        hl_o, hw_o = args[1] * so, args[2] * so
        seen = _shape_gaps(
            fx + s * (x - fx), fy + s * (y - fy), heading,
            s * self._half_len[i], s * self._half_wid[i], bool(self._is_rect[i]),
            fx + so * (self._x[others] - fx), fy + so * (self._y[others] - fy),
            args[0], hl_o, hw_o, args[3],
        )  # fmt: skip
        return np.minimum(world, seen)

    def _check(
        self, i: int, x: float, y: float, heading: float, others: FloatArray, *, quick: bool = False
    ) -> list[tuple[float, float]]:
        """Constraints object ``i`` would break at (x, y, heading): their unit normals.

        Each normal points from the obstacle (wall, image border, other object) into the
        free side, so reflecting the velocity about it bounces away. Empty if valid;
        with ``quick``, stops at the first broken constraint.
        """
        normals: list[tuple[float, float]] = []
        hl, hw = self._half_len[i], self._half_wid[i]
        if self._is_rect[i]:
            ch, sh = abs(math.cos(heading)), abs(math.sin(heading))
            ex, ey = hl * ch + hw * sh, hl * sh + hw * ch
        else:
            ex = ey = hl
        (x0, x1), (y0, y1) = self._sim.arena_x_cm, self._sim.arena_y_cm
        if x - ex < x0:
            normals.append((1.0, 0.0))
        if x + ex > x1:
            normals.append((-1.0, 0.0))
        if y - ey < y0:
            normals.append((0.0, 1.0))
        if y + ey > y1:
            normals.append((0.0, -1.0))
        if quick and normals:
            return normals
        px, py = self._outline(i, x, y, heading)
        inside, worst = self._in_image(px, py, float(self._z[i]))
        if not inside:
            nx, ny = x - px[worst], y - py[worst]
            norm = math.hypot(nx, ny) or 1.0
            normals.append((nx / norm, ny / norm))
            if quick:
                return normals
        gaps = self._gaps(i, x, y, heading, others)
        for j in others[gaps < MIN_GAP_CM]:
            nx, ny = x - self._x[j], y - self._y[j]
            norm = math.hypot(nx, ny) or 1.0
            normals.append((nx / norm, ny / norm))
        return normals

    def _place_all(self) -> None:
        """Draw start positions and directions until every constraint holds."""
        sim = self._sim
        n = len(self._kind)
        (x0, x1), (y0, y1) = sim.arena_x_cm, sim.arena_y_cm
        for _ in range(_PLACE_RESTARTS):
            for i in range(n):
                others = np.arange(i)
                for _ in range(_PLACE_TRIES):
                    x, y = self._rng.uniform(x0, x1), self._rng.uniform(y0, y1)
                    direction = self._rng.uniform(-math.pi, math.pi)
                    heading = direction if self._is_rect[i] else 0.0
                    if not self._check(i, x, y, heading, others, quick=True):
                        self._x[i], self._y[i] = x, y
                        self._heading[i], self._direction[i] = heading, direction
                        break
                else:
                    break  # object i found no room: start again
            else:
                return
        raise ValueError(
            f"cannot place the robot and {sim.n_obstacles} obstacles inside the arena "
            f"x {sim.arena_x_cm} cm, y {sim.arena_y_cm} cm and the image with gaps of "
            f"{MIN_GAP_CM} cm; enlarge the arena or use fewer or smaller obstacles"
        )

    # ------------------------------------------------------------------ motion
    def step(self) -> None:
        """Advance one frame: move every object, bouncing where a move would break a rule.

        Objects move one after another (robot first), each checked against the others'
        current positions, so the arena, image and gap rules hold after every move. An
        object that finds no valid move this frame stays put and picks a new direction.
        """
        if self._marked is not None:
            self._index += 1
            self._follow_paths()
            return
        n = len(self._kind)
        everyone = np.arange(n)
        for i in range(n):
            speed = self._speed[i]
            if speed <= 0.0:
                continue
            others = everyone[everyone != i]
            turn = self._rng.normal(0.0, _TURN_SIGMA_RAD[self._kind[i]])
            direction = self._direction[i] + turn
            vx, vy = speed * math.cos(direction), speed * math.sin(direction)
            moved = False
            for _ in range(3):  # propose, bounce off what was hit, propose again
                heading = math.atan2(vy, vx) if self._is_rect[i] else 0.0
                normals = self._check(i, self._x[i] + vx, self._y[i] + vy, heading, others)
                if not normals:
                    moved = True
                    break
                for nx, ny in normals:
                    dot = vx * nx + vy * ny
                    if dot < 0.0:
                        vx, vy = vx - 2.0 * dot * nx, vy - 2.0 * dot * ny
            if not moved:
                for d in self._rng.uniform(-math.pi, math.pi, size=_RANDOM_DIRECTIONS):
                    vx, vy = speed * math.cos(d), speed * math.sin(d)
                    heading = float(d) if self._is_rect[i] else 0.0
                    if not self._check(
                        i, self._x[i] + vx, self._y[i] + vy, heading, others, quick=True
                    ):
                        moved = True
                        break
            if moved:
                self._x[i] += vx
                self._y[i] += vy
                self._direction[i] = math.atan2(vy, vx)
                if self._is_rect[i]:
                    self._heading[i] = self._direction[i]
            else:
                self._direction[i] = self._rng.uniform(-math.pi, math.pi)
        self._index += 1

    def truth(self) -> FrameTruth:
        """Ground truth of the current frame."""
        objects = []
        for i, kind in enumerate(self._kind):
            rect = bool(self._is_rect[i])
            length, width = 2.0 * self._half_len[i], 2.0 * self._half_wid[i]
            radius = math.sqrt(length * width / math.pi) if rect else self._half_len[i]
            heading = math.degrees(self._heading[i]) if rect else 0.0
            heading = (heading + 180.0) % 360.0 - 180.0
            extra: dict[str, float | int] = {}
            if self._marked is not None and i < len(self._paths.cx):
                vx, vy = self._paths.velocity(self._index)
                fps = self._sim.fps
                extra = {
                    "marker_id": self._marked.marker_ids[i],
                    "vx_cm_s": float(vx[i]) * fps,
                    "vy_cm_s": float(vy[i]) * fps,
                }
            objects.append(
                SimObject(
                    id=self._ids[i],
                    kind=kind,  # type: ignore[arg-type]
                    x_cm=float(self._x[i]),
                    y_cm=float(self._y[i]),
                    z_cm=float(self._z[i]),
                    radius_cm=float(radius),
                    heading_deg=180.0 if heading == -180.0 else heading,
                    shape="rect" if rect else "disk",
                    length_cm=float(length),
                    width_cm=float(width),
                    **extra,  # type: ignore[arg-type]
                )
            )
        return FrameTruth(index=self._index, objects=objects)

    # ------------------------------------------------------------------ rendering
    def _paint_object(self, level: NDArray[np.float32], i: int) -> None:
        x, y = float(self._x[i]), float(self._y[i])
        h, z = float(self._heading[i]), float(self._z[i])
        plane = self._plane(z)
        paint_top_face(
            level, self._cam, self._sim, x=x, y=y, z=z, heading=h,
            half_len=float(self._half_len[i]), half_wid=float(self._half_wid[i]),
            is_rect=bool(self._is_rect[i]), samples=plane,
        )  # fmt: skip
        if self._marked is not None and i < len(self._marked.marker_ids):
            paint_marker(
                level, self._cam, self._sim, cells=self._marked.cells[i],
                side_cm=self._marked.side_cm[i], hand=self._marked.hand,
                x=x, y=y, z=z, heading=h, samples=plane,
            )  # fmt: skip

    def _paint_clutter(self, level: NDArray[np.float32]) -> None:
        """Draw this frame's clutter specks on the floor (Z = 0) into ``level``."""
        sim, cam = self._sim, self._cam
        if sim.clutter_count == 0 or sim.clutter_area_cm2[1] <= 0.0:
            return
        rng = np.random.default_rng([self._seed, self._index, _STREAM_CLUTTER])
        n = len(self._kind)
        fx, fy = self._foot
        s = self._shadow
        # Every object twice: its footprint and its top face as seen (see _gaps).
        ox = np.concatenate([self._x, fx + s * (self._x - fx)])
        oy = np.concatenate([self._y, fy + s * (self._y - fy)])
        oh = np.concatenate([self._heading, self._heading])
        ohl = np.concatenate([self._half_len, s * self._half_len])
        ohw = np.concatenate([self._half_wid, s * self._half_wid])
        orect = np.concatenate([self._is_rect, self._is_rect])
        assert ox.size == 2 * n
        placed: list[tuple[float, float, float]] = []
        m = IMAGE_MARGIN_PX
        for _ in range(sim.clutter_count):
            area = rng.uniform(*sim.clutter_area_cm2)
            a2, a3 = rng.uniform(0.0, 0.25, size=2)
            p2, p3 = rng.uniform(0.0, 2.0 * math.pi, size=2)
            # r(φ) = r0·(1 + a2 cos(2φ + p2) + a3 cos(3φ + p3)) encloses π r0² (1 + (a2² + a3²)/2).
            r0 = math.sqrt(area / (math.pi * (1.0 + 0.5 * (a2 * a2 + a3 * a3))))
            bound = r0 * (1.0 + a2 + a3)
            if r0 <= 0.0:
                continue
            for _ in range(_CLUTTER_TRIES):
                row = rng.uniform(m, cam.rows - 1 - m)
                col = rng.uniform(m, cam.cols - 1 - m)
                bp = back_project(row, col, cam, 0.0)
                if not bp.valid:
                    continue
                x, y = float(bp.x_cm), float(bp.y_cm)
                gaps = _shape_gaps(x, y, 0.0, bound, bound, False, ox, oy, oh, ohl, ohw, orect)
                if gaps.min() < CLUTTER_CLEARANCE_CM:
                    continue
                if any(
                    math.hypot(x - qx, y - qy) - bound - qb < CLUTTER_SPACING_CM
                    for qx, qy, qb in placed
                ):
                    continue
                placed.append((x, y, bound))
                phi = np.linspace(0.0, 2.0 * math.pi, 24, endpoint=False)
                rad = bound / math.cos(math.pi / 24)
                px, py = x + rad * np.cos(phi), y + rad * np.sin(phi)

                def inside(
                    X: FloatArray,
                    Y: FloatArray,
                    x: float = x,
                    y: float = y,
                    r0: float = r0,
                    k: tuple[float, float, float, float] = (a2, a3, p2, p3),
                ) -> NDArray[np.bool_]:
                    dx, dy = X - x, Y - y
                    phi = np.arctan2(dy, dx)
                    r = r0 * (
                        1.0 + k[0] * np.cos(2.0 * phi + k[2]) + k[1] * np.cos(3.0 * phi + k[3])
                    )
                    return dx * dx + dy * dy <= r * r

                paint_shape(level, cam, sim.supersample, px, py, 0.0, inside, sim.clutter_level,
                            self._plane(0.0))  # fmt: skip
                break

    def render(
        self, *, clean: bool = False, clutter: bool | None = None
    ) -> tuple[NDArray[np.uint8], FrameTruth]:
        """Render the current frame.

        Parameters
        ----------
        clean : bool
            If True, leave out blur, sensor noise, pepper noise and (unless ``clutter``
            says otherwise) clutter: the anti-aliased, lit scene alone.
        clutter : bool or None
            Draw the clutter specks; default ``not clean``.

        Returns
        -------
        image : (rows, cols) uint8 array
            The camera frame; pixel (i, j) is centred on row i, column j.
        truth : FrameTruth
            The objects in this frame.
        """
        sim = self._sim
        level = np.full(self._light.shape, sim.floor_level, dtype=np.float32)
        for i in range(len(self._kind)):
            self._paint_object(level, i)
        if clutter if clutter is not None else not clean:
            self._paint_clutter(level)
        rng = None if clean else np.random.default_rng([self._seed, self._index, _STREAM_NOISE])
        return finish_frame(level, self._light, sim, rng), self.truth()

    def frames(self, n: int) -> Iterator[tuple[NDArray[np.uint8], FrameTruth]]:
        """Yield ``(image, truth)`` for ``n`` consecutive frames from the current one.

        The arena is left ``n`` steps further on.
        """
        for _ in range(int(n)):
            yield self.render()
            self.step()


def control_points(truth: FrameTruth | _TruthRecord) -> list[ControlPoint]:
    """A frame's objects as control points: ``R`` for the robot (``R<id>`` for each marked
    robot), ``O1``, ``O2``, … for the obstacles (in id order), at the centres of their top
    faces (world cm)."""
    points = []
    obstacles = 0
    for obj in truth.objects:
        if obj.kind == "robot":
            name = "R" if obj.marker_id is None else f"R{obj.id}"
        else:
            obstacles += 1
            name = f"O{obstacles}"
        points.append(ControlPoint(name=name, x_cm=obj.x_cm, y_cm=obj.y_cm, z_cm=obj.z_cm))
    return points


def write_dataset(out_dir: Path, config: OvisConfig, frames: int, seed: int) -> DatasetInfo:
    """Render ``frames`` frames of a fresh :class:`Arena` and write them as a data set.

    Files in ``out_dir`` (created if missing; each written atomically):

    * ``frame_0000.png`` … — the 8-bit grey frames;
    * ``truth.json`` — ``{"seed", "preset", "camera", "frames": [{"index", "file",
      "objects": [SimObject, …]}]}``;
    * ``points.toml`` — the control points of the first frame (``R`` for the robot,
      ``O1``, ``O2``, … for the obstacles, top-face centres in cm) and a ``[config]``
      table with the full configuration, readable by
      :func:`ovis.common.config.load_points`;
    * ``checks.toml`` (with two frames or more) — the last frame's objects as check
      points and ``image`` = that frame's file, for ``ovis calibrate --check``
      (:func:`ovis.common.calibration.accuracy.load_checks`).
    """
    if int(frames) < 1:
        raise ValueError(f"frames must be at least 1, got {frames}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    arena = Arena(config, seed)
    records: list[_TruthRecord] = []
    paths: list[Path] = []
    for image, truth in arena.frames(int(frames)):
        name = f"frame_{truth.index:04d}.png"
        ok, buf = cv2.imencode(".png", image)
        if not ok:
            raise OSError(f"could not encode {name} as PNG")
        write_atomic(out_dir / name, buf.tobytes())
        paths.append(out_dir / name)
        records.append(_TruthRecord(index=truth.index, file=name, objects=truth.objects))

    truth_file = _TruthFile(
        seed=int(seed),
        preset=config.preset,
        camera=msgspec.to_builtins(config.camera),
        frames=records,
    )
    truth_path = out_dir / "truth.json"
    write_atomic(truth_path, msgspec.json.format(msgspec.json.encode(truth_file), indent=2))

    points = [msgspec.to_builtins(p) for p in control_points(records[0])]
    header = (
        f"# ovis simulated data set (seed {int(seed)}): control points = top-face centres of "
        f"the objects in {records[0].file}, world cm\n"
    )
    text = header + dump_toml({"points": points, "config": msgspec.to_builtins(config)})
    points_path = out_dir / "points.toml"
    write_atomic(points_path, text.encode("utf-8"))
    checks_path = None
    if len(records) > 1:  # held-out check points for `ovis calibrate --check`
        last = records[-1]
        checks = [msgspec.to_builtins(p) for p in control_points(last)]
        header = (
            f"# ovis simulated data set (seed {int(seed)}): check points = top-face centres "
            f"of the objects in {last.file} (not used for calibration), world cm\n"
        )
        checks_path = out_dir / "checks.toml"
        text = header + dump_toml({"image": last.file, "points": checks})
        write_atomic(checks_path, text.encode("utf-8"))
    return DatasetInfo(
        out_dir=out_dir, frames=paths, truth=truth_path, points=points_path, checks=checks_path
    )
