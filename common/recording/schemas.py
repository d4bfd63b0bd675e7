"""JSON Schemas of the channels of a recording.

Every bus topic is recorded as its msgpack payloads with the JSON Schema of the message
that travels on it (``msgspec.json.schema`` of the Struct), so that any tool reading the
file can decode them. Schemas are written self-contained (``$ref`` resolved in place):
Foxglove reads a channel's schema as one document.
"""

from __future__ import annotations

from typing import Any

import msgspec

from ovis.common.messages import (
    BinaryFrame,
    BlobList,
    CalibrationUpdate,
    Frame,
    Message,
    ObstacleFrame,
    RobotCommand,
    RobotDrive,
    StreamHealth,
    TruthFrame,
)

__all__ = ["BUS_TYPES", "bus_type", "json_schema", "schema_bytes"]

#: The message that travels on each topic of an arena (the key's last chunk).
BUS_TYPES: dict[str, Any] = {
    "frames": Frame,
    "binary": BinaryFrame,
    "blobs": BlobList,
    "obstacles": ObstacleFrame,
    "truth": TruthFrame,
    "health": StreamHealth,
    "calibration": CalibrationUpdate,
    "cmd": RobotCommand,
    "drive": RobotDrive,
}


def bus_type(key: str) -> tuple[str, Any]:
    """The schema name and message type of a bus key such as ``ovis/default/frames``;
    a topic ovis does not know gets the union of all messages."""
    tp = BUS_TYPES.get(key.rsplit("/", 1)[-1])
    if tp is None:
        return "ovis.Message", Message
    return f"ovis.{tp.__name__}", tp


def _inline(node: Any, defs: dict[str, Any]) -> Any:
    if isinstance(node, dict):
        ref = node.get("$ref")
        if isinstance(ref, str) and ref.startswith("#/$defs/"):
            rest = {k: v for k, v in node.items() if k != "$ref"}
            return {**_inline(defs[ref.removeprefix("#/$defs/")], defs), **rest}
        return {k: _inline(v, defs) for k, v in node.items()}
    if isinstance(node, list):
        return [_inline(v, defs) for v in node]
    return node


def json_schema(tp: Any, title: str) -> dict[str, Any]:
    """The JSON Schema of ``tp`` with every ``$ref`` resolved in place and ``title`` set
    (ovis messages and the Foxglove views have no recursive types)."""
    (top,), defs = msgspec.json.schema_components([tp], ref_template="#/$defs/{name}")
    schema = _inline(top, defs)
    schema.pop("title", None)
    return {"title": title, **schema}


def schema_bytes(tp: Any, title: str) -> bytes:
    """:func:`json_schema` as UTF-8 JSON, what an MCAP schema record holds."""
    return msgspec.json.encode(json_schema(tp, title))
