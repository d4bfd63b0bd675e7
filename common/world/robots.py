"""Marked robots on the floor: pose from a marker's corners, and a filter over frames.

**Pose** (:func:`marker_poses`). A marker lies flat on its robot's top at
``marker_height_cm``: its four corners are back-projected onto that plane, z = h (not the
floor: the top is nearer the camera), with the camera model in use (:class:`RobotTracker`
reads them from a :class:`~ovis.common.camera.plane_table.PlaneTable` of each marker
plane, made once per calibration). The robot's centre is
the mean of the four points (the marker is a square centred on the robot). Its heading is
the direction from the marker's bottom edge to its top edge (the marker's top faces the
robot's front), averaged with the left → right edge direction turned 90° towards it;
degrees counter-clockwise from +X in the world frame, in (−180, 180].

**Filter** (:class:`RobotFilter`), one per robot: a constant-velocity Kalman filter on
the state (x, y, vx, vy, θ, ω). The three pairs (x, vx), (y, vy), (θ, ω) do not interact,
so each is a 1-D filter with ``F = [[1, Δt], [0, 1]]``, process noise of a white
acceleration a (``Q = σ_a²·[[Δt⁴/4, Δt³/2], [Δt³/2, Δt²]]``, σ_a = ``filter.accel_cm_s2``
or ``filter.yaw_accel_deg_s2``) and a measurement of the first element with σ =
``filter.position_sigma_cm`` / ``filter.heading_sigma_deg``. The heading innovation is
wrapped to (−180, 180] and θ kept there. The rows (x, vx) and (y, vy) have the same
noises and are measured together, so their covariances stay equal: one is kept for
both. A robot not seen is predicted forward; its
``age_s`` is the time since its last sighting, and after ``pose.robot_timeout_s`` it is
dropped (a later sighting starts a new filter).
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass, field
from typing import Annotated, NamedTuple

import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.camera.plane_table import PlaneTable
from ovis.common.camera.projection import back_project
from ovis.common.config import CameraModel, PoseConfig, RobotSpec
from ovis.common.vision.markers import Markers
from ovis.common.world.planner import wrap_angle_deg

__all__ = [
    "MarkerPoses",
    "RobotFilter",
    "RobotState",
    "RobotTracker",
    "UnknownMarker",
    "corner_pose",
    "marker_poses",
    "poses_of",
]

Finite = Annotated[float, msgspec.Meta(ge=-1e12, le=1e12)]
NonNegative = Annotated[float, msgspec.Meta(ge=0.0, le=1e12)]

#: Initial spread of an unseen velocity (cm/s) and yaw rate (deg/s).
_V0_SIGMA = 200.0
_W0_SIGMA = 360.0


class RobotState(msgspec.Struct, kw_only=True):
    """One marked robot in one frame: filtered pose and velocity (world cm, degrees,
    seconds). ``age_s`` is how long ago its marker was last seen (0: in this frame)."""

    id: Annotated[int, msgspec.Meta(ge=0)]
    name: str
    marker_id: Annotated[int, msgspec.Meta(ge=0)]
    x_cm: Finite
    y_cm: Finite
    z_cm: Finite
    heading_deg: Annotated[float, msgspec.Meta(gt=-180.0, le=180.0)]
    vx_cm_s: Finite
    vy_cm_s: Finite
    yaw_rate_deg_s: Finite
    age_s: NonNegative
    radius_cm: NonNegative
    #: whether ``vx_cm_s``/``vy_cm_s``/``yaw_rate_deg_s`` come from the marker seen at two
    #: capture times; false on a robot's first sighting (they are then 0, not measured)
    velocity_measured: bool = False


class UnknownMarker(msgspec.Struct, kw_only=True):
    """A decoded marker that no configured robot carries: its id, image centre, and
    floor position at ``pose.robot_height_cm`` (not a robot: nothing is tracked)."""

    marker_id: Annotated[int, msgspec.Meta(ge=0)]
    row: Finite
    col: Finite
    x_cm: Finite
    y_cm: Finite


class MarkerPoses(NamedTuple):
    """Floor pose of each marker: (n,) centre x, y (cm), heading (deg) and validity."""

    x_cm: NDArray[np.float64]
    y_cm: NDArray[np.float64]
    heading_deg: NDArray[np.float64]
    valid: NDArray[np.bool_]


def marker_poses(
    corners_rc: NDArray[np.float64], heights_cm: NDArray[np.float64], camera: CameraModel
) -> MarkerPoses:
    """Centre and heading of markers from their image corners (n, 4, 2) (row, col, in
    OpenCV's order: top-left, top-right, bottom-right, bottom-left), each on the plane
    z = ``heights_cm`` (n,)."""
    z = np.asarray(heights_cm, dtype=np.float64)[:, None]
    b = back_project(corners_rc[:, :, 0], corners_rc[:, :, 1], camera, z)
    points = np.asarray(b.x_cm) + 1j * np.asarray(b.y_cm)
    return poses_of(points, np.asarray(b.valid).reshape(points.shape))


def poses_of(points: NDArray[np.complex128], valid: NDArray[np.bool_]) -> MarkerPoses:
    """:func:`marker_poses` from the markers' corners on their planes, (n, 4) x + iy (cm)
    in OpenCV's corner order, and where each was valid: :func:`corner_pose` of each (a
    handful of markers: one formula, in plain Python)."""
    poses = [
        corner_pose(*corners) if ok else None
        for corners, ok in zip(points.tolist(), valid.all(axis=1).tolist(), strict=True)
    ]
    x, y, heading = (
        np.array([math.nan if p is None else p[k] for p in poses], dtype=np.float64)
        for k in range(3)
    )
    return MarkerPoses(x, y, heading, np.array([p is not None for p in poses], dtype=bool))


def corner_pose(
    tl: complex, tr: complex, br: complex, bl: complex
) -> tuple[float, float, float] | None:
    """One marker's (x, y, heading) from its corners on its plane (x + iy, cm, OpenCV's
    order), None when not valid (a corner not finite, or all on one line): its centre,
    and the direction from its bottom edge to its top edge turned by 90° towards the
    right-hand edge's one (which way depends on the world's handedness)."""
    if not all(map(cmath.isfinite, (tl, tr, br, bl))):
        return None
    up, across = (tl + tr - bl - br) / 2.0, (tr + br - tl - bl) / 2.0
    cross = (across.conjugate() * up).imag
    if cross == 0.0:
        return None
    forward = up + (1j if cross > 0.0 else -1j) * across
    centre = (tl + tr + br + bl) / 4.0
    heading = math.degrees(math.atan2(forward.imag, forward.real))
    return centre.real, centre.imag, wrap_angle_deg(heading)


@dataclass
class RobotFilter:
    """Constant-velocity Kalman filter of one robot (see the module docstring).

    ``value``/``rate`` hold (x, y, θ) and (vx, vy, ω); ``position`` the 2×2 covariance
    ``[p00, p01, p11]`` of the rows (x, vx) and (y, vy) (equal: one for both),
    ``heading`` that of (θ, ω). Plain floats: for these few 2-state rows, scalar
    arithmetic costs less than numpy's small-array calls.
    """

    accel_var: tuple[float, float]  # σ_a² of the white acceleration: position, heading
    noise_var: tuple[float, float]  # σ² of one measurement: position, heading
    value: list[float]
    rate: list[float]
    position: list[float]
    heading: list[float]
    stamp_s: float
    seen_s: float
    start_s: float  # the first measurement's stamp

    @property
    def rate_measured(self) -> bool:
        """Whether the velocity comes from measurements at two capture times (before
        the second, it is the start's 0, not a measurement)."""
        return self.seen_s > self.start_s

    @classmethod
    def start(
        cls, pose: PoseConfig, x: float, y: float, heading: float, stamp_s: float
    ) -> RobotFilter:
        f = pose.filter
        noise = (f.position_sigma_cm**2, f.heading_sigma_deg**2)
        accel = (f.accel_cm_s2**2, f.yaw_accel_deg_s2**2)
        return cls(
            accel, noise, [x, y, wrap_angle_deg(heading)], [0.0, 0.0, 0.0],
            [noise[0], 0.0, _V0_SIGMA**2], [noise[1], 0.0, _W0_SIGMA**2], stamp_s, stamp_s,
            stamp_s,
        )  # fmt: skip

    @property
    def state(self) -> NDArray[np.float64]:
        """(3, 2): rows (x, vx), (y, vy), (θ, ω)."""
        return np.array([self.value, self.rate]).T

    def predict(self, stamp_s: float) -> None:
        """Move the state to ``stamp_s`` (no-op for an earlier or equal stamp)."""
        dt = stamp_s - self.stamp_s
        if dt <= 0.0:
            return
        value, rate = self.value, self.rate
        value[0] += rate[0] * dt
        value[1] += rate[1] * dt
        value[2] = wrap_angle_deg(value[2] + rate[2] * dt)
        q = (dt**4 / 4.0, dt**3 / 2.0, dt * dt)
        self.position = _predicted(self.position, dt, self.accel_var[0], q)
        self.heading = _predicted(self.heading, dt, self.accel_var[1], q)
        self.stamp_s = stamp_s

    def update(self, x: float, y: float, heading: float | None) -> None:
        """Fold in one measurement taken at the current stamp (a marker's; without a
        heading, the position alone: an unmarked robot's centre)."""
        value, rate = self.value, self.rate
        (k0, k1), self.position = _corrected(self.position, self.noise_var[0])
        dx, dy = x - value[0], y - value[1]
        value[0] += k0 * dx
        value[1] += k0 * dy
        rate[0] += k1 * dx
        rate[1] += k1 * dy
        self.seen_s = self.stamp_s
        if heading is None:
            return
        (k0, k1), self.heading = _corrected(self.heading, self.noise_var[1])
        turn = wrap_angle_deg(heading - value[2])
        value[2] = wrap_angle_deg(value[2] + k0 * turn)
        rate[2] += k1 * turn


def _predicted(
    p: list[float], dt: float, accel_var: float, q: tuple[float, float, float]
) -> list[float]:
    """One row's covariance ``[p00, p01, p11]`` moved on by ``dt``: F·P·Fᵀ + σ_a²·Q."""
    p00, p01, p11 = p
    return [
        p00 + 2.0 * dt * p01 + dt * dt * p11 + accel_var * q[0],
        p01 + dt * p11 + accel_var * q[1],
        p11 + accel_var * q[2],
    ]


def _corrected(p: list[float], noise_var: float) -> tuple[tuple[float, float], list[float]]:
    """One row's Kalman gain (k0, k1) for a measurement of its first element with
    variance ``noise_var``, and its covariance ``[p00, p01, p11]`` after it."""
    p00, p01, p11 = p
    s = p00 + noise_var
    k0, k1 = p00 / s, p01 / s
    return (k0, k1), [(1.0 - k0) * p00, (1.0 - k0) * p01, p11 - k1 * p01]


@dataclass
class RobotTracker:
    """Every configured robot's filter; one :meth:`update` per frame."""

    pose: PoseConfig
    filters: dict[int, RobotFilter] = field(default_factory=dict)  # by robot id
    #: the configured robots by marker id, and in id order (set from ``pose``)
    _by_marker: dict[int, RobotSpec] = field(init=False, repr=False)
    _in_order: list[RobotSpec] = field(init=False, repr=False)
    #: each marker plane's table, for the camera they were made with
    _tables: dict[float, PlaneTable] = field(default_factory=dict, repr=False)
    _camera: CameraModel | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self._index()

    def _index(self) -> None:
        self._by_marker = {r.marker_id: r for r in self.pose.robots}
        self._in_order = sorted(self.pose.robots, key=lambda r: r.id)

    def reconfigure(self, pose: PoseConfig) -> None:
        """New settings; filters of robots still configured with the same marker are kept."""
        keep = {(r.id, r.marker_id) for r in pose.robots}
        old = {r.id: r.marker_id for r in self.pose.robots}
        self.filters = {k: f for k, f in self.filters.items() if (k, old.get(k)) in keep}
        self.pose = pose
        self._index()

    def prepare(self, camera: CameraModel) -> None:
        """Make ``camera``'s tables of the configured markers' planes now (at start, or
        for a new calibration before the frames use it), so that no frame waits."""
        heights = {r.marker_height_cm for r in self.pose.robots}
        tables = {h: PlaneTable(camera, h) for h in heights}
        self._tables, self._camera = tables, camera

    def update(
        self, markers: Markers, camera: CameraModel, stamp_s: float
    ) -> tuple[list[RobotState], list[UnknownMarker]]:
        """Fold in this frame's markers; the robots still tracked and the unknown markers."""
        if camera is not self._camera:
            self._camera, self._tables = camera, {}
        specs = self._by_marker
        measured: dict[int, tuple[float, float, float]] = {}
        unknown: list[UnknownMarker] = []
        # a few markers a frame: plain Python per marker costs less than array calls
        for marker, corners in zip(markers.ids.tolist(), markers.corners.tolist(), strict=True):
            robot = specs.get(marker)
            height = self.pose.robot_height_cm if robot is None else robot.marker_height_cm
            z = self._pose(corners, height, camera)
            if z is None:
                continue
            if robot is None:
                rows, cols = zip(*corners, strict=True)
                unknown.append(
                    UnknownMarker(
                        marker_id=marker,
                        row=sum(rows) / 4.0,
                        col=sum(cols) / 4.0,
                        x_cm=z[0],
                        y_cm=z[1],
                    )
                )
                continue
            if robot.id in measured:  # the same marker twice: keep the one nearer the filter
                z = self._nearer(robot.id, measured[robot.id], z)
            measured[robot.id] = z
        states: list[RobotState] = []
        for robot in self._in_order:
            f = self.filters.get(robot.id)
            z = measured.get(robot.id)
            if f is None and z is None:
                continue
            if f is None:
                f = self.filters[robot.id] = RobotFilter.start(self.pose, *z, stamp_s)  # type: ignore[misc]
            else:
                f.predict(stamp_s)
                if z is not None:
                    f.update(*z)
            age = max(stamp_s - f.seen_s, 0.0)
            if age > self.pose.robot_timeout_s:
                del self.filters[robot.id]
                continue
            states.append(_state(robot, f, age))
        return states, unknown

    def _pose(
        self, corners: list[list[float]], height_cm: float, camera: CameraModel
    ) -> tuple[float, float, float] | None:
        """One marker's (x, y, heading) from its four image corners (row, col), on the
        plane z = ``height_cm`` (read from that plane's table, made once per camera)."""
        table = self._tables.get(height_cm)
        if table is None:
            table = self._tables[height_cm] = PlaneTable(camera, height_cm)
        return corner_pose(*table.points(corners))

    def _nearer(
        self, robot_id: int, a: tuple[float, float, float], b: tuple[float, float, float]
    ) -> tuple[float, float, float]:
        f = self.filters.get(robot_id)
        if f is None:
            return a
        x, y = f.value[0], f.value[1]
        return a if np.hypot(a[0] - x, a[1] - y) <= np.hypot(b[0] - x, b[1] - y) else b


def _state(robot: RobotSpec, f: RobotFilter, age: float) -> RobotState:
    (x, y, heading), (vx, vy, yaw_rate) = f.value, f.rate
    return RobotState(
        id=robot.id,
        name=robot.name,
        marker_id=robot.marker_id,
        x_cm=x,
        y_cm=y,
        z_cm=robot.marker_height_cm,
        heading_deg=wrap_angle_deg(heading),
        vx_cm_s=vx,
        vy_cm_s=vy,
        yaw_rate_deg_s=yaw_rate,
        age_s=age,
        radius_cm=robot.radius_cm,
        velocity_measured=f.rate_measured,
    )
