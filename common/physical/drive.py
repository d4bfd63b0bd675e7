"""Differential-drive robots in MuJoCo: a chassis on a free joint rolling on two driven
wheels and two casters, the wheels turned by velocity actuators.

A driven robot is the same solid box as a kinematic one (the same geom, albedo and
marker, in geom group 1, colliding with the other solids), on a **free joint**: it
stands on the floor by gravity, and moves only by its wheels' friction on the floor.
Under it, hidden from the cameras (geom group 3), are

* two **wheels** (cylinders of :data:`WHEEL_RADIUS_CM`) on hinges about the robot's
  lateral axis (+Y of the body: a positive wheel speed rolls it forwards), half the
  track (:data:`TRACK_CM`) either side of its centre, each driven by a MuJoCo
  ``velocity`` actuator (force ``kv·(ω_target − ω)``, bounded by :data:`WHEEL_TORQUE_NM`)
  whose target is the wheel's speed in rad/s;
* two **casters** (frictionless spheres, ``condim`` 1, their contact parameters
  preferred to the floor's) ahead of and behind the axle, just clear of the floor.

Wheels and casters touch the floor and nothing else; the floor touches only them
(contact bits :data:`WHEEL_BITS`). Which wheel speeds carry out a command (v, ω) and
within which limits is :mod:`ovis.common.navigation.base`'s business: here the wheels
only follow their targets.
"""

from __future__ import annotations

import math

import mujoco

from ovis.common.physical.scene import Solid

__all__ = [
    "HIDDEN_GROUP",
    "SOLID_BITS",
    "TRACK_CM",
    "WHEEL_BITS",
    "WHEEL_RADIUS_CM",
    "add_wheels",
    "free_joint_name",
    "wheel_actuator_names",
]

#: Contact bits: the solids touch each other; wheels and casters touch only the floor.
SOLID_BITS = 1
WHEEL_BITS = 2
#: Geom group of what is under a robot (never rendered: the cameras show groups 0, 1).
HIDDEN_GROUP = 3
WHEEL_RADIUS_CM = 2.0
WHEEL_WIDTH_CM = 1.0
#: Distance between the two wheels' contact lines (cm).
TRACK_CM = 8.0
CASTER_RADIUS_CM = 0.8
#: How far a caster stands above the floor when the robot is level: the wheels carry
#: the weight (and grip), a caster only stops the chassis from tipping.
CASTER_GAP_CM = 0.03
#: Velocity servo gain (N·m·s/rad) and torque bound (N·m) of a wheel's actuator.
WHEEL_KV = 0.05
WHEEL_TORQUE_NM = 0.2
WHEEL_MASS_KG = 0.05
#: Reflected inertia of a wheel's motor and gearbox (kg·m²).
WHEEL_ARMATURE = 1e-4
CHASSIS_MASS_KG = 0.6
#: Friction of a wheel on the floor (sliding; torsional and rolling unused: condim 3).
WHEEL_FRICTION = (1.5, 0.0, 0.0)
#: Time constant (s) of a wheel's contact: stiff, so that a rolling wheel hardly creeps
#: (MuJoCo's soft contacts let a loaded contact slide a little).
WHEEL_SOLREF_S = 0.004

_CM_PER_M = 100.0


def free_joint_name(solid: Solid) -> str:
    return f"s{solid.id}_free"


def wheel_actuator_names(solid: Solid) -> tuple[str, str]:
    """The left and right wheels' actuators."""
    return f"s{solid.id}_motor_l", f"s{solid.id}_motor_r"


def _m(cm: float) -> float:
    return cm / _CM_PER_M


def add_wheels(spec: mujoco.MjSpec, body: mujoco.MjsBody, solid: Solid) -> None:
    """Give a robot's body its free joint, wheels, casters and wheel actuators (module
    docstring). The body's own geoms (chassis, marker) are added by the caller. The
    model integrates implicitly in velocity (``implicitfast``): a wheel's servo is far
    stiffer than its inertia over one time step, which the explicit Euler step cannot
    follow."""
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    body.add_freejoint(name=free_joint_name(solid))
    # a cylinder's axis is its local Z: turned −90° about X it lies along +Y
    along_y = [math.cos(-math.pi / 4), math.sin(-math.pi / 4), 0.0, 0.0]
    hidden = {"group": HIDDEN_GROUP, "contype": WHEEL_BITS, "conaffinity": 0}
    for side, sign, actuator in zip(
        ("l", "r"), (1.0, -1.0), wheel_actuator_names(solid), strict=True
    ):
        wheel = body.add_body(
            name=f"s{solid.id}_wheel_{side}",
            pos=[0.0, _m(sign * TRACK_CM / 2.0), _m(WHEEL_RADIUS_CM)],
        )
        joint = f"s{solid.id}_wheel_{side}"
        wheel.add_joint(
            name=joint,
            type=mujoco.mjtJoint.mjJNT_HINGE,
            axis=[0.0, 1.0, 0.0],
            armature=WHEEL_ARMATURE,
        )
        wheel.add_geom(
            type=mujoco.mjtGeom.mjGEOM_CYLINDER,
            size=[_m(WHEEL_RADIUS_CM), _m(WHEEL_WIDTH_CM / 2.0), 0.0],
            quat=along_y,
            mass=WHEEL_MASS_KG,
            friction=list(WHEEL_FRICTION),
            condim=3,
            priority=1,
            solref=[WHEEL_SOLREF_S, 1.0],
            rgba=[0.1, 0.1, 0.1, 1.0],
            **hidden,
        )
        motor = spec.add_actuator(name=actuator, target=joint)
        motor.trntype = mujoco.mjtTrn.mjTRN_JOINT
        motor.set_to_velocity(kv=WHEEL_KV)
        motor.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        motor.forcerange = [-WHEEL_TORQUE_NM, WHEEL_TORQUE_NM]
    reach = max(solid.length_cm / 2.0 - CASTER_RADIUS_CM - 1.0, CASTER_RADIUS_CM)
    for sign in (1.0, -1.0):
        body.add_geom(
            type=mujoco.mjtGeom.mjGEOM_SPHERE,
            size=[_m(CASTER_RADIUS_CM), 0.0, 0.0],
            pos=[_m(sign * reach), 0.0, _m(CASTER_RADIUS_CM + CASTER_GAP_CM)],
            mass=0.005,
            condim=1,
            friction=[0.0, 0.0, 0.0],
            priority=1,
            rgba=[0.1, 0.1, 0.1, 1.0],
            **hidden,
        )
