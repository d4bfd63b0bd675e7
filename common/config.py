"""Configuration: msgspec Structs validated on load, TOML presets, control-point files.

A configuration file is TOML. It may name a ``preset`` (``default``, ``paper``,
``pinhole`` or ``physical``) and override any subset of its fields (a ``[camera]`` table
of another ``model`` than the preset's replaces the preset's camera instead); the merged result
is validated in one pass, and a bad value is reported with its path and the allowed
range, e.g.
``Expected `float` <= 1.0 - at `$.camera.s_x```.
"""

from __future__ import annotations

import math
import tomllib
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec

__all__ = [
    "CALIBRATED_VARIABLES",
    "KEEP_CALIBRATIONS",
    "MARKER_DICTIONARIES",
    "PINHOLE_VARIABLES",
    "PRESETS",
    "CalibrationRanges",
    "CameraModel",
    "CameraParams",
    "CameraSpec",
    "ConfigError",
    "ControlPoint",
    "FusionConfig",
    "GAConfig",
    "ImageParams",
    "NavigationConfig",
    "OvisConfig",
    "PhysicalConfig",
    "PinholeParams",
    "PinholeRanges",
    "PointsFile",
    "PoseConfig",
    "RobotFilterConfig",
    "RobotSpec",
    "Ros2Config",
    "ServiceConfig",
    "SimulatorConfig",
    "TrustConfig",
    "ZenohConfig",
    "load_config",
    "load_points",
    "preset_text",
    "resolve_config",
    "router_zenoh",
    "with_ga",
    "with_options",
]

PRESETS = ("default", "paper", "pinhole", "physical")

#: Calibration versions the calibrator keeps (``[service] keep_calibrations``'s default).
KEEP_CALIBRATIONS = 20

#: The nine variables the GA tunes (paper §4), in the paper's order.
CALIBRATED_VARIABLES = (
    "threshold",
    "size_filter_cm2",
    "Z0_cm",
    "lam_mm",
    "k1",
    "k2",
    "k3",
    "s_x",
    "s_y",
)


class ConfigError(ValueError):
    """A configuration or points file that cannot be used; the message says why."""


def _rng(lo: float, hi: float) -> Any:
    return Annotated[float, msgspec.Meta(ge=lo, le=hi)]


Length = _rng(-1e5, 1e5)
Positive = Annotated[float, msgspec.Meta(gt=0.0, le=1e6)]
Coefficient = _rng(-1.0, 1.0)
Fraction = _rng(0.0, 1.0)
PairF = tuple[float, float]


def _check_pair(owner: str, name: str, pair: PairF, lo: float, hi: float) -> None:
    a, b = pair
    if not (math.isfinite(a) and math.isfinite(b)):
        raise ValueError(f"{owner}.{name} must be finite, got [{a}, {b}]")
    if a > b:
        raise ValueError(f"{owner}.{name}: lower bound {a} is above upper bound {b}")
    if a < lo or b > hi:
        raise ValueError(f"{owner}.{name} = [{a}, {b}] must lie within [{lo}, {hi}]")


class CameraParams(
    msgspec.Struct, tag_field="model", tag="paper", forbid_unknown_fields=True, kw_only=True
):
    """Constants and parameters of the paper's camera model (eqs. 4–10).

    Lengths of the set-up are in cm, of the image plane in mm; ``c_x``/``c_y`` are the row
    and column of the image centre (the paper's x_f is the row). ``Z0_cm, lam_mm, k1, k2,
    k3, s_x, s_y`` are the calibrated ones; the rest are fixed constants of the set-up.
    Functions of :mod:`ovis.common.camera.paper_model` also accept instances whose calibrated fields
    hold numpy arrays (a GA population). ``model = "paper"`` is the tag that tells it
    from :class:`PinholeParams` in a configuration or calibration file.
    """

    rows: Annotated[int, msgspec.Meta(ge=8, le=20000)]
    cols: Annotated[int, msgspec.Meta(ge=8, le=20000)]
    d_x_mm: Positive
    d_y_mm: Positive
    N_fx: Positive
    N_fy: Positive
    c_x: Length
    c_y: Length
    X0_cm: Length
    Y0_cm: Length
    L_cm: Length
    r1_cm: Length
    r2_cm: Length
    r3_cm: Length
    theta_deg: Annotated[float, msgspec.Meta(gt=0.0, le=90.0)]
    Z0_cm: Length
    lam_mm: Positive
    k1: Coefficient = 0.0
    k2: Coefficient = 0.0
    k3: Coefficient = 0.0
    s_x: Positive
    s_y: Positive

    @property
    def model(self) -> Literal["paper"]:
        """The camera model's tag, ``"paper"``."""
        return "paper"


class PinholeParams(
    msgspec.Struct, tag_field="model", tag="pinhole", forbid_unknown_fields=True, kw_only=True
):
    """A pinhole camera with 6-DoF pose and Brown–Conrady distortion, exactly OpenCV's.

    OpenCV's pixel x is the **column** and y the **row**: ``fx``, ``cx`` act on columns,
    ``fy``, ``cy`` on rows (ovis's own APIs always say row/col). The pose maps world
    points (cm) into the camera, ``p_cam = R(rvec)·p_world + tvec_cm`` (OpenCV's
    world → camera convention; ``rvec`` is a Rodrigues vector in radians, so the
    camera centre is ``−Rᵀ·tvec_cm``). Distortion coefficients are in OpenCV's order
    ``(k1, k2, p1, p2, k3)``. A negative focal length mirrors the image (the paper
    model's equivalent pinhole has one, see :mod:`ovis.common.camera.export`).
    ``pixel_pitch_mm`` only converts pixel errors to millimetres on the image plane
    (the paper's DIPE unit); it plays no part in the projection. Functions of
    :mod:`ovis.common.camera.pinhole` also accept instances whose fields hold numpy arrays (a
    GA population).
    """

    rows: Annotated[int, msgspec.Meta(ge=8, le=20000)]
    cols: Annotated[int, msgspec.Meta(ge=8, le=20000)]
    fx: _rng(-1e6, 1e6)  # focal length along columns, px
    fy: _rng(-1e6, 1e6)  # focal length along rows, px
    cx: Length  # principal point column (OpenCV x), px
    cy: Length  # principal point row (OpenCV y), px
    k1: _rng(-1e3, 1e3) = 0.0
    k2: _rng(-1e3, 1e3) = 0.0
    p1: _rng(-1e3, 1e3) = 0.0
    p2: _rng(-1e3, 1e3) = 0.0
    k3: _rng(-1e3, 1e3) = 0.0
    rvec: tuple[Length, Length, Length]  # Rodrigues vector, world → camera, rad
    tvec_cm: tuple[Length, Length, Length]  # translation, world → camera, cm
    pixel_pitch_mm: Positive | None = None  # None: unknown, errors in px only

    def __post_init__(self) -> None:
        for name in ("fx", "fy"):
            value = getattr(self, name)  # (population cameras hold arrays: not checked)
            if isinstance(value, float | int) and abs(value) < 1e-9:
                raise ValueError(f"camera.{name} must not be 0 (a focal length in pixels)")

    @property
    def model(self) -> Literal["pinhole"]:
        """The camera model's tag, ``"pinhole"``."""
        return "pinhole"

    @property
    def d_x_mm(self) -> float:
        """Pixel pitch along rows, mm (square pixels: ``pixel_pitch_mm``; NaN: unknown)."""
        return math.nan if self.pixel_pitch_mm is None else self.pixel_pitch_mm

    @property
    def d_y_mm(self) -> float:
        """Pixel pitch along columns, mm (square pixels: ``pixel_pitch_mm``; NaN: unknown)."""
        return self.d_x_mm


