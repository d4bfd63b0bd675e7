"""An arena larger than one view, seen by a grid of cameras with overlapping views.

:func:`camera_grid` lays ``nx × ny`` pinhole cameras over the floor, each above its
cell with its own pose (position, height, yaw, tilt jitter) and lens (focal length and
radial distortion), every view covering its cell plus ``overlap_cm`` on each inner side,
all calibrated to the one shared floor frame. :class:`GridScene` is the ground truth on
that floor: marked robots driving round ellipses that cross every camera's cell (so
they are handed over from view to view) and still obstacles. :func:`measure` is what one
camera measures of it: each object whose footprint lies inside its image, its centre
projected to a pixel, disturbed by pixel noise and back-projected.
"""

from __future__ import annotations

import math

import cv2
import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.camera.projection import back_project, disks_in_image, project
from ovis.common.config import CameraModel, CameraSpec, PinholeParams
from ovis.common.sim.arena import SimObject

__all__ = ["GridScene", "camera_grid", "grid_arena", "measure", "whole_in_view"]

FloatArray = NDArray[np.float64]

#: an object is measured when its footprint is this far (pixels) inside the image
WHOLE_MARGIN_PX = 1.0


def grid_arena(
    nx: int, ny: int, cell_cm: tuple[float, float]
) -> tuple[tuple[float, float], tuple[float, float]]:
    """The floor ``(x range, y range)`` of an ``nx × ny`` grid of ``cell_cm`` cells."""
    return (0.0, nx * cell_cm[0]), (0.0, ny * cell_cm[1])


def _down_rotation(yaw_deg: float, tilt_x_deg: float, tilt_y_deg: float) -> FloatArray:
    """World → camera rotation of a camera looking down (optical axis −Z), its image
    columns along +X turned by ``yaw``, tilted by small angles about X and Y."""
    down = np.diag([1.0, -1.0, -1.0])
    yaw, tx, ty = (
        cv2.Rodrigues(np.array(v, float))[0]
        for v in (
            [0.0, 0.0, math.radians(yaw_deg)],
            [math.radians(tilt_x_deg), 0.0, 0.0],
            [0.0, math.radians(tilt_y_deg), 0.0],
        )
    )
    return tx @ ty @ down @ yaw.T


def camera_grid(
    nx: int,
    ny: int,
    *,
    cell_cm: tuple[float, float] = (100.0, 75.0),
    overlap_cm: float = 15.0,
    height_cm: float = 150.0,
    rows: int = 480,
    cols: int = 640,
    seed: int = 0,
) -> list[CameraSpec]:
    """``nx × ny`` simulated cameras named ``cam<i><j>`` (column i, row j), each seeing
    its cell plus ``overlap_cm`` beyond each inner edge; poses and lenses differ by seed.

    Raises ``ValueError`` when a drawn camera cannot cover its cell in its image."""
    if nx < 1 or ny < 1:
        raise ValueError(f"a camera grid needs at least 1 × 1 cameras, got {nx} × {ny}")
    rng = np.random.default_rng([seed, 19])
    w, h = cell_cm
    specs = []
    for j in range(ny):
        for i in range(nx):
            x0, x1 = (
                i * w - (overlap_cm if i > 0 else 0.0),
                (i + 1) * w + (overlap_cm if i < nx - 1 else 0.0),
            )
            y0, y1 = (
                j * h - (overlap_cm if j > 0 else 0.0),
                (j + 1) * h + (overlap_cm if j < ny - 1 else 0.0),
            )
            centre = np.array(
                [(x0 + x1) / 2 + rng.uniform(-3, 3), (y0 + y1) / 2 + rng.uniform(-3, 3)]
            )
            z = height_cm * rng.uniform(0.93, 1.07)
            R = _down_rotation(rng.uniform(-5, 5), rng.uniform(-3, 3), rng.uniform(-3, 3))
            k1 = float(rng.uniform(-0.08, 0.04))
            C = np.array([centre[0], centre[1], z])
            # the focal length that fits the cell's corners (plus margin) in the image
            corners = np.array([[x0, y0, 0], [x1, y0, 0], [x0, y1, 0], [x1, y1, 0]], float)
            cam_pts = (R @ (corners - C).T).T
            u = np.abs(cam_pts[:, 0] / cam_pts[:, 2]).max()
            v = np.abs(cam_pts[:, 1] / cam_pts[:, 2]).max()
            f = 0.85 * min((cols / 2) / u, (rows / 2) / v)
            rvec = cv2.Rodrigues(R)[0].ravel()
            cam = PinholeParams(
                rows=rows,
                cols=cols,
                fx=float(f),
                fy=float(f * rng.uniform(0.995, 1.005)),
                cx=float(cols / 2 - 0.5 + rng.uniform(-4, 4)),
                cy=float(rows / 2 - 0.5 + rng.uniform(-4, 4)),
                k1=k1,
                rvec=tuple(float(r) for r in rvec),
                tvec_cm=tuple(float(t) for t in -R @ C),
            )
            p = project(corners[:, 0], corners[:, 1], np.full(4, 7.0), cam)
            inside = (
                p.valid & (p.row >= 0) & (p.row <= rows - 1) & (p.col >= 0) & (p.col <= cols - 1)
            )
            if not inside.all():
                raise ValueError(f"camera cam{i}{j} does not cover its cell; lower the overlap")
            specs.append(CameraSpec(name=f"cam{i}{j}", source="sim", camera=cam))
    return specs


