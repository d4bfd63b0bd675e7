"""A :class:`~ovis.common.physical.scene.Scene` as a MuJoCo model (``mujoco.MjSpec``).

* **Floor**: a matte plane of the scene's albedo at Z = 0 with the floor marks, flat
  white discs, in geom group 0. Nothing collides with it: the solids slide on joints.
* **Light**: the ceiling lamps are spot lights pointing down that cast shadows; the
  headlight gives only the ambient share (light from everywhere: what a room's walls and
  ceiling send back), never light from the camera's direction.
* **Solids** (geom group 1, hidden for the empty floor): each a body on two slide
  joints (X, Y) and a hinge (yaw) carrying one geom: a cylinder, a box or a convex mesh
  prism, its base on the floor, matte, of the solid's albedo; they collide with each
  other. A marked robot carries a white plate with its marker's black cells on top,
  printed so that the camera sees it unmirrored. With ``driven``, each robot is a
  differential-drive body instead (:mod:`ovis.common.physical.drive`): on a free joint
  at its path's centre, turned by its ``yaw_deg``, rolling on wheels the floor touches.
* **Cameras**: one per calibrated camera (``cam0``, ``cam1`` …), placed and with the
  intrinsics of :func:`~ovis.common.physical.camera.render_camera`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import mujoco
import numpy as np

from ovis.common.config import CameraModel, OvisConfig
from ovis.common.physical.camera import CM_PER_M, RenderCamera
from ovis.common.physical.drive import CHASSIS_MASS_KG, WHEEL_BITS, add_wheels
from ovis.common.physical.scene import Scene, Solid, circumradius
from ovis.common.sim.painting import marker_hand
from ovis.common.vision.markers import marker_cells

__all__ = [
    "FLOOR_GROUP",
    "SOLID_GROUP",
    "add_camera",
    "build_spec",
    "camera_name",
    "is_driven",
    "joint_names",
]

FLOOR_GROUP = 0
SOLID_GROUP = 1
#: Sides of the polygon a cylinder is drawn as (its outline departs from the circle by
#: less than 1 − cos(π/n) of its radius).
CYLINDER_SIDES = 180
SHADOW_MAP_PX = 2048
MARK_SIDES = 48
#: Thickness of a floor mark and of a robot's marker plate and cells (cm).
PRINT_CM = 0.05
#: Spot cone half-angle (deg) and fall-off exponent of a ceiling lamp.
LAMP_CUTOFF_DEG = 80.0
LAMP_EXPONENT = 1.0
#: Mass (kg) of a solid (its joints are driven, so only collisions feel it).
SOLID_MASS_KG = 1.0


def camera_name(k: int) -> str:
    return f"cam{k}"


def add_camera(spec: mujoco.MjSpec, name: str, rendered: RenderCamera) -> None:
    """A MuJoCo camera called ``name`` placed and focused as ``rendered`` says
    (:func:`~ovis.common.physical.camera.render_camera`)."""
    cam = spec.worldbody.add_camera(name=name, pos=rendered.pos_m.tolist())
    cam.quat = rendered.quat.tolist()
    cam.resolution = list(rendered.canvas)
    cam.sensor_size = [rendered.canvas[0] * 1e-5, rendered.canvas[1] * 1e-5]
    cam.focal_pixel = list(rendered.focal_px)
    cam.principal_pixel = list(rendered.principal_px)


def joint_names(solid: Solid) -> tuple[str, str, str]:
    """The slide X, slide Y and yaw joints of a solid."""
    return f"s{solid.id}_x", f"s{solid.id}_y", f"s{solid.id}_yaw"


def _m(cm: float) -> float:
    return cm / CM_PER_M


def _grey(albedo: float) -> list[float]:
    return [albedo, albedo, albedo, 1.0]


def _add_marker(
    body: mujoco.MjsBody, solid: Solid, config: OvisConfig, hand: float, top_cm: float
) -> None:
    """The marker printed on a robot's top: a white plate with a one-cell margin, and a
    box per black cell (top edge towards +X of the body, the robot's heading)."""
    cells = marker_cells(config.pose.marker_dictionary, int(solid.marker_id or 0))
    k = cells.shape[0]
    side = solid.marker_side_cm
    cell = side / k
    plate = side + 2.0 * cell
    z = top_cm + PRINT_CM / 2.0
    body.add_geom(
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=[_m(plate / 2.0), _m(plate / 2.0), _m(PRINT_CM / 2.0)],
        pos=[0.0, 0.0, _m(z)],
        rgba=_grey(0.92),
        group=SOLID_GROUP,
        contype=0,
        conaffinity=0,
        mass=0.0,
    )
    half = side / 2.0
    for r in range(k):
        for c in range(k):
            if cells[r, c]:
                continue
            v = half - (r + 0.5) * cell  # along the heading (+X)
            u = -half + (c + 0.5) * cell  # along the marker's right: (0, −hand) in X, Y
            body.add_geom(
                type=mujoco.mjtGeom.mjGEOM_BOX,
                size=[_m(cell / 2.0), _m(cell / 2.0), _m(PRINT_CM / 2.0)],
                pos=[_m(v), _m(-hand * u), _m(z + PRINT_CM)],
                rgba=_grey(0.04),
                group=SOLID_GROUP,
                contype=0,
                conaffinity=0,
                mass=0.0,
            )


def _ring_prism(radius_cm: float, n: int, height_cm: float) -> list[float]:
    """Corners (m) of an upright prism on the floor whose ``n`` corners lie on a circle of
    ``radius_cm``, ``height_cm`` tall (MuJoCo draws its convex hull)."""
    a = 2.0 * math.pi * np.arange(n) / n
    r = _m(radius_cm)
    ring = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
    h = _m(height_cm)
    vert = np.concatenate(
        [np.column_stack([ring, np.zeros(n)]), np.column_stack([ring, np.full(n, h)])]
    )
    return vert.ravel().tolist()


def _prism_vertices(solid: Solid, n: int) -> list[float]:
    """A prism solid's corners (a cylinder's: on its circle, as a lathe would cut it)."""
    r = circumradius(solid.radius_cm, n) if solid.shape == "prism" else solid.radius_cm
    return _ring_prism(r, n, solid.height_cm)


def _disc_vertices(radius_cm: float) -> list[float]:
    """A floor mark: a disc of paper on the floor."""
    return _ring_prism(radius_cm, MARK_SIDES, PRINT_CM)


def is_driven(solid: Solid, driven: bool) -> bool:
    """Whether ``solid`` is a differential-drive body in a model built with ``driven``."""
    return driven and solid.kind == "robot"


def _add_solid(
    spec: mujoco.MjSpec, solid: Solid, config: OvisConfig, hand: float, driven: bool = False
) -> None:
    mass = SOLID_MASS_KG
    if is_driven(solid, driven):
        yaw = math.radians(solid.yaw_deg)
        body = spec.worldbody.add_body(
            name=f"solid{solid.id}",
            pos=[_m(solid.path.cx_cm), _m(solid.path.cy_cm), 0.0],
            quat=[math.cos(yaw / 2.0), 0.0, 0.0, math.sin(yaw / 2.0)],
        )
        add_wheels(spec, body, solid)
        mass = CHASSIS_MASS_KG
    else:
        body = spec.worldbody.add_body(name=f"solid{solid.id}", pos=[0.0, 0.0, 0.0])
        jx, jy, jyaw = joint_names(solid)
        body.add_joint(name=jx, type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1.0, 0.0, 0.0])
        body.add_joint(name=jy, type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0.0, 1.0, 0.0])
        body.add_joint(name=jyaw, type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0.0, 0.0, 1.0])
    h = _m(solid.height_cm)
    common = {
        "rgba": _grey(solid.albedo),
        "group": SOLID_GROUP,
        "mass": mass,
        "name": f"solid{solid.id}_geom",
    }
    if solid.shape == "box":
        body.add_geom(
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[_m(solid.length_cm / 2.0), _m(solid.width_cm / 2.0), h / 2.0],
            pos=[0.0, 0.0, h / 2.0],
            **common,
        )
    else:  # a cylinder as a many-sided prism: flat top, sharp rim, smoothly shaded side
        n = solid.sides if solid.shape == "prism" else CYLINDER_SIDES
        spec.add_mesh(name=f"solid{solid.id}_mesh", uservert=_prism_vertices(solid, n))
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=f"solid{solid.id}_mesh", **common)
    if solid.marker_id is not None:
        _add_marker(body, solid, config, hand, solid.height_cm)


