"""What Foxglove shows of a recording: the camera as ``foxglove.CompressedImage`` and
the arena as ``foxglove.SceneUpdate``, JSON-encoded with Foxglove's JSON Schemas.

The Structs mirror the fields of Foxglove's message definitions (foxglove/schemas);
their JSON Schemas are generated from them (:func:`foxglove_schema`). Lengths are in
metres (ovis works in cm), times are ``{sec, nsec}``, bytes are base64 (as Foxglove's
JSON encoding expects).
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

import cv2
import msgspec

from ovis.common.messages import Frame, ObstacleFrame
from ovis.common.recording.schemas import schema_bytes
from ovis.common.world.detection import DetectedObject

__all__ = [
    "FOXGLOVE_TYPES",
    "CompressedImage",
    "SceneUpdate",
    "compressed_image",
    "foxglove_schema",
    "scene_update",
]

#: JPEG quality of the camera view (the lossless frames are on the bus channel).
JPEG_QUALITY = 90
#: Reference frame of the arena entities (world coordinates, z up).
ARENA_FRAME = "arena"
CM = 0.01  # metres per cm

Empty = Annotated[list[Any], msgspec.Meta(max_length=0)]


class Time(msgspec.Struct):
    """A point in time, ``sec`` + ``nsec`` since the Unix epoch."""

    sec: Annotated[int, msgspec.Meta(ge=0)]
    nsec: Annotated[int, msgspec.Meta(ge=0, le=999_999_999)]

    @classmethod
    def of_ns(cls, ns: int) -> Time:
        return cls(*divmod(int(ns), 1_000_000_000))


class Duration(msgspec.Struct):
    sec: int
    nsec: Annotated[int, msgspec.Meta(ge=0, le=999_999_999)]


class Vector3(msgspec.Struct):
    x: float
    y: float
    z: float


class Quaternion(msgspec.Struct):
    x: float
    y: float
    z: float
    w: float


class Pose(msgspec.Struct):
    position: Vector3
    orientation: Quaternion


class Color(msgspec.Struct):
    """RGBA, each between 0 and 1."""

    r: float
    g: float
    b: float
    a: float


class CubePrimitive(msgspec.Struct):
    pose: Pose
    size: Vector3
    color: Color


class CylinderPrimitive(msgspec.Struct):
    pose: Pose
    size: Vector3
    bottom_scale: float
    top_scale: float
    color: Color


class TextPrimitive(msgspec.Struct):
    pose: Pose
    billboard: bool
    font_size: float
    scale_invariant: bool
    color: Color
    text: str


class KeyValuePair(msgspec.Struct):
    key: str
    value: str


class SceneEntity(msgspec.Struct, kw_only=True):
    """One object of the scene; an entity replaces the earlier one of the same ``id``."""

    timestamp: Time
    frame_id: str
    id: str
    lifetime: Duration
    frame_locked: bool = False
    metadata: list[KeyValuePair] = []
    arrows: Empty = []
    cubes: list[CubePrimitive] = []
    spheres: Empty = []
    cylinders: list[CylinderPrimitive] = []
    lines: Empty = []
    triangles: Empty = []
    texts: list[TextPrimitive] = []
    models: Empty = []


class SceneEntityDeletion(msgspec.Struct):
    """``type`` 0 deletes the entity ``id``, 1 every entity of the topic."""

    timestamp: Time
    type: Literal[0, 1]
    id: str


class SceneUpdate(msgspec.Struct):
    """An update to the entities of a 3D scene."""

    deletions: list[SceneEntityDeletion]
    entities: list[SceneEntity]


class CompressedImage(msgspec.Struct):
    """A compressed image (``format`` "jpeg" or "png")."""

    timestamp: Time
    frame_id: str
    data: bytes
    format: str


#: Foxglove schema name of each view.
FOXGLOVE_TYPES: dict[str, Any] = {
    "foxglove.CompressedImage": CompressedImage,
    "foxglove.SceneUpdate": SceneUpdate,
}


def foxglove_schema(name: str) -> bytes:
    """The JSON Schema of a Foxglove view, e.g. ``foxglove.SceneUpdate``."""
    return schema_bytes(FOXGLOVE_TYPES[name], name)


def compressed_image(frame: Frame) -> CompressedImage:
    """The frame as a JPEG ``foxglove.CompressedImage`` (grey or BGR, as OpenCV writes
    them) stamped with its capture time."""
    ok, jpeg = cv2.imencode(".jpg", frame.image(), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise ValueError(f"frame {frame.seq}: OpenCV could not encode it as JPEG")
    return CompressedImage(Time.of_ns(frame.stamp_ns), "camera", jpeg.tobytes(), "jpeg")


_ROBOT = Color(0.2, 0.6, 1.0, 0.9)
_OBSTACLE = Color(1.0, 0.45, 0.1, 0.9)
_LABEL = Color(1.0, 1.0, 1.0, 1.0)
_FLAT = Quaternion(0.0, 0.0, 0.0, 1.0)


def _heading(deg: float | None) -> Quaternion:
    """Rotation about +z by ``deg`` (counter-clockwise from +X)."""
    half = math.radians(deg or 0.0) / 2.0
    return Quaternion(0.0, 0.0, math.sin(half), math.cos(half))


def _entity(obj: DetectedObject, stamp: Time) -> SceneEntity:
    """A robot (a box along its heading) or an obstacle (a cylinder), standing on the
    floor up to its top plane, with its id written above it."""
    height = max(obj.z_cm, 0.1) * CM
    centre = Vector3(obj.x_cm * CM, obj.y_cm * CM, height / 2.0)
    label = TextPrimitive(
        Pose(Vector3(centre.x, centre.y, height + 0.03), _FLAT),
        True,
        14.0,
        True,
        _LABEL,
        "robot" if obj.kind == "robot" else f"obstacle {obj.id}",
    )
    entity = SceneEntity(
        timestamp=stamp,
        frame_id=ARENA_FRAME,
        id=f"{obj.kind}-{obj.id}",
        lifetime=Duration(0, 0),
        texts=[label],
        metadata=[KeyValuePair("radius_cm", f"{obj.radius_cm:.2f}")],
    )
    if obj.kind == "robot":
        e = max(obj.elongation, 1.0)
        length, width = math.sqrt(obj.area_cm2 * e) * CM, math.sqrt(obj.area_cm2 / e) * CM
        pose = Pose(centre, _heading(obj.heading_deg))
        entity.cubes = [CubePrimitive(pose, Vector3(length, width, height), _ROBOT)]
    else:
        d = 2.0 * obj.radius_cm * CM
        pose = Pose(centre, _FLAT)
        entity.cylinders = [CylinderPrimitive(pose, Vector3(d, d, height), 1.0, 1.0, _OBSTACLE)]
    return entity


def scene_update(msg: ObstacleFrame) -> SceneUpdate:
    """The arena of one obstacle message: every earlier entity deleted, then the robot
    and the obstacles as they are now."""
    stamp = Time.of_ns(msg.stamp_ns)
    objects = ([msg.robot] if msg.robot is not None else []) + list(msg.obstacles)
    return SceneUpdate(
        deletions=[SceneEntityDeletion(stamp, 1, "")],
        entities=[_entity(o, stamp) for o in objects],
    )