class GridScene:
    """Ground truth of the grid arena: ``robots`` marked robots (ids 1…N, markers
    0…N−1) on ellipses round the arena's centre at ``speed_cm_s``, and ``obstacles``
    still disks at least ``gap_cm`` apart, off the robots' paths.

    With ``period_frames`` = P, the robots all drive one way round, the same whole
    number of laps per P frames (at least one), evenly spaced in phase: frame ``f + P``
    equals frame ``f`` exactly (a prerendered period loops without a jump in the truth
    or the identities) and no two robots ever touch (as drawn, they would merge)."""

    def __init__(
        self,
        arena_x_cm: tuple[float, float],
        arena_y_cm: tuple[float, float],
        *,
        robots: int,
        obstacles: int,
        seed: int,
        fps: float = 30.0,
        speed_cm_s: float = 30.0,
        robot_height_cm: float = 5.0,
        obstacle_height_cm: float = 7.0,
        obstacle_radius_cm: tuple[float, float] = (4.0, 6.0),
        gap_cm: float = 15.0,
        period_frames: int | None = None,
    ) -> None:
        if period_frames is not None and period_frames < 1:
            raise ValueError(f"period_frames must be at least 1, got {period_frames}")
        rng = np.random.default_rng([seed, 1919])
        self.period = period_frames
        self.fps, self.robot_z, self.obstacle_z = fps, robot_height_cm, obstacle_height_cm
        cx, cy = np.mean(arena_x_cm), np.mean(arena_y_cm)
        half_w, half_h = (arena_x_cm[1] - arena_x_cm[0]) / 2, (arena_y_cm[1] - arena_y_cm[0]) / 2
        k = np.arange(robots)
        scale = 0.35 + 0.45 * (k + 0.5) / max(robots, 1)  # nested ellipses
        self._ax, self._ay = scale * half_w, scale * half_h
        self._centre = (cx, cy)
        self._phase0 = rng.uniform(0, 2 * math.pi, robots)
        mean_radius = (self._ax + self._ay) / 2
        self._omega = speed_cm_s / mean_radius * np.where(k % 2 == 0, 1.0, -1.0)
        if period_frames is not None and robots:
            # whole laps per period, so the scene repeats exactly; one way round at one
            # angular speed, evenly spaced in phase, so that robots never meet (rendered,
            # touching robots would merge into one blob)
            turn = 2 * math.pi * fps / period_frames  # one lap per period, rad/s
            laps = max(round(float(np.abs(self._omega).mean()) / turn), 1)
            self._omega = np.full(robots, laps * turn)
            self._phase0 = self._phase0[0] + 2 * math.pi * k / robots
        placed: list[tuple[float, float, float]] = []
        path_t = np.linspace(0, 2 * math.pi, 200)
        path = (
            np.concatenate(
                [
                    np.stack([cx + a * np.cos(path_t), cy + b * np.sin(path_t)], 1)
                    for a, b in zip(self._ax, self._ay, strict=True)
                ]
            )
            if robots
            else np.zeros((0, 2))
        )
        tries = 0
        while len(placed) < obstacles:
            tries += 1
            if tries > 100000:
                raise ValueError(f"cannot place {obstacles} obstacles {gap_cm} cm apart here")
            r = rng.uniform(*obstacle_radius_cm)
            x = rng.uniform(arena_x_cm[0] + 2 * r, arena_x_cm[1] - 2 * r)
            y = rng.uniform(arena_y_cm[0] + 2 * r, arena_y_cm[1] - 2 * r)
            if path.size and np.hypot(path[:, 0] - x, path[:, 1] - y).min() < gap_cm + r:
                continue
            if any(math.hypot(x - px, y - py) < gap_cm + r + pr for px, py, pr in placed):
                continue
            placed.append((x, y, r))
        self._obstacles = [
            SimObject(
                id=1000 + n,
                kind="obstacle",
                x_cm=x,
                y_cm=y,
                z_cm=obstacle_height_cm,
                radius_cm=r,
                heading_deg=0.0,
                shape="disk",
                length_cm=2 * r,
                width_cm=2 * r,
            )
            for n, (x, y, r) in enumerate(placed)
        ]

    def objects(self, frame: int) -> list[SimObject]:
        """Every object at ``frame`` (robots first, by id)."""
        t = frame / self.fps
        a = self._phase0 + self._omega * t
        x = self._centre[0] + self._ax * np.cos(a)
        y = self._centre[1] + self._ay * np.sin(a)
        vx = -self._ax * np.sin(a) * self._omega
        vy = self._ay * np.cos(a) * self._omega
        robots = [
            SimObject(
                id=k + 1,
                kind="robot",
                x_cm=float(x[k]),
                y_cm=float(y[k]),
                z_cm=self.robot_z,
                radius_cm=9.0,
                heading_deg=math.degrees(math.atan2(vy[k], vx[k])),
                shape="rect",
                length_cm=14.0,
                width_cm=10.0,
                marker_id=k,
                vx_cm_s=float(vx[k]),
                vy_cm_s=float(vy[k]),
            )
            for k in range(len(a))
        ]
        return robots + self._obstacles


