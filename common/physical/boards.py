"""A printed chessboard in the physical world, held before a camera or lying on the floor,
rendered by MuJoCo through an ovis camera, with the true place of its inner corners: what
``ovis intrinsics`` and ``ovis calibrate --board`` are checked against.

The board is a mosaic of black and white tiles in a white margin one square wide, all
boxes of one thickness whose printed faces lie in one plane (exact edges, no relief). It
is laid out in the frame of :func:`ovis.common.vision.boards.board_points`: inner corner
(i, j) at (i·S, j·S, 0), the tile diagonally beyond corner 0 black, z into the board (the
printed face looks along −z). A :class:`BoardPose` places that frame in the world (cm).

:class:`BoardScene` renders it through any calibrated camera with the camera mapping,
lens resampling and sensor noise of the physical world (:func:`render_camera`,
:func:`~ovis.common.physical.model.add_camera`,
:func:`~ovis.common.physical.world.grey_frame`, :func:`~ovis.common.physical.world.sensor_noise`),
lit from the camera and without shadows; with ``floor=True`` over a dark floor. It
renders at a multiple of the camera's resolution and averages it down (the camera
scaled exactly, :func:`~ovis.common.camera.scaling.scale_camera`): MuJoCo's multisampling
alone leaves an edge's pixels a few coverage steps, which move corners by tenths of a
pixel. :func:`held_poses` draws poses a person holding the board up would give;
:func:`lying_on_floor` lays it face up on the floor.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import mujoco
import numpy as np
from numpy.typing import NDArray

from ovis.common.camera import pinhole
from ovis.common.camera.projection import project
from ovis.common.camera.scaling import scale_camera
from ovis.common.config import CameraModel, PinholeParams
from ovis.common.physical.camera import CM_PER_M, render_camera
from ovis.common.physical.model import add_camera
from ovis.common.physical.world import grey_frame, sensor_noise
from ovis.common.vision.boards import BoardSpec, board_points

__all__ = [
    "PRINT_CM",
    "BoardPose",
    "BoardScene",
    "held_poses",
    "lying_on_floor",
]

#: Thickness of the printed board (cm): paper on the floor, a card held up.
PRINT_CM = 0.01
#: Albedo of the black and white tiles and of the floor under a lying board (the
#: physical world's default floor).
BLACK, WHITE, FLOOR = 0.05, 0.9, 0.12
#: Light: the share from everywhere, and from the camera's direction.
AMBIENT, HEADLIGHT = 0.3, 0.6
#: Near and far clipping distances (m): near enough for a board 45 cm away, far enough
#: for the floor behind it, and depth resolution finer than the paper's thickness.
Z_NEAR_M, Z_FAR_M = 0.05, 20.0
#: Pixels an outer edge of the board (with its margin) keeps from the image border.
IMAGE_MARGIN_PX = 4.0
#: Poses drawn per pose kept before :func:`held_poses` gives up.
TRIES = 200
_STREAM_NOISE, _STREAM_POSES = 11, 12


class BoardPose(NamedTuple):
    """Where the board's frame is in the world: ``rotation``'s columns are its x, y, z
    axes, ``origin_cm`` is its first inner corner (world cm)."""

    rotation: NDArray[np.float64]
    origin_cm: NDArray[np.float64]

    def world(self, board_xyz: NDArray[np.floating]) -> NDArray[np.float64]:
        """World positions (cm) of points given in the board's frame, (N, 3)."""
        return np.asarray(board_xyz, np.float64) @ self.rotation.T + self.origin_cm

    def corners_cm(self, spec: BoardSpec) -> NDArray[np.float64]:
        """World positions (cm) of the board's inner corners, in OpenCV's corner order."""
        return self.world(board_points(spec))


def lying_on_floor(spec: BoardSpec, x_cm: float, y_cm: float, angle_deg: float) -> BoardPose:
    """The board face up on the floor, the middle of its inner corners at (``x_cm``,
    ``y_cm``), its first row (x) at ``angle_deg`` from the world's +X (counter-clockwise
    seen from above), its printed face :data:`PRINT_CM` above the floor. Its other rows
    lie to the right of the first (its y is the row turned 90° clockwise)."""
    a = math.radians(angle_deg)
    x = np.array([math.cos(a), math.sin(a), 0.0])
    z = np.array([0.0, 0.0, -1.0])
    rotation = np.column_stack([x, np.cross(z, x), z])
    middle = np.array([(spec.cols - 1) / 2.0, (spec.rows - 1) / 2.0, 0.0]) * spec.square
    return BoardPose(rotation, np.array([x_cm, y_cm, PRINT_CM]) - rotation @ middle)