def build_spec(
    scene: Scene,
    config: OvisConfig,
    cameras: Sequence[CameraModel],
    rendered: Sequence[RenderCamera],
    samples: int,
    *,
    driven: bool = False,
) -> mujoco.MjSpec:
    """The MuJoCo model of a scene seen by ``cameras`` (module docstring); ``driven``:
    its robots on wheels."""
    spec = mujoco.MjSpec()
    spec.modelname = f"ovis_physical_{scene.seed}"
    spec.option.timestep = 0.002
    vis = spec.visual
    vis.global_.offwidth = max(r.canvas[0] for r in rendered)
    vis.global_.offheight = max(r.canvas[1] for r in rendered)
    vis.quality.offsamples = int(samples)
    vis.quality.shadowsize = SHADOW_MAP_PX
    vis.quality.numquads = 1
    vis.headlight.active = 1
    vis.headlight.ambient = [scene.ambient] * 3
    vis.headlight.diffuse = [0.0, 0.0, 0.0]
    vis.headlight.specular = [0.0, 0.0, 0.0]
    vis.map.znear = 0.001
    vis.map.zfar = 50.0
    spec.worldbody.add_geom(
        name="floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[20.0, 20.0, 0.1],
        rgba=_grey(scene.floor_albedo),
        group=FLOOR_GROUP,
        contype=0,
        conaffinity=WHEEL_BITS,  # only wheels stand on it: the solids slide on joints
    )
    for mark in scene.marks:
        spec.add_mesh(name=f"mark_{mark.name}", uservert=_disc_vertices(mark.radius_cm))
        spec.worldbody.add_geom(
            name=f"mark_{mark.name}",
            type=mujoco.mjtGeom.mjGEOM_MESH,
            meshname=f"mark_{mark.name}",
            pos=[_m(mark.x_cm), _m(mark.y_cm), 0.0],
            rgba=_grey(0.9),
            group=FLOOR_GROUP,
            contype=0,
            conaffinity=0,
        )
    direct = (1.0 - scene.ambient) / max(len(scene.lamps), 1)
    for k, lamp in enumerate(scene.lamps):
        spec.worldbody.add_light(
            name=f"lamp{k}",
            type=mujoco.mjtLightType.mjLIGHT_SPOT,
            pos=[_m(lamp.x_cm), _m(lamp.y_cm), _m(lamp.z_cm)],
            dir=[0.0, 0.0, -1.0],
            diffuse=[direct] * 3,
            specular=[0.0] * 3,
            ambient=[0.0] * 3,
            castshadow=scene.shadows,
            cutoff=LAMP_CUTOFF_DEG,
            exponent=LAMP_EXPONENT,
        )
    (x0, x1), (y0, y1) = scene.arena_x_cm, scene.arena_y_cm
    mid = (0.5 * (x0 + x1), 0.5 * (y0 + y1))
    for solid in scene.solids:
        hand = 1.0
        if solid.marker_id is not None:
            hand = marker_hand(cameras[0], mid[0], mid[1], solid.height_cm)
        _add_solid(spec, solid, config, hand, driven)
    for k, r in enumerate(rendered):
        add_camera(spec, camera_name(k), r)
    return spec