def whole_in_view(cam: CameraModel, objects: list[SimObject]) -> NDArray[np.bool_]:
    """Per object: its whole footprint (the disk round its longest half-extent) projects
    inside ``cam``'s image, :data:`WHOLE_MARGIN_PX` from the border."""
    if not objects:
        return np.zeros(0, bool)
    x = np.array([o.x_cm for o in objects])
    y = np.array([o.y_cm for o in objects])
    z = np.array([o.z_cm for o in objects])
    r = np.array([max(o.radius_cm, o.length_cm / 2) for o in objects])
    return disks_in_image(x, y, z, r, cam, margin_px=WHOLE_MARGIN_PX)


def measure(
    cam: PinholeParams, objects: list[SimObject], pixel_sigma_px: float, rng: np.random.Generator
) -> list[SimObject]:
    """What ``cam`` measures of ``objects``: those whose whole footprint is inside its
    image, their centres projected, disturbed by Gaussian pixel noise of
    ``pixel_sigma_px`` and back-projected onto their top faces (ids kept, for scoring)."""
    if not objects:
        return []
    x = np.array([o.x_cm for o in objects])
    y = np.array([o.y_cm for o in objects])
    z = np.array([o.z_cm for o in objects])
    inside = whole_in_view(cam, objects)
    p = project(x, y, z, cam)
    row = p.row + rng.normal(0, pixel_sigma_px, len(x))
    col = p.col + rng.normal(0, pixel_sigma_px, len(x))
    b = back_project(row, col, cam, z)
    keep = inside & p.valid & b.valid
    return [
        msgspec.structs.replace(o, x_cm=float(b.x_cm[k]), y_cm=float(b.y_cm[k]))
        for k, o in enumerate(objects)
        if keep[k]
    ]