#: Either camera model; the ``model`` field of ``[camera]`` says which.
CameraModel = CameraParams | PinholeParams

#: The pinhole variables the GA can tune (see :class:`PinholeRanges`), in GA order.
PINHOLE_VARIABLES = (
    "fx",
    "fy",
    "cx",
    "cy",
    "k1",
    "k2",
    "p1",
    "p2",
    "k3",
    "rvec_x",
    "rvec_y",
    "rvec_z",
    "tvec_x_cm",
    "tvec_y_cm",
    "tvec_z_cm",
)


class PinholeRanges(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Search range [lo, hi] of each pinhole variable (``[calibration.pinhole]``).

    A variable left out (or given as ``[v, v]``) is fixed at the configured camera's
    value. ``rvec_x..z`` are the Rodrigues vector's components (rad), ``tvec_*_cm`` the
    translation's (cm); ``fx, cx`` act on columns, ``fy, cy`` on rows (OpenCV).
    """

    fx: PairF | None = None
    fy: PairF | None = None
    cx: PairF | None = None
    cy: PairF | None = None
    k1: PairF | None = None
    k2: PairF | None = None
    p1: PairF | None = None
    p2: PairF | None = None
    k3: PairF | None = None
    rvec_x: PairF | None = None
    rvec_y: PairF | None = None
    rvec_z: PairF | None = None
    tvec_x_cm: PairF | None = None
    tvec_y_cm: PairF | None = None
    tvec_z_cm: PairF | None = None

    def __post_init__(self) -> None:
        for name in PINHOLE_VARIABLES:
            pair = getattr(self, name)
            if pair is not None:
                _check_pair("calibration.pinhole", name, pair, -1e6, 1e6)


class ImageParams(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Image pipeline settings (paper §3). ``threshold``/``size_filter_cm2`` are calibrated.

    Beyond the paper, for real floors (:mod:`ovis.common.vision.segmentation`,
    :mod:`ovis.common.vision.contrast`):
    ``threshold_mode`` "fixed" (the paper's grey level), "otsu" (Otsu's level of the
    frame), "adaptive" (``threshold`` applied to the local contrast: the frame minus its
    Gaussian local mean over ``block_px``, by default a window that follows the objects,
    plus 128) or "auto" (Otsu's level of that local contrast around the objects);
    ``background``, an image of the empty floor subtracted first (then
    128 is "as the empty floor"); ``roi``, a mask image (non-zero: look here);
    ``max_size_cm2``, the largest object kept. ``size_filter_cm2`` is compared with a
    blob's area on the obstacles' top plane (``pose.obstacle_height_cm``), or on the
    floor when heights are measured (``pose.heights``): a silhouette carried onto the
    floor covers at least its footprint.
    """

    median: Literal["paper", "ordinary", "none"] = "paper"
    polarity: Literal["bright", "dark"] = "bright"
    threshold: Annotated[int, msgspec.Meta(ge=0, le=255)] = 128
    size_filter_cm2: _rng(0.0, 1e6) = 20.0
    perimeter: Literal["kb", "crofton"] = "kb"
    threshold_mode: Literal["fixed", "otsu", "adaptive", "auto"] = "fixed"
    block_px: Annotated[int, msgspec.Meta(ge=0, le=100001)] = 0  # 0: follows the objects
    background: str | None = None
    roi: str | None = None
    max_size_cm2: Annotated[float, msgspec.Meta(gt=0.0, le=1e9)] | None = None
    #: how far an edge spreads in this camera's frames (the σ of a Gaussian blur, px):
    #: the sub-pixel outlines of measured heights model it (:mod:`ovis.common.vision.outline`)
    edge_blur_px: Annotated[float, msgspec.Meta(ge=0.2, le=5.0)] = 0.6
    #: the sensor noise of this camera's frames (grey levels, 1σ)
    noise_sigma: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)] = 1.5


