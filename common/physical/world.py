"""The physical world running: a scene in MuJoCo, moved through time, rendered by each
camera, and its ground truth read from the physics state.

:class:`PhysicalWorld` sets every solid's joints to where its path is at time ``t`` (and
their velocities to the path's), runs MuJoCo's forward dynamics, and reads the truth back
from the physics state: each solid's footprint centre and yaw from its body's pose, its
velocity from its joints, its height from its geom. A frame is the camera's render of
that state in grey (anti-aliased, with the lamps' shadows when ``[physical] shadows``),
resampled through the lens (:mod:`ovis.common.physical.camera`), with Gaussian sensor
noise drawn from ``(seed, frame index, camera)``: a frame depends only on the seed, the
frame's time and index, and the camera.

**Driven robots** (``driven=True``): each robot is a differential-drive body
(:mod:`ovis.common.physical.drive`) that only its wheels move. :meth:`set_time` then
places the obstacles alone, and :meth:`advance` runs MuJoCo's dynamics forward: the
obstacles are put back on their paths every :data:`KINEMATIC_STEP_S` (their joints'
positions and velocities; in between they coast at their path's velocity), the robots
roll on their wheels' targets (:meth:`set_wheels`), and a robot touching another solid
is a MuJoCo contact (:meth:`touching`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import msgspec
import mujoco
import numpy as np
from numpy.typing import NDArray

from ovis.common.camera.projection import project
from ovis.common.config import CameraModel, OvisConfig
from ovis.common.physical.camera import CM_PER_M, RenderCamera, render_camera
from ovis.common.physical.drive import free_joint_name, wheel_actuator_names
from ovis.common.physical.model import (
    FLOOR_GROUP,
    SOLID_GROUP,
    build_spec,
    camera_name,
    is_driven,
    joint_names,
)
from ovis.common.physical.scene import Scene, Solid, footprint
from ovis.common.sim.arena import FrameTruth, SimObject

__all__ = ["PhysicalWorld", "SolidView", "grey_frame", "sensor_noise", "silhouette_px"]

_STREAM_NOISE = 5
#: Where :meth:`PhysicalWorld.alone_px` puts the solids it takes away (m along X).
_AWAY_M = 1000.0
#: How often (s of simulated time) :meth:`PhysicalWorld.advance` puts the obstacles back
#: on their paths.
KINEMATIC_STEP_S = 0.01
#: Points per footprint edge projected for a solid's silhouette (edges bend in a lens).
EDGE_SAMPLES = 8
_SHAPES = {"cylinder": "disk", "box": "rect", "prism": "prism"}


def grey_frame(
    renderer: mujoco.Renderer,
    data: mujoco.MjData,
    camera: str,
    rendered: RenderCamera,
    option: mujoco.MjvOption | None = None,
) -> NDArray[np.uint8]:
    """The grey frame MuJoCo's ``camera`` renders of ``data``, resampled through the lens
    (``rendered``: that camera's :func:`~ovis.common.physical.camera.render_camera`)."""
    if option is None:
        renderer.update_scene(data, camera=camera)
    else:
        renderer.update_scene(data, camera=camera, scene_option=option)
    grey = cv2.cvtColor(renderer.render(), cv2.COLOR_RGB2GRAY)
    return rendered.finish(grey)


def sensor_noise(grey: NDArray[np.uint8], sigma: float, key: Sequence[int]) -> NDArray[np.uint8]:
    """``grey`` with Gaussian sensor noise of ``sigma`` grey levels drawn from ``key`` (a
    seed sequence: the same key, the same noise), rounded and clipped to 0..255."""
    if sigma <= 0.0:
        return grey
    rng = np.random.default_rng(list(key))
    noisy = grey + rng.standard_normal(grey.shape, dtype=np.float32) * np.float32(sigma)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


class SolidView(msgspec.Struct, frozen=True, kw_only=True):
    """How much of one solid a camera sees: ``visible_px``, its pixels in front of
    everything else (0: hidden), and ``visible_share``, their share of the pixels it would
    cover alone in the frame."""

    id: int
    visible_px: int
    visible_share: float


def silhouette_px(
    solid: Solid, x_cm: float, y_cm: float, yaw_rad: float, camera: CameraModel
) -> float:
    """Pixels (area, px²) of ``camera``'s frame that ``solid`` at ``(x_cm, y_cm)`` turned
    by ``yaw_rad`` covers when alone: the convex hull of its footprint's outline projected
    at its foot and at its top (each edge sampled, as the lens bends it), clipped to the
    frame."""
    foot = footprint(solid, x_cm, y_cm, yaw_rad)
    t = np.linspace(0.0, 1.0, EDGE_SAMPLES, endpoint=False)
    ring = foot[:, None, :] + (np.roll(foot, -1, axis=0) - foot)[:, None, :] * t[None, :, None]
    ring = ring.reshape(-1, 2)
    xs = np.concatenate([ring[:, 0], ring[:, 0]])
    ys = np.concatenate([ring[:, 1], ring[:, 1]])
    zs = np.concatenate([np.zeros(len(ring)), np.full(len(ring), solid.height_cm)])
    p = project(xs, ys, zs, camera)
    if not np.all(p.valid):
        return 0.0
    hull = cv2.convexHull(np.stack([p.col, p.row], axis=1).astype(np.float32))
    w, h = float(camera.cols), float(camera.rows)
    frame = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    area, _ = cv2.intersectConvexConvex(hull, frame.astype(np.float32))
    return float(area)


def _wrap_deg(a: float) -> float:
    a = (a + 180.0) % 360.0 - 180.0
    return 180.0 if a == -180.0 else a


class PhysicalWorld:
    """A scene in MuJoCo seen by ``cameras`` (see the module's docstring).

    Raises ValueError for a camera that cannot be rendered (a distortion that is not
    one-to-one over its frame); ``mujoco.FatalError`` or a RuntimeError when no
    off-screen OpenGL context can be made (``MUJOCO_GL=egl``, see
    :func:`ovis.common.physical.availability.why_unavailable`).
    """

    def __init__(
        self,
        scene: Scene,
        config: OvisConfig,
        cameras: Sequence[CameraModel],
        *,
        noise_sigma: float | None = None,
        driven: bool = False,
    ) -> None:
        self.scene = scene
        self.cameras = list(cameras)
        self.rendered: list[RenderCamera] = [render_camera(c) for c in self.cameras]
        phys = config.physical
        self.noise_sigma = phys.noise_sigma if noise_sigma is None else float(noise_sigma)
        self.spec = build_spec(
            scene, config, self.cameras, self.rendered, phys.samples, driven=driven
        )
        self.model = self.spec.compile()
        self.data = mujoco.MjData(self.model)
        m = self.model
        #: the solids moved along their paths, and the differential-drive robots
        self.kinematic = [s for s in scene.solids if not is_driven(s, driven)]
        self.driven = [s for s in scene.solids if is_driven(s, driven)]
        self._qpos = [[m.joint(n).qposadr[0] for n in joint_names(s)] for s in self.kinematic]
        self._qvel = [[m.joint(n).dofadr[0] for n in joint_names(s)] for s in self.kinematic]
        self._free = {s.id: m.joint(free_joint_name(s)) for s in self.driven}
        self._motors = {
            s.id: [m.actuator(n).id for n in wheel_actuator_names(s)] for s in self.driven
        }
        self._body = [m.body(f"solid{s.id}").id for s in scene.solids]
        self._body_of = {s.id: b for s, b in zip(scene.solids, self._body, strict=True)}
        self._geom = {s.id: m.geom(f"solid{s.id}_geom").id for s in scene.solids}
        self._renderers: dict[tuple[int, int], mujoco.Renderer] = {}
        self._options: dict[bool, mujoco.MjvOption] = {}
        self.t_s = 0.0
        self.set_time(0.0)

    # ------------------------------------------------------------------ motion
    def _yaw(self, solid: Solid, t_s: float) -> tuple[float, float]:
        """Yaw (rad) and yaw rate (rad/s) of a solid at ``t_s``: an obstacle keeps its
        own, a moving robot faces along its path."""
        if solid.kind != "robot" or not solid.path.moving:
            return math.radians(solid.yaw_deg), 0.0
        period = self.scene.period_s
        dt = 1e-3 * period
        yaws = []
        for tau in (t_s - dt, t_s, t_s + dt):
            vx, vy = solid.path.velocity(tau, period)
            yaws.append(math.atan2(float(vy), float(vx)))
        rate = math.remainder(yaws[2] - yaws[0], 2.0 * math.pi) / (2.0 * dt)
        return yaws[1], rate

    def _place(self, t_s: float) -> None:
        """Every kinematic solid where its path is at ``t_s``, at its path's velocity."""
        period = self.scene.period_s
        qpos, qvel = self.data.qpos, self.data.qvel
        for solid, pa, va in zip(self.kinematic, self._qpos, self._qvel, strict=True):
            x, y = solid.path.at(t_s, period)
            vx, vy = solid.path.velocity(t_s, period)
            yaw, rate = self._yaw(solid, t_s)
            qpos[pa] = [float(x) / CM_PER_M, float(y) / CM_PER_M, yaw]
            qvel[va] = [float(vx) / CM_PER_M, float(vy) / CM_PER_M, rate]

    def set_time(self, t_s: float) -> None:
        """Move every solid (every obstacle when robots are driven) to where its path is
        at ``t_s`` (s) and update the physics state (joint positions and velocities, then
        MuJoCo's forward dynamics)."""
        self._place(t_s)
        mujoco.mj_forward(self.model, self.data)
        self.t_s = float(t_s)
        self.data.time = self.t_s

    def advance(self, seconds: float, *, settle: bool = True) -> None:
        """Run the dynamics ``seconds`` forward (whole physics steps): the driven robots
        on their wheels' targets, the obstacles put back on their paths every
        :data:`KINEMATIC_STEP_S`. Then (``settle``, else at :meth:`settle`) the
        obstacles are exactly on their paths at :attr:`t_s` and the state is MuJoCo's
        there; unsettled, the contacts are the last step's."""
        dt = float(self.model.opt.timestep)
        steps = round(seconds / dt)
        chunk = max(1, round(KINEMATIC_STEP_S / dt))
        done = 0
        while done < steps:
            n = min(chunk, steps - done)
            self._place(self.t_s + done * dt)
            mujoco.mj_step(self.model, self.data, nstep=n)
            done += n
        self.t_s += steps * dt
        if settle:
            self.settle()

    def settle(self) -> None:
        """The obstacles on their paths at :attr:`t_s`, MuJoCo's derived state updated."""
        self._place(self.t_s)
        mujoco.mj_forward(self.model, self.data)

    def position_cm(self, solid_id: int) -> tuple[float, float]:
        """Where a solid's body is (cm) in the current state."""
        x_m, y_m = self.data.xpos[self._body_of[solid_id]][:2]
        return float(x_m) * CM_PER_M, float(y_m) * CM_PER_M

    def set_wheels(self, robot_id: int, left_rad_s: float, right_rad_s: float) -> None:
        """The wheel speeds (rad/s, positive: forwards) a driven robot's actuators hold."""
        left, right = self._motors[robot_id]
        self.data.ctrl[left] = left_rad_s
        self.data.ctrl[right] = right_rad_s

    def yaw_rate_deg_s(self, robot_id: int) -> float:
        """A driven robot's turn rate (deg/s, counter-clockwise; its free joint's
        angular velocity about the vertical, the robot standing level)."""
        return math.degrees(float(self.data.qvel[self._free[robot_id].dofadr[0] + 5]))

    def touching(self) -> list[tuple[int, int]]:
        """Pairs (robot id, other solid's id) of the driven robots' contacts with other
        solids in the current state (MuJoCo's contacts; each pair once)."""
        robots = {self._geom[s.id]: s.id for s in self.driven}
        solids = {g: i for i, g in self._geom.items()}
        out: set[tuple[int, int]] = set()
        con = self.data.contact
        for g1, g2, dist in zip(con.geom1, con.geom2, con.dist, strict=True):
            if dist > 0.0:
                continue
            for a, b in ((g1, g2), (g2, g1)):
                if a in robots and b in solids:
                    out.add((robots[a], solids[b]))
        return sorted(out)

    def clearance_cm(self, robot_id: int, within_cm: float = 50.0) -> float:
        """The smallest distance (cm) from a driven robot's body to any other solid's
        (MuJoCo's signed geom distance: negative inside), ``within_cm`` when none is
        nearer."""
        mine = self._geom[robot_id]
        best = within_cm
        for other, geom in self._geom.items():
            if other == robot_id:
                continue
            d = mujoco.mj_geomDistance(
                self.model, self.data, mine, geom, within_cm / CM_PER_M, None
            )
            best = min(best, d * CM_PER_M)
        return best

    # ------------------------------------------------------------------ truth
    def truth(self, index: int, stamp_ns: int | None = None) -> FrameTruth:
        """Ground truth of the current state, read from the physics: every solid's
        footprint centre (cm), top height, yaw, equal-area radius and velocity (cm/s)."""
        objects = []
        velocity = {s.id: va[:2] for s, va in zip(self.kinematic, self._qvel, strict=True)}
        velocity |= {i: [j.dofadr[0], j.dofadr[0] + 1] for i, j in self._free.items()}
        for solid, body in zip(self.scene.solids, self._body, strict=True):
            x_m, y_m = self.data.xpos[body][:2]
            xmat = self.data.xmat[body].reshape(3, 3)
            yaw = math.degrees(math.atan2(xmat[1, 0], xmat[0, 0]))
            va = velocity[solid.id]  # a free joint's first three: world linear velocity
            vx, vy = self.data.qvel[va[0]] * CM_PER_M, self.data.qvel[va[1]] * CM_PER_M
            length, width = solid.length_cm, solid.width_cm
            if solid.shape != "box":
                length = width = 2.0 * solid.bound_cm
            objects.append(
                SimObject(
                    id=solid.id,
                    kind=solid.kind,
                    x_cm=float(x_m) * CM_PER_M,
                    y_cm=float(y_m) * CM_PER_M,
                    z_cm=solid.height_cm,
                    radius_cm=solid.radius_cm,
                    heading_deg=_wrap_deg(yaw) if solid.shape != "cylinder" else 0.0,
                    shape=_SHAPES[solid.shape],  # type: ignore[arg-type]
                    length_cm=length,
                    width_cm=width,
                    marker_id=solid.marker_id,
                    vx_cm_s=float(vx),
                    vy_cm_s=float(vy),
                    sides=solid.sides,
                )
            )
        objects.sort(key=lambda o: (o.kind != "robot", o.id))
        return FrameTruth(index=int(index), objects=objects, stamp_ns=stamp_ns)

    # ------------------------------------------------------------------ rendering
    def _renderer(self, k: int) -> mujoco.Renderer:
        w, h = self.rendered[k].canvas
        key = (w, h)
        if key not in self._renderers:
            self._renderers[key] = mujoco.Renderer(self.model, h, w)
        return self._renderers[key]

    def _option(self, solids: bool) -> mujoco.MjvOption:
        if solids not in self._options:
            opt = mujoco.MjvOption()
            opt.geomgroup[:] = 0
            opt.geomgroup[FLOOR_GROUP] = 1
            opt.geomgroup[SOLID_GROUP] = int(solids)
            self._options[solids] = opt
        return self._options[solids]

    def clean(self, k: int = 0, *, solids: bool = True) -> NDArray[np.uint8]:
        """Camera ``k``'s grey frame of the current state without sensor noise
        (``solids=False``: the empty floor with its marks, for background subtraction)."""
        return grey_frame(
            self._renderer(k), self.data, camera_name(k), self.rendered[k], self._option(solids)
        )

    def render(self, index: int, k: int = 0) -> NDArray[np.uint8]:
        """Camera ``k``'s grey frame of the current state, frame ``index``'s sensor noise
        added (deterministic per seed, index and camera)."""
        key = (self.scene.seed, int(index), k, _STREAM_NOISE)
        return sensor_noise(self.clean(k), self.noise_sigma, key)

    def visible_px(self, k: int = 0) -> dict[int, int]:
        """Pixels of camera ``k``'s frame where each solid (by id) is seen in front of
        everything else: 0 for a solid hidden behind others."""
        renderer = self._renderer(k)
        renderer.enable_segmentation_rendering()
        try:
            renderer.update_scene(self.data, camera=camera_name(k), scene_option=self._option(True))
            seg = renderer.render()
        finally:
            renderer.disable_segmentation_rendering()
        geom = np.where(seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM), seg[..., 0], -1)
        # ids are exact in float32; resampled through the lens, nearest, as the frame is
        geom = self.rendered[k].finish(geom.astype(np.float32), cv2.INTER_NEAREST)
        ids = geom.astype(np.int64).ravel()
        counts = np.bincount(ids[ids >= 0], minlength=self.model.ngeom)
        out: dict[int, int] = {}
        for solid, body in zip(self.scene.solids, self._body, strict=True):
            mine = np.flatnonzero(self.model.geom_bodyid == body)
            out[solid.id] = int(counts[mine].sum())
        return out

    def alone_px(self, k: int = 0) -> dict[int, int]:
        """Pixels of camera ``k``'s (canvas) image each solid (by id) covers when the
        others are taken away: with :meth:`visible_px`, how much of it others hide."""
        out: dict[int, int] = {}
        t_s = self.t_s
        try:
            for solid in self.scene.solids:
                self.set_time(t_s)
                for other, qa in zip(self.kinematic, self._qpos, strict=True):
                    if other is not solid:  # far beyond every camera's view
                        self.data.qpos[qa[0]] = _AWAY_M
                mujoco.mj_forward(self.model, self.data)
                out[solid.id] = self.visible_px(k)[solid.id]
        finally:
            self.set_time(t_s)
        return out

    def views(self, k: int = 0) -> list[SolidView]:
        """How much of each solid camera ``k`` sees now: its pixels in front of everything
        else (:meth:`visible_px`) and their share of its silhouette, the pixels it would
        cover alone in the frame (the convex hull of its outline's projection, top and
        foot)."""
        visible = self.visible_px(k)
        out = []
        for solid, body in zip(self.scene.solids, self._body, strict=True):
            x_m, y_m = self.data.xpos[body][:2]
            xmat = self.data.xmat[body].reshape(3, 3)
            yaw = math.atan2(xmat[1, 0], xmat[0, 0])
            where = (float(x_m) * CM_PER_M, float(y_m) * CM_PER_M, yaw)
            area = silhouette_px(solid, *where, self.cameras[k])
            seen = visible[solid.id]
            share = min(1.0, seen / area) if area > 0 else 0.0
            out.append(SolidView(id=solid.id, visible_px=seen, visible_share=round(share, 4)))
        return out

    def close(self) -> None:
        for r in self._renderers.values():
            r.close()
        self._renderers.clear()