def _outline(spec: BoardSpec) -> NDArray[np.float64]:
    """The board's outer edge, margin included, in its frame (points along the edge)."""
    s = spec.square
    x0, y0 = -2.0 * s, -2.0 * s
    x1, y1 = (spec.cols + 1) * s, (spec.rows + 1) * s
    t = np.linspace(0.0, 1.0, 9)[:, None]
    ends = [((x0, y0), (x1, y0)), ((x1, y0), (x1, y1)), ((x1, y1), (x0, y1)), ((x0, y1), (x0, y0))]
    edge = [np.asarray(a) + t * (np.asarray(b) - np.asarray(a)) for a, b in ends]
    xy = np.concatenate(edge)
    return np.column_stack([xy, np.zeros(len(xy))])


def _turn(axis: NDArray[np.float64], angle_rad: float) -> NDArray[np.float64]:
    return pinhole.rodrigues(np.asarray(axis, np.float64) * angle_rad)


def held_poses(
    camera: PinholeParams,
    spec: BoardSpec,
    count: int,
    seed: int,
    *,
    distance_cm: tuple[float, float] = (45.0, 85.0),
    max_tilt_deg: float = 45.0,
    max_roll_deg: float = 45.0,
) -> list[BoardPose]:
    """``count`` poses of the board held before ``camera``, drawn from ``seed``: its centre
    ``distance_cm`` from the camera on a ray through a random pixel (of each ninth of the
    image in turn: its corners, edges and middle, as docs/real-camera.md asks), turned up to
    ``max_roll_deg`` about the line of sight and tilted up to ``max_tilt_deg`` about a
    random axis in its plane, the whole board (margin included) inside the image.

    Raises ValueError when no such pose is found in :data:`TRIES` draws per pose (a board
    too large for the view at that distance)."""
    rng = np.random.default_rng([seed, _STREAM_POSES])
    R = pinhole.rodrigues(np.asarray(camera.rvec, np.float64))
    centre_cam = -R.T @ np.asarray(camera.tvec_cm, np.float64)
    middle = np.array([(spec.cols - 1) / 2.0, (spec.rows - 1) / 2.0, 0.0]) * spec.square
    outline = _outline(spec)
    W, H = int(camera.cols), int(camera.rows)
    poses: list[BoardPose] = []
    for _ in range(count * TRIES):
        cell = len(poses) % 9  # the image's corners, edges and middle in turn
        u = rng.uniform(cell % 3, cell % 3 + 1) * W / 3.0
        v = rng.uniform(cell // 3, cell // 3 + 1) * H / 3.0
        ray = R.T @ np.array([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0])
        ray /= np.linalg.norm(ray)
        centre = centre_cam + rng.uniform(*distance_cm) * ray
        facing = np.column_stack([R[0], R[1], ray])  # x along the image's right, z away
        facing[:, 0] -= ray * (facing[:, 0] @ ray)
        facing[:, 0] /= np.linalg.norm(facing[:, 0])
        facing[:, 1] = np.cross(ray, facing[:, 0])
        roll = _turn(np.array([0.0, 0.0, 1.0]), math.radians(rng.uniform(-1, 1) * max_roll_deg))
        a = rng.uniform(0.0, 2.0 * math.pi)
        tilt = _turn(
            np.array([math.cos(a), math.sin(a), 0.0]), math.radians(rng.uniform(0.0, max_tilt_deg))
        )
        rot = facing @ tilt @ roll
        pose = BoardPose(rot, centre - rot @ middle)
        edge = pose.world(outline)
        p = project(edge[:, 0], edge[:, 1], edge[:, 2], camera)
        m = IMAGE_MARGIN_PX
        inside = (p.col >= m) & (p.col <= W - 1 - m) & (p.row >= m) & (p.row <= H - 1 - m)
        if p.valid.all() and inside.all():
            poses.append(pose)
            if len(poses) == count:
                return poses
    raise ValueError(
        f"no pose of a {spec.describe()} board of {spec.square:g} cm squares at "
        f"{distance_cm[0]:g}-{distance_cm[1]:g} cm keeps it inside the image"
    )


def _mosaic(spec: BoardSpec) -> list[tuple[NDArray[np.float64], NDArray[np.float64], float]]:
    """The board's tiles and margin as boxes: (centre, half sizes) in the board's frame
    (cm) and albedo. Tile (a, b) spans x in [(a−1)·S, a·S], y in [(b−1)·S, b·S]."""
    s, t = spec.square, PRINT_CM
    boxes = []
    for a in range(spec.cols + 1):
        for b in range(spec.rows + 1):
            centre = np.array([(a - 0.5) * s, (b - 0.5) * s, t / 2.0])
            boxes.append(
                (centre, np.array([s / 2.0, s / 2.0, t / 2.0]), (BLACK, WHITE)[(a + b) % 2])
            )
    # the margin, one square wide: two strips along x (full length), two along y between them
    x0, x1 = -2.0 * s, (spec.cols + 1) * s
    y0, y1 = -2.0 * s, (spec.rows + 1) * s
    for yc in (y0 + s / 2.0, y1 - s / 2.0):
        boxes.append(
            (
                np.array([(x0 + x1) / 2.0, yc, t / 2.0]),
                np.array([(x1 - x0) / 2.0, s / 2.0, t / 2.0]),
                WHITE,
            )
        )
    for xc in (x0 + s / 2.0, x1 - s / 2.0):
        boxes.append(
            (
                np.array([xc, (y0 + y1) / 2.0, t / 2.0]),
                np.array([s / 2.0, (y1 - y0) / 2.0 - s, t / 2.0]),
                WHITE,
            )
        )
    return boxes


class BoardScene:
    """A chessboard ``spec`` (squares of ``spec.square`` cm) seen by ``camera``, over the
    a dark floor when ``floor`` (module docstring). ``samples``: MuJoCo's anti-aliasing
    samples per pixel; ``supersample``: the factor of the resolution rendered and averaged
    down; ``noise_sigma``: sensor noise (grey levels) drawn from ``seed`` and each frame's
    index.

    Raises ValueError for a camera that cannot be rendered (as
    :func:`~ovis.common.physical.camera.render_camera`).
    """

    CAMERA = "board_cam"

    def __init__(
        self,
        spec: BoardSpec,
        camera: CameraModel,
        *,
        floor: bool = False,
        samples: int = 4,
        supersample: int = 3,
        noise_sigma: float = 1.5,
        seed: int = 0,
    ) -> None:
        if spec.kind != "chessboard":
            raise ValueError(f"only chessboards are rendered, not {spec.describe()}")
        self.spec, self.camera = spec, camera
        self.noise_sigma, self.seed = float(noise_sigma), int(seed)
        self.supersample = int(supersample)
        k = self.supersample
        self.rendered = render_camera(scale_camera(camera, k * camera.rows, k * camera.cols))
        mj = mujoco.MjSpec()
        mj.modelname = "ovis_board"
        mj.stat.extent = 1.0  # clipping distances below in metres
        vis = mj.visual
        vis.global_.offwidth, vis.global_.offheight = self.rendered.canvas
        vis.quality.offsamples = int(samples)
        vis.headlight.active = 1
        vis.headlight.ambient = [AMBIENT] * 3
        vis.headlight.diffuse = [HEADLIGHT] * 3
        vis.headlight.specular = [0.0] * 3
        vis.map.znear, vis.map.zfar = Z_NEAR_M, Z_FAR_M
        if floor:
            mj.worldbody.add_geom(
                type=mujoco.mjtGeom.mjGEOM_PLANE,
                size=[20.0, 20.0, 0.1],
                rgba=[FLOOR, FLOOR, FLOOR, 1.0],
                contype=0,
                conaffinity=0,
            )
        body = mj.worldbody.add_body(name="board", mocap=True)
        for centre, half, albedo in _mosaic(spec):
            body.add_geom(
                type=mujoco.mjtGeom.mjGEOM_BOX,
                size=(half / CM_PER_M).tolist(),
                pos=(centre / CM_PER_M).tolist(),
                rgba=[albedo, albedo, albedo, 1.0],
                contype=0,
                conaffinity=0,
            )
        add_camera(mj, self.CAMERA, self.rendered)
        self.model = mj.compile()
        self.data = mujoco.MjData(self.model)
        w, h = self.rendered.canvas
        self._renderer = mujoco.Renderer(self.model, h, w)

    def render(self, pose: BoardPose, index: int = 0) -> NDArray[np.uint8]:
        """The camera's grey frame of the board at ``pose``, with frame ``index``'s sensor
        noise (deterministic per seed and index)."""
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, np.ascontiguousarray(pose.rotation).ravel())
        self.data.mocap_pos[0] = pose.origin_cm / CM_PER_M
        self.data.mocap_quat[0] = quat
        mujoco.mj_forward(self.model, self.data)
        grey = grey_frame(self._renderer, self.data, self.CAMERA, self.rendered)
        if self.supersample > 1:
            size = (int(self.camera.cols), int(self.camera.rows))
            grey = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
        return sensor_noise(grey, self.noise_sigma, (self.seed, int(index), _STREAM_NOISE))

    def close(self) -> None:
        self._renderer.close()

    def __enter__(self) -> BoardScene:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