class CalibrationRanges(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Search range [lo, hi] of each GA variable (paper §5.1)."""

    threshold: PairF = (100.0, 230.0)
    size_filter_cm2: PairF = (20.0, 50.0)
    Z0_cm: PairF = (125.0, 150.0)
    lam_mm: PairF = (3.5, 8.0)
    k1: PairF = (-1e-6, 1e-6)
    k2: PairF = (-1e-6, 1e-6)
    k3: PairF = (-1e-6, 1e-6)
    s_x: PairF = (0.1, 1.0)
    s_y: PairF = (0.1, 1.0)
    #: after the GA, move the threshold and size filter to the middle of the values that
    #: still see exactly one object per control point (robust on later frames)
    centre_image_settings: bool = True
    #: ranges of the pinhole model's variables (used when ``camera.model = "pinhole"``;
    #: the camera variables above are then unused, threshold and size filter are shared)
    pinhole: PinholeRanges | None = None

    def __post_init__(self) -> None:
        limits = {
            "threshold": (0.0, 255.0),
            "size_filter_cm2": (0.0, 1e6),
            "Z0_cm": (-1e5, 1e5),
            "lam_mm": (1e-6, 1e6),
            "k1": (-1.0, 1.0),
            "k2": (-1.0, 1.0),
            "k3": (-1.0, 1.0),
            "s_x": (1e-6, 1e6),
            "s_y": (1e-6, 1e6),
        }
        for name, (lo, hi) in limits.items():
            _check_pair("calibration", name, getattr(self, name), lo, hi)

    def bounds(self) -> tuple[tuple[float, float], ...]:
        """The ranges in :data:`CALIBRATED_VARIABLES` order."""
        return tuple(tuple(getattr(self, n)) for n in CALIBRATED_VARIABLES)  # type: ignore[misc]


class GAConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Binary-coded GA settings (paper §4–5.1); the paper's best: 100, 90, 0.9, 0.005."""

    population: Annotated[int, msgspec.Meta(ge=2, le=100000)] = 100
    generations: Annotated[int, msgspec.Meta(ge=1, le=100000)] = 90
    pc: Fraction = 0.9
    pm: Fraction = 0.005
    bits: Annotated[int, msgspec.Meta(ge=2, le=30)] = 10
    tournament: Annotated[int, msgspec.Meta(ge=2, le=64)] = 3
    elitism: Annotated[int, msgspec.Meta(ge=0, le=1000)] = 1
    seed: Annotated[int, msgspec.Meta(ge=0)] = 0
    coding: Literal["binary", "gray"] = "gray"
    #: after the GA, polish the continuous camera parameters by bounded least squares
    #: (:mod:`ovis.common.calibration.refine`; beyond the paper). False here and in the ``paper``
    #: preset (the paper's method); the ``default`` preset turns it on.
    polish: bool = False


#: Marker dictionaries ``[pose] marker_dictionary`` may name, and how many markers each
#: holds (ids run from 0): AprilTag 36h11 and OpenCV's ArUco 4×4, 5×5 and 6×6 sets.
MARKER_DICTIONARIES: dict[str, int] = {
    "apriltag_36h11": 587,
    **{f"aruco_{n}x{n}_{k}": k for n in (4, 5, 6) for k in (50, 100, 250, 1000)},
}

MarkerDictionary = Literal[
    "apriltag_36h11",
    "aruco_4x4_50",
    "aruco_4x4_100",
    "aruco_4x4_250",
    "aruco_4x4_1000",
    "aruco_5x5_50",
    "aruco_5x5_100",
    "aruco_5x5_250",
    "aruco_5x5_1000",
    "aruco_6x6_50",
    "aruco_6x6_100",
    "aruco_6x6_250",
    "aruco_6x6_1000",
]

Angle = _rng(-360.0, 360.0)
#: A camera's name becomes a Zenoh key chunk (``ovis/<arena>/cam/<name>/…``).
CameraName = Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_.-]{1,64}$")]


class RobotSpec(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """One marked robot (``[[pose.robots]]``): its identity and the marker on its top.

    ``marker_side_cm`` is the side of the marker's black square (what OpenCV calls the
    marker length), printed flat on the robot's top at ``marker_height_cm`` above the
    floor with its top edge towards the robot's front (its heading), centred on the
    robot's centre. ``radius_cm`` is the robot's footprint radius: blobs within it are
    the robot's, and the other robots plan around a disk of that radius. A goal point
    or goal line of its own overrides ``[pose] goal_cm``/``goal_angle_deg``.
    """

    id: Annotated[int, msgspec.Meta(ge=0, le=1_000_000)]
    name: Annotated[str, msgspec.Meta(min_length=1, max_length=64)]
    marker_id: Annotated[int, msgspec.Meta(ge=0, le=100_000)]
    marker_side_cm: Annotated[float, msgspec.Meta(gt=0.0, le=1e4)]
    marker_height_cm: _rng(0.0, 1e4)
    radius_cm: Annotated[float, msgspec.Meta(gt=0.0, le=1e4)]
    goal_cm: PairF | None = None
    goal_angle_deg: Angle | None = None

    def __post_init__(self) -> None:
        if self.goal_cm is not None and not all(math.isfinite(v) for v in self.goal_cm):
            raise ValueError(f"pose.robots: robot {self.name!r} goal_cm must be finite")


class RobotFilterConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """The constant-velocity Kalman filter of each marked robot (``[pose.filter]``; see
    :mod:`ovis.common.world.robots`): the spread of the unmodelled accelerations (white
    noise driving the velocities) and of one marker measurement."""

    accel_cm_s2: Annotated[float, msgspec.Meta(gt=0.0, le=1e6)] = 100.0
    yaw_accel_deg_s2: Annotated[float, msgspec.Meta(gt=0.0, le=1e7)] = 2000.0
    position_sigma_cm: Annotated[float, msgspec.Meta(gt=0.0, le=1e3)] = 0.02
    heading_sigma_deg: Annotated[float, msgspec.Meta(gt=0.0, le=180.0)] = 0.15


class PoseConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Robot/obstacle rule, object heights, tracking and goal (paper §5.2).

    With configured heights (``heights``), the robot is the blob with the lowest
    compactness among those whose compactness is at most ``robot_max_compactness`` and
    whose floor area lies in ``robot_area_cm2``, and back-projection uses the plane of
    each class's top face (``*_height_cm``). With measured heights, every solid's
    footprint and height are measured and the unmarked robot is the box of
    ``robot_size_cm`` and ``robot_height_cm``.
    """

    robot_max_compactness: _rng(0.0, 2.0) = 0.92
    robot_area_cm2: PairF = (60.0, 600.0)
    robot_height_cm: _rng(0.0, 1e4) = 5.0
    obstacle_height_cm: _rng(0.0, 1e4) = 7.0
    track_gate_cm: Annotated[float, msgspec.Meta(gt=0.0, le=1e4)] = 20.0
    goal_cm: PairF | None = None
    goal_angle_deg: _rng(-360.0, 360.0) | None = None
    #: marked robots; empty: the one robot is picked by the compactness rule above
    robots: Annotated[list[RobotSpec], msgspec.Meta(max_length=1000)] = []
    marker_dictionary: MarkerDictionary = "aruco_4x4_50"
    #: a marked robot not seen for this long (s) is dropped; until then it is reported
    #: where its filter predicts it, with the age of its last sighting
    robot_timeout_s: Annotated[float, msgspec.Meta(gt=0.0, le=3600.0)] = 1.0
    filter: RobotFilterConfig = msgspec.field(default_factory=RobotFilterConfig)
    #: "configured": every object's top face is taken to lie at its class's height
    #: (``robot_height_cm``, ``obstacle_height_cm``) and its position is its blob's
    #: centroid carried onto that plane (the light simulator's flat tops); "measured":
    #: each solid's shape, footprint and height are fitted to its silhouette
    #: (:mod:`ovis.common.solids`; needs ``[image] background``, the empty floor)
    heights: Literal["configured", "measured"] = "configured"
    #: with measured heights, the classes whose configured height is declared true: not
    #: measured, used as it is (the footprint is still fitted, at that height)
    declared_heights: Annotated[list[Literal["robot", "obstacle"]], msgspec.Meta(max_length=2)] = []
    #: the unmarked robot's footprint, length × width (cm): with measured heights it is
    #: the box of this size and ``robot_height_cm`` (not the least compact blob)
    robot_size_cm: PairF = (16.0, 10.0)
    #: a measured height less certain than this (1σ, cm) is not measurable there: the
    #: class's configured height is reported instead, and said
    height_sigma_max_cm: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)] = 0.35
    #: with measured heights, full fits of a blob's solids per frame (a new or changed
    #: blob, or a periodic refit that averages a height over its track); 0: every blob
    #: that needs one, at once (offline)
    fits_per_frame: Annotated[int, msgspec.Meta(ge=0, le=1000)] = 1

    def __post_init__(self) -> None:
        _check_pair("pose", "robot_area_cm2", self.robot_area_cm2, 0.0, 1e7)
        _check_pair("pose", "robot_size_cm", tuple(sorted(self.robot_size_cm)), 0.1, 1e4)
        if len(set(self.declared_heights)) != len(self.declared_heights):
            raise ValueError(f"pose.declared_heights repeats a class: {self.declared_heights}")
        if self.goal_cm is not None and not all(math.isfinite(v) for v in self.goal_cm):
            raise ValueError("pose.goal_cm must be finite")
        size = MARKER_DICTIONARIES[self.marker_dictionary]
        by_marker: dict[int, RobotSpec] = {}
        by_id: dict[int, RobotSpec] = {}
        for robot in self.robots:
            if robot.marker_id >= size:
                raise ValueError(
                    f"pose.robots: robot {robot.name!r} has marker_id {robot.marker_id} but "
                    f"{self.marker_dictionary} holds markers 0-{size - 1}"
                )
            other = by_marker.setdefault(robot.marker_id, robot)
            if other is not robot:
                raise ValueError(
                    f"pose.robots: robots {other.name!r} (id {other.id}) and {robot.name!r} "
                    f"(id {robot.id}) both use marker {robot.marker_id}; give each its own"
                )
            other = by_id.setdefault(robot.id, robot)
            if other is not robot:
                raise ValueError(
                    f"pose.robots: robots {other.name!r} and {robot.name!r} both have id "
                    f"{robot.id}; give each its own"
                )


class SimulatorConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """The built-in simulated arena: what is on the floor and how the frame looks."""

    arena_x_cm: PairF = (15.0, 115.0)
    arena_y_cm: PairF = (15.0, 130.0)
    n_obstacles: Annotated[int, msgspec.Meta(ge=0, le=500)] = 3
    obstacle_radius_cm: PairF = (4.0, 6.0)
    robot_size_cm: PairF = (16.0, 10.0)
    speed_cm_per_frame: _rng(0.0, 1e3) = 2.0
    floor_level: _rng(0.0, 255.0) = 70.0
    object_level: _rng(0.0, 255.0) = 215.0
    lighting_gradient: Fraction = 0.25
    vignetting: Fraction = 0.2
    noise_sigma: _rng(0.0, 100.0) = 4.0
    pepper_fraction: Fraction = 0.01
    blur_sigma_px: _rng(0.0, 10.0) = 0.6
    clutter_count: Annotated[int, msgspec.Meta(ge=0, le=10000)] = 6
    clutter_area_cm2: PairF = (1.0, 12.0)
    clutter_level: _rng(0.0, 255.0) = 235.0
    supersample: Annotated[int, msgspec.Meta(ge=1, le=8)] = 3
    #: grey level of a marker's black cells (marked robots, ``pose.robots``)
    marker_level: _rng(0.0, 255.0) = 25.0
    #: simulated frames per second: the ground truth's velocities are in cm/s at this rate
    fps: Annotated[float, msgspec.Meta(gt=0.0, le=10000.0)] = 30.0
    #: "light": the built-in flat-top painter (the paper's figures, speed); "physical":
    #: solid objects in MuJoCo (``[physical]``, :mod:`ovis.common.physical`)
    world: Literal["light", "physical"] = "light"

    def __post_init__(self) -> None:
        _check_pair("simulator", "arena_x_cm", self.arena_x_cm, -1e5, 1e5)
        _check_pair("simulator", "arena_y_cm", self.arena_y_cm, -1e5, 1e5)
        _check_pair("simulator", "obstacle_radius_cm", self.obstacle_radius_cm, 0.1, 1e4)
        _check_pair("simulator", "clutter_area_cm2", self.clutter_area_cm2, 0.0, 1e6)
        if min(self.robot_size_cm) <= 0:
            raise ValueError("simulator.robot_size_cm must be positive (length, width)")


Shape = Literal["cylinder", "box", "prism"]


class PhysicalConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """The physical world (``[physical]``, ``--world physical``; :mod:`ovis.common.physical`):
    solid obstacles of mixed shapes and heights on a dark floor under ceiling lights,
    simulated and rendered by MuJoCo through the configured camera (the arena is
    ``[simulator] arena_x_cm × arena_y_cm``; the robots are ``simulator.robot_size_cm``
    boxes ``pose.robot_height_cm`` tall, marked ones carrying their marker on top).

    Obstacles: ``n_obstacles`` solids, each a cylinder, a box at any yaw or an upright
    prism with 3, 5 or 6 sides (``shapes``), as wide as a disk of radius in
    ``radius_cm`` and ``height_cm`` tall, moving at up to ``speed_cm_s`` on closed paths
    that keep ``gap_cm`` between any two footprints (0: still). Light: ``lights``
    ceiling lamps ``light_height_cm`` up casting shadows (``shadows``) and an ambient
    share ``ambient``; grey albedos of the floor and the objects; Gaussian sensor noise
    ``noise_sigma`` (grey levels); ``samples`` anti-aliasing samples per pixel.
    """

    n_obstacles: Annotated[int, msgspec.Meta(ge=0, le=64)] = 6
    shapes: Annotated[list[Shape], msgspec.Meta(min_length=1, max_length=3)] = msgspec.field(
        default_factory=lambda: ["cylinder", "box", "prism"]
    )
    radius_cm: PairF = (3.0, 7.0)
    height_cm: PairF = (1.0, 25.0)
    gap_cm: _rng(0.0, 100.0) = 3.0
    speed_cm_s: _rng(0.0, 500.0) = 6.0
    robots_move: bool = True
    floor_albedo: Fraction = 0.12
    object_albedo: PairF = (0.55, 0.9)
    lights: Annotated[int, msgspec.Meta(ge=1, le=8)] = 2
    light_height_cm: _rng(50.0, 2000.0) = 260.0
    ambient: Fraction = 0.25
    shadows: bool = True
    noise_sigma: _rng(0.0, 50.0) = 1.5
    samples: Annotated[int, msgspec.Meta(ge=0, le=16)] = 4
    #: flat discs on the floor at known places, for calibrating the camera on them
    #: (``ovis simulate --world physical`` writes them as control points)
    floor_marks: Annotated[int, msgspec.Meta(ge=0, le=64)] = 8
    mark_radius_cm: _rng(0.2, 20.0) = 1.0

    def __post_init__(self) -> None:
        _check_pair("physical", "radius_cm", self.radius_cm, 0.5, 100.0)
        _check_pair("physical", "height_cm", self.height_cm, 0.5, 100.0)
        _check_pair("physical", "object_albedo", self.object_albedo, 0.0, 1.0)


class ZenohConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """How a service joins the Zenoh network.

    ``config_file`` (a Zenoh JSON5 configuration, e.g. the secure profile in ``deploy/``)
    is loaded first; ``mode``, ``connect`` and ``listen`` then override it when set.
    """

    mode: Literal["client", "peer", "router"] = "client"
    connect: list[str] = msgspec.field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    listen: list[str] = []
    config_file: str | None = None
    multicast_scouting: bool = False
    #: frames and other large messages written once into shared memory, read by the
    #: subscribers on the same host without the network (across hosts Zenoh sends the
    #: bytes instead); false sends everything over the network
    shared_memory: bool = True


class ServiceConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Settings of the running services (``ovis run``/``ovis up``)."""

    arena: str = "default"
    #: "sim" (the simulated arena), a folder of images, a video file, a camera:
    #: "camera:0" (OpenCV index) or a device path such as "/dev/video0", or a stream
    #: URL (rtsp://, http://, https://) opened by OpenCV.
    source: str = "sim"
    #: camera and stream settings asked of the device (OpenCV capture properties; a
    #: device may refuse them: the frames' real size is what counts)
    camera_width: Annotated[int, msgspec.Meta(ge=1, le=20000)] | None = None
    camera_height: Annotated[int, msgspec.Meta(ge=1, le=20000)] | None = None
    camera_fps: Annotated[float, msgspec.Meta(gt=0.0, le=10000.0)] | None = None
    #: exposure in the driver's unit (V4L2: 100 µs steps); None leaves it automatic
    camera_exposure: Annotated[float, msgspec.Meta(ge=-1e6, le=1e6)] | None = None
    fps: Annotated[float, msgspec.Meta(ge=0.0, le=10000.0)] = 30.0  # 0: as fast as possible
    loop: bool = True  # replay a folder or video from the start when it ends
    seed: Annotated[int, msgspec.Meta(ge=0)] = 0  # simulated arena seed
    #: simulated arena only: 0 renders each frame live; N renders N frames once at start
    #: and replays them in a loop (fresh sequence numbers and stamps), so that the
    #: renderer is not the bottleneck when measuring the pipeline (``benchmarks/``)
    prerender: Annotated[int, msgspec.Meta(ge=0, le=100000)] = 0
    #: where the calibrator keeps its versioned calibrations
    state_dir: str = "ovis-state"
    #: control points: "simulator" (the simulated frame's ground truth) or a points file
    points: str = "simulator"
    auto_calibrate: bool = True  # calibrate on the first frame when nothing is saved
    #: the largest GA the calibrator runs (its configured one and any a query asks for):
    #: population (memory grows with it), population × generations (time grows with
    #: it), and the seconds one calibration may take before it is cancelled
    max_population: Annotated[int, msgspec.Meta(ge=2, le=100000)] = 1000
    max_evaluations: Annotated[int, msgspec.Meta(ge=2, le=10**9)] = 200_000
    calibration_budget_s: Annotated[float, msgspec.Meta(gt=0.0, le=86400.0)] = 120.0
    status_period_s: Annotated[float, msgspec.Meta(gt=0.0, le=3600.0)] = 1.0
    frame_timeout_s: Annotated[float, msgspec.Meta(gt=0.0, le=3600.0)] = 2.0
    queue_depth: Annotated[int, msgspec.Meta(ge=1, le=1000)] = 2
    #: CPU cores this service's process may run on (Linux); empty: any. Stages that pass
    #: frames to each other run fastest on one shared core at camera rates: each wakes
    #: on the core the previous one just left, with the libraries' code still in cache
    #: (``ovis up`` does this by default, see ``--pin``).
    cpus: Annotated[
        list[Annotated[int, msgspec.Meta(ge=0, le=4095)]], msgspec.Meta(max_length=4096)
    ] = []
    #: one camera of several (``[[cameras]]``): this process is in that camera's chain
    #: and its topics are ``ovis/<arena>/cam/<camera_name>/…``; None: the one camera
    camera_name: CameraName | None = None
    #: the cameras of ``[[cameras]]`` a stage process serves, each on its own topics
    #: (``ovis run STAGE --cameras a,b``); empty: every one listed
    cameras: Annotated[list[CameraName], msgspec.Meta(max_length=64)] = []
    #: how ``ovis up --cameras`` lays out a host's cameras: "per-stage", one process per
    #: stage serving every camera of the host; "per-camera", one process per stage per
    #: camera (a camera per host)
    layout: Literal["per-stage", "per-camera"] = "per-stage"
    #: an MCAP source another tool wrote: the topic of the image channel to read (empty:
    #: its only image channel); ``ovis up --topic``
    source_topic: Annotated[str, msgspec.Meta(max_length=4096)] = ""
    #: calibration versions the calibrator keeps in ``state_dir`` (older ones are
    #: deleted when it saves a new one)
    keep_calibrations: Annotated[int, msgspec.Meta(ge=1, le=100000)] = KEEP_CALIBRATIONS

    def __post_init__(self) -> None:
        if self.camera_name is not None and self.cameras:
            raise ValueError(
                f"service: camera_name {self.camera_name!r} makes this process one camera's "
                f"chain; cameras {self.cameras} names several: give one or the other"
            )
        if len(set(self.cameras)) != len(self.cameras):
            raise ValueError(f"service: cameras {self.cameras} names a camera twice")
        if self.source_topic and not self.source.lower().endswith(".mcap"):
            raise ValueError(
                f"source_topic {self.source_topic!r} picks a channel of an MCAP file, but "
                f"the source is {self.source!r}: give an .mcap source or no topic"
            )

    @property
    def simulated_source(self) -> bool:
        """Whether ``source`` is the simulator ("sim" or a simulated grid camera):
        anything else is a real camera's frames, which need a calibration of their own."""
        return self.source == "sim" or self.source.startswith("grid:")


class TrustConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Where the keys of the proof of origin are (``[trust]``, docs/trust.md): the
    calibrator, the pose stage, fusion and the planner sign with ``<keys_dir>/<role>.key``
    (made on first start); the others trust ``<keys_dir>/<role>.pub``, or the public key
    files named here (copied from the host that made them)."""

    keys_dir: Annotated[str, msgspec.Meta(max_length=4096)] = ""  # "": <state_dir>/keys
    calibrator_public: Annotated[str, msgspec.Meta(max_length=4096)] = ""
    pose_public: Annotated[str, msgspec.Meta(max_length=4096)] = ""
    fusion_public: Annotated[str, msgspec.Meta(max_length=4096)] = ""
    planner_public: Annotated[str, msgspec.Meta(max_length=4096)] = ""


class CameraSpec(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """One of several cameras over one arena (``[[cameras]]``): its name, its source (as
    ``service.source``) and its camera model calibrated to the *shared* floor frame
    (``camera``, inline) or a calibration file saved by ``ovis calibrate``/``ovis locate``
    (``calibration``); exactly one of the two."""

    name: CameraName
    source: Annotated[str, msgspec.Meta(min_length=1, max_length=4096)] = "sim"
    camera: CameraModel | None = None
    calibration: Annotated[str, msgspec.Meta(min_length=1, max_length=4096)] | None = None
    #: the camera's own image of its empty floor (its ``[image] background``); None:
    #: the arena's ``[image] background``
    background: Annotated[str, msgspec.Meta(min_length=1, max_length=4096)] | None = None

    def __post_init__(self) -> None:
        if (self.camera is None) == (self.calibration is None):
            raise ValueError(
                f"cameras: camera {self.name!r} needs exactly one of camera (a model) "
                "or calibration (a file)"
            )


class FusionConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """How the fusion service merges the cameras' detections (``[fusion]``, see
    :mod:`ovis.common.fusion`).

    Frames whose capture stamps lie within ``match_window_ms`` of each other form one
    world frame; a world frame waits at most ``wait_ms`` for a late camera, and a frame
    arriving after its world frame left is counted as late. A camera's position error at
    a floor point is ``pixel_sigma_px`` pushed through its back-projection Jacobian;
    two obstacles are one when their distance is within ``gate_sigmas`` of the combined
    error (plus ``gate_floor_cm``) and their radii differ by at most ``radius_gate_cm``.
    A world obstacle keeps its identity while it moves less than ``track_gate_cm`` per
    frame and is dropped after ``lost_frames`` frames unseen. A solid's footprint and
    height fitted by several cameras are merged by their covariances, each camera's
    (x, y) variance raised by ``footprint_bias_cm``² (what a fit's own covariance leaves
    out); the merged height counts as measured where its σ is at most
    ``height_sigma_max_cm``. Cameras' fitted heights (and footprints) of one obstacle
    disagree when their χ² about the merged point has a probability below
    ``disagree_p`` (:mod:`ovis.common.fusion.merge`).
    """

    match_window_ms: Annotated[float, msgspec.Meta(gt=0.0, le=10000.0)] = 10.0
    wait_ms: Annotated[float, msgspec.Meta(ge=0.0, le=10000.0)] = 20.0
    pixel_sigma_px: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)] = 0.3
    gate_sigmas: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)] = 5.0
    gate_floor_cm: Annotated[float, msgspec.Meta(ge=0.0, le=1e4)] = 1.0
    radius_gate_cm: Annotated[float, msgspec.Meta(ge=0.0, le=1e4)] = 2.0
    track_gate_cm: Annotated[float, msgspec.Meta(gt=0.0, le=1e4)] = 10.0
    lost_frames: Annotated[int, msgspec.Meta(ge=1, le=100000)] = 15
    disagree_p: Annotated[float, msgspec.Meta(gt=0.0, lt=1.0)] = 0.001
    footprint_bias_cm: Annotated[float, msgspec.Meta(ge=0.0, le=100.0)] = 0.15
    height_sigma_max_cm: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)] = 0.35


#: What the ROS 2 bridge can publish (``[ros2] topics``).
ROS2_TOPICS = ("obstacles", "markers", "odom", "camera_info", "image", "tf_static")


class Ros2Config(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """ovis as a ROS 2 node over rmw_zenoh (``ovis up --ros2``, docs/ros2.md): the ROS 2
    domain, the node's namespace and name, the floor's TF frame, which topics it
    publishes, the rates of the topics people watch (markers, the camera image; poses
    and odometry go with every frame), and the Zenoh router of the ROS 2 side
    (``rmw_zenohd``; empty: ovis's own bus). The rates' defaults are the ones the
    benchmark row ``ros2`` measures."""

    domain_id: Annotated[int, msgspec.Meta(ge=0, le=232)] = 0
    namespace: Annotated[str, msgspec.Meta(pattern=r"^(/[A-Za-z_][A-Za-z0-9_]*)+$")] = "/ovis"
    node: Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")] = "ovis"
    frame_id: Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z_][A-Za-z0-9_/]*$")] = "ovis_floor"
    topics: list[Literal[ROS2_TOPICS]] = msgspec.field(default_factory=lambda: list(ROS2_TOPICS))
    #: MarkerArrays per second on ``markers``, by the frames' capture stamps (0: none)
    markers_rate_hz: Annotated[float, msgspec.Meta(ge=0.0, le=1000.0)] = 2.0
    #: camera images (with their CameraInfo) per second on ``camera/image/compressed``,
    #: by the frames' capture stamps (0: none)
    image_rate_hz: Annotated[float, msgspec.Meta(ge=0.0, le=1000.0)] = 1.0
    #: JPEG quality of those images
    image_quality: Annotated[int, msgspec.Meta(ge=1, le=100)] = 80
    #: the ROS 2 side's router (e.g. rmw_zenohd's ``tcp/127.0.0.1:7447``); empty: the
    #: ROS 2 topics go on ovis's own Zenoh bus
    connect: list[str] = []


Planner = Literal["fuzzy", "dwa", "straight"]


class NavigationConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Robots driven to their goals (``[navigation]``, docs/navigation.md;
    :mod:`ovis.common.navigation`).

    **Planner**: ``planner`` (the genetic-fuzzy planner, the dynamic window baseline or
    the straight-to-goal driver); ``planner_file``, a tuned fuzzy planner (``ovis
    navigate --tune``; empty: the one shipped); a robot is at its goal within
    ``goal_tolerance_cm``.

    **Robots** (differential drive, :mod:`ovis.common.navigation.base`): top speed
    ``max_speed_cm_s`` and acceleration ``max_accel_cm_s2`` of each wheel's rim, and
    ``brake_cm_s2`` when a safety rule stops it; turn rate at most
    ``max_yaw_rate_deg_s``.

    **Safety** (robot side): a robot stops when no command came for
    ``command_timeout_s``, or when the frame a command was made from is older than
    ``max_frame_age_s`` (also the planner's limit: it never drives on an older frame).
    ``follow``: what the physical world's robots follow: ovis's signed commands
    (``"ovis"``), or each robot's ROS 2 ``cmd_vel`` (``"cmd_vel"``: a TwistStamped
    with no proof of origin, docs/navigation.md; ``ovis up --drive --follow cmd_vel``).
    ``cmd_vel``: the planner also publishes each command as ROS 2's ``TwistStamped`` on
    ``<[ros2] namespace>/robots/robot_<id>/cmd_vel`` (``ovis up --drive --ros2``).
    ``drive``: the physical world's live source is the seed's scenario, its robots
    driven by the commands (``ovis up --world physical --drive``). A robot whose marker
    was not seen in a frame (an obstacle touching it merges their blobs) is planned
    for on the pose filter's prediction for at most ``predict_s``, then told to stop.

    **Scenarios** (``ovis navigate``, ``ovis up --drive``): ``case`` 1 (two obstacles)
    or 2 (four) crossing the robots' paths at up to ``obstacle_speed`` × the top speed;
    ``robots`` driven robots; frames and commands at ``rate_hz``; the pipeline's latency
    (frame capture → command at the robot) drawn per frame from a log-normal with median
    and 99th percentile ``latency_ms``; a run ends unfinished after ``timeout_factor`` ×
    the straight-line time at top speed.
    """

    planner: Planner = "fuzzy"
    planner_file: Annotated[str, msgspec.Meta(max_length=4096)] = ""
    goal_tolerance_cm: Annotated[float, msgspec.Meta(gt=0.0, le=1e3)] = 4.0
    max_speed_cm_s: Annotated[float, msgspec.Meta(gt=0.0, le=1e3)] = 20.0
    max_accel_cm_s2: Annotated[float, msgspec.Meta(gt=0.0, le=1e4)] = 60.0
    brake_cm_s2: Annotated[float, msgspec.Meta(gt=0.0, le=1e4)] = 300.0
    max_yaw_rate_deg_s: Annotated[float, msgspec.Meta(gt=0.0, le=3600.0)] = 240.0
    command_timeout_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 0.22
    max_frame_age_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 0.5
    follow: Literal["ovis", "cmd_vel"] = "ovis"
    cmd_vel: bool = False
    drive: bool = False
    predict_s: Annotated[float, msgspec.Meta(ge=0.0, le=10.0)] = 0.3
    case: Literal[1, 2] = 2
    robots: Annotated[int, msgspec.Meta(ge=1, le=2)] = 1
    obstacle_speed: Annotated[float, msgspec.Meta(gt=0.0, le=1.0)] = 0.6
    rate_hz: Annotated[float, msgspec.Meta(gt=0.0, le=1000.0)] = 10.0
    latency_ms: PairF = (45.0, 90.0)
    timeout_factor: Annotated[float, msgspec.Meta(ge=1.0, le=100.0)] = 3.0

    def __post_init__(self) -> None:
        _check_pair("navigation", "latency_ms", self.latency_ms, 0.0, 10000.0)


class OvisConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Everything ovis needs: camera, image pipeline, GA ranges and settings, pose, simulator."""

    preset: Literal["default", "paper", "pinhole", "physical"] = "default"
    camera: CameraModel
    image: ImageParams = msgspec.field(default_factory=ImageParams)
    calibration: CalibrationRanges = msgspec.field(default_factory=CalibrationRanges)
    ga: GAConfig = msgspec.field(default_factory=GAConfig)
    pose: PoseConfig = msgspec.field(default_factory=PoseConfig)
    simulator: SimulatorConfig = msgspec.field(default_factory=SimulatorConfig)
    physical: PhysicalConfig = msgspec.field(default_factory=PhysicalConfig)
    service: ServiceConfig = msgspec.field(default_factory=ServiceConfig)
    zenoh: ZenohConfig = msgspec.field(default_factory=ZenohConfig)
    #: several cameras over one arena, fused into one world (empty: the one ``camera``)
    cameras: Annotated[list[CameraSpec], msgspec.Meta(max_length=64)] = []
    fusion: FusionConfig = msgspec.field(default_factory=FusionConfig)
    trust: TrustConfig = msgspec.field(default_factory=TrustConfig)
    ros2: Ros2Config = msgspec.field(default_factory=Ros2Config)
    navigation: NavigationConfig = msgspec.field(default_factory=NavigationConfig)

    @property
    def starts_with_configured_camera(self) -> bool:
        """Whether the stages may work with the configured camera until a calibration
        comes: the light simulator's frames are painted through it, and the simulated
        grid's chains are given their cameras; the physical world's single camera, like a
        real one, waits for the calibrator's (made on its floor marks)."""
        if not self.service.simulated_source:
            return False
        return not (self.service.source == "sim" and self.simulator.world == "physical")

    def __post_init__(self) -> None:
        names = [c.name for c in self.cameras]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(f"cameras: names must be unique, {', '.join(twice)} repeated")
        unknown = [n for n in self.service.cameras if n not in names]
        if unknown:
            listed = ", ".join(names) or "none"
            raise ValueError(
                f"service: cameras {', '.join(unknown)} not in [[cameras]] (listed: {listed})"
            )
        renders_its_floor = self.service.simulated_source and self.simulator.world == "physical"
        if self.pose.heights == "measured" and not (self.image.background or renders_its_floor):
            raise ValueError(
                'pose.heights = "measured" needs image.background, an image of the empty '
                "floor (objects are told from it by being brighter); the physical world's "
                "own source renders it at start"
            )


class ControlPoint(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """A named calibration point, world cm: the centre of an object's top face (a blob,
    matched by predicted position), or a point whose pixel position ``row``, ``col`` is
    known (a board corner, a marker, a clicked point: no blob matching)."""

    name: str
    x_cm: Length
    y_cm: Length
    z_cm: Length = 0.0
    row: Length | None = None  # pixel row (px), with col
    col: Length | None = None

    def __post_init__(self) -> None:
        if (self.row is None) != (self.col is None):
            raise ValueError(f"control point {self.name!r}: give both row and col, or neither")

    @property
    def pixel_known(self) -> bool:
        return self.row is not None


class PointsFile(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """A control-points file: the points and, optionally, the configuration they go with."""

    points: list[ControlPoint]
    config: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        if not self.points:
            raise ValueError("a points file needs at least one [[points]] entry")
        names = [p.name for p in self.points]
        if len(set(names)) != len(names):
            raise ValueError(f"control point names must be unique, got {names}")


def preset_text(name: str) -> str:
    """The commented TOML text of a built-in preset."""
    if name not in PRESETS:
        raise ConfigError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")
    return resources.files("ovis.common.presets").joinpath(f"{name}.toml").read_text("utf-8")


def _deep_merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _deep_merge(out[key], value)
        else:
            out[key] = value
    return out


def config_from_dict(data: dict[str, Any], source: str = "configuration") -> OvisConfig:
    """Validate a configuration mapping, laid over the preset it names (default ``default``)."""
    preset = data.get("preset", "default")
    if preset not in PRESETS:
        raise ConfigError(
            f"{source}: unknown preset {preset!r} - at `$.preset`; choose one of "
            f"{', '.join(PRESETS)}"
        )
    base = tomllib.loads(preset_text(preset))
    camera, preset_model = data.get("camera"), base["camera"]["model"]
    if isinstance(camera, dict) and camera.get("model", preset_model) != preset_model:
        # another camera model than the preset's: its [camera] table is not a base
        base = {k: v for k, v in base.items() if k != "camera"}
    merged = _deep_merge(base, data)
    try:
        return msgspec.convert(merged, OvisConfig)
    except msgspec.ValidationError as exc:
        raise ConfigError(f"{source}: {exc}") from None


def _read_toml(path: Path, what: str) -> dict[str, Any]:
    try:
        text = Path(path).read_text("utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{what} {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read {what} {path}: {exc}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{what} {path} is not valid TOML: {exc}") from None


def load_config(path: Path | str | None = None, *, preset: str = "default") -> OvisConfig:
    """Load and validate a TOML configuration file, or a bare preset when ``path`` is None."""
    if path is None:
        return config_from_dict({"preset": preset}, f"preset {preset}")
    return config_from_dict(_read_toml(Path(path), "configuration file"), str(path))


def load_points(path: Path | str) -> PointsFile:
    """Load a control-points TOML file (``[[points]]`` with name, x_cm, y_cm, z_cm)."""
    data = _read_toml(Path(path), "points file")
    try:
        points = msgspec.convert(data, PointsFile)
    except msgspec.ValidationError as exc:
        raise ConfigError(
            f"points file {path}: {exc}. Expected [[points]] tables with name, x_cm, y_cm, "
            "z_cm (default 0) and, for points whose pixel is known, row and col (px)"
        ) from None
    if points.config is not None:
        config_from_dict(points.config, f"points file {path}, [config]")
    return points


def dump_toml(obj: msgspec.Struct | dict[str, Any]) -> str:
    """TOML text of a Struct or mapping (None fields are left out: TOML has no null)."""
    import tomli_w

    data = msgspec.to_builtins(obj) if isinstance(obj, msgspec.Struct) else obj

    def drop_none(v: Any) -> Any:
        if isinstance(v, dict):
            return {k: drop_none(x) for k, x in v.items() if x is not None}
        if isinstance(v, list):
            return [drop_none(x) for x in v]
        return v

    return tomli_w.dumps(drop_none(data))


def resolve_config(
    config_file: Path | None, preset: str | None, points_config: dict[str, Any] | None = None
) -> OvisConfig:
    """The configuration a command works with: the ``--config`` file, else a points
    file's ``[config]`` table (when no preset is named), else the preset (default
    ``default``)."""
    if config_file is not None:
        return load_config(config_file)
    if points_config is not None and preset is None:
        return config_from_dict(points_config, "points file [config]")
    return load_config(preset=preset or "default")


def with_options(
    config_file: Path | None,
    *,
    connect: list[str] | None = None,
    listen: list[str] | None = None,
    mode: str | None = None,
    preset: str | None = None,
    world: str | None = None,
    **service: Any,
) -> OvisConfig:
    """The configuration (a file, else ``preset``, by default the default preset) with
    command-line options laid over it, validated again: Zenoh's connect (when given),
    listen and mode, the simulated ``world`` (``[simulator] world``) and every
    ``[service]`` field that is not None."""
    if config_file is not None:
        cfg = load_config(config_file)
    else:
        cfg = load_config(preset=preset or "default")
    data = msgspec.to_builtins(cfg)
    if world is not None:
        data["simulator"]["world"] = world
    if connect:
        data["zenoh"]["connect"] = connect
    if listen is not None:
        data["zenoh"]["listen"] = listen
    if mode is not None:
        data["zenoh"]["mode"] = mode
    data["service"].update({k: v for k, v in service.items() if v is not None})
    return config_from_dict(data, "configuration with command-line options")


def with_ga(config: OvisConfig, **ga: Any) -> OvisConfig:
    """The configuration with the ``[ga]`` fields given (not None) replaced."""
    given = {k: v for k, v in ga.items() if v is not None}
    if not given:
        return config
    return msgspec.structs.replace(config, ga=msgspec.structs.replace(config.ga, **given))


def router_zenoh(
    config: OvisConfig,
    config_file: Path | None,
    *,
    listen: list[str] | None,
    connect: list[str] | None,
    default_endpoint: str,
) -> ZenohConfig:
    """A router's Zenoh settings: the command line's ``listen``/``connect`` first, then
    what the configuration file's ``[zenoh]`` section itself sets, else listen on
    ``default_endpoint`` (none when a Zenoh JSON5 file names the endpoints) and mesh
    with no other router."""
    given: dict[str, Any] = {}
    if config_file is not None:
        given = _read_toml(Path(config_file), "configuration file").get("zenoh", {})
    zc = config.zenoh
    default_listen = [] if zc.config_file else [default_endpoint]
    return msgspec.structs.replace(
        zc,
        listen=listen or (zc.listen if "listen" in given else default_listen),
        connect=connect or (zc.connect if "connect" in given else []),
    )
