"""The rmw_zenoh wire layout, written from its design document (``docs/design.md`` of
``ros2/rmw_zenoh``): the key expression a topic's messages are put on, the attachment
each message carries, the liveliness tokens that make a node and its publishers and
subscriptions part of a ROS 2 graph (``ros2 node list``, ``ros2 topic list``), and the
compact QoS text those tokens end with.

Only the layout is here (strings and bytes, no Zenoh); CDR payloads and type hashes come
from :mod:`ovis.common.ros2.convert` (rosbags). Parsers for each piece are here too, so
that a reader (a test, the ``ros2:`` frame source) checks what it receives against the
same rules.
"""

from __future__ import annotations

import re
import struct
from typing import Literal

import msgspec
import xxhash

__all__ = [
    "ADMIN_SPACE",
    "DEFAULT_QOS",
    "GID_SIZE",
    "Attachment",
    "EntityKind",
    "QoS",
    "Token",
    "TopicKey",
    "WireError",
    "dds_type_name",
    "decode_attachment",
    "demangle",
    "encode_attachment",
    "entity_gid",
    "entity_token",
    "mangle",
    "node_token",
    "parse_qos",
    "parse_token",
    "parse_topic_key",
    "qos_text",
    "qualified_name",
    "ros_type_name",
    "topic_key",
    "topic_key_pattern",
]

#: The hermetic prefix of every liveliness token (``*`` and ``**`` never match it).
ADMIN_SPACE = "@ros2_lv"
#: A publisher's GID: 16 bytes, the XXH3-128 hash of its liveliness token.
GID_SIZE = 16
#: NN node, MP message publisher, MS message subscription, SS service server, SC client.
EntityKind = Literal["NN", "MP", "MS", "SS", "SC"]
ENTITY_KINDS = ("NN", "MP", "MS", "SS", "SC")

# rmw's QoS enums (rmw/types.h): the numbers written in a token.
RELIABLE, BEST_EFFORT = 1, 2
TRANSIENT_LOCAL, VOLATILE = 1, 2
KEEP_LAST, KEEP_ALL = 1, 2

_NAME_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_TYPE_NAME = re.compile(r"([A-Za-z][A-Za-z0-9_]*)/(msg|srv)/([A-Za-z][A-Za-z0-9_]*)")
_DDS_TYPE = re.compile(r"([A-Za-z][A-Za-z0-9_]*)::(msg|srv)::dds_::([A-Za-z][A-Za-z0-9_]*)_")
_TYPE_HASH = re.compile(r"RIHS01_[0-9a-f]{64}")


class WireError(ValueError):
    """A name, key, token or attachment that does not follow the rmw_zenoh layout."""


class QoS(msgspec.Struct, frozen=True, kw_only=True):
    """The QoS policies a token states (deadline, lifespan and liveliness are left at
    their defaults: infinite, automatic)."""

    reliability: Literal[1, 2] = RELIABLE
    durability: Literal[1, 2] = VOLATILE
    history: Literal[1, 2] = KEEP_LAST
    depth: int = 42


#: rmw_zenoh's default QoS (``qos.cpp``): a field equal to it is left empty in a token.
DEFAULT_QOS = QoS()


def qos_text(qos: QoS) -> str:
    """The compact QoS of a token (rmw_zenoh's ``qos_to_keyexpr``):
    ``<reliability>:<durability>:<history>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:
    <liveliness>,<lease s>,<ns>``, each field empty when it is rmw_zenoh's default."""

    def field(value: int, default: int) -> str:
        return "" if value == default else str(value)

    d = DEFAULT_QOS
    return (
        f"{field(qos.reliability, d.reliability)}:{field(qos.durability, d.durability)}:"
        f"{field(qos.history, d.history)},{field(qos.depth, d.depth)}:,:,:,,"
    )


def parse_qos(text: str) -> QoS:
    """The QoS of a token's last chunk (:func:`qos_text`'s inverse); deadline, lifespan
    and liveliness must be the defaults (ovis states no other)."""
    parts = text.split(":")
    if len(parts) != 6 or parts[3:] != [",", ",", ",,"]:
        raise WireError(f"QoS {text!r}: expected 6 ':'-separated fields, the last three empty")
    history, _, depth = parts[2].partition(",")
    try:
        return QoS(
            reliability=int(parts[0] or RELIABLE),  # type: ignore[arg-type]
            durability=int(parts[1] or VOLATILE),  # type: ignore[arg-type]
            history=int(history or KEEP_LAST),  # type: ignore[arg-type]
            depth=int(depth or DEFAULT_QOS.depth),
        )
    except (ValueError, msgspec.ValidationError) as exc:
        raise WireError(f"QoS {text!r}: {exc}") from None


def mangle(name: str) -> str:
    """A name in a token: each ``/`` replaced by ``%``."""
    return name.replace("/", "%")


def demangle(name: str) -> str:
    return name.replace("%", "/")


def _check_name(name: str, what: str) -> None:
    """A fully qualified ROS name: ``/`` then tokens of letters, digits and ``_`` (not
    starting with a digit) separated by single ``/``."""
    tokens = name[1:].split("/")
    if not name.startswith("/") or not all(_NAME_TOKEN.fullmatch(t) for t in tokens):
        raise WireError(
            f"{what} {name!r} is not a ROS name: '/' then letters, digits and '_' "
            "(not starting with a digit), separated by single '/'"
        )


def qualified_name(namespace: str, topic: str) -> str:
    """The fully qualified name of ``topic`` in ``namespace`` (a topic starting with
    ``/`` is absolute, as ``/tf_static``)."""
    name = topic if topic.startswith("/") else f"{namespace.rstrip('/')}/{topic}"
    _check_name(name, "topic")
    return name


def _type_parts(pattern: re.Pattern[str], text: str, form: str) -> tuple[str, ...]:
    """(package, msg or srv, name) of a type name written as ``form``."""
    match = pattern.fullmatch(text)
    if match is None:
        raise WireError(f"type {text!r} is not {form}")
    return match.groups()


def dds_type_name(type_name: str) -> str:
    """``geometry_msgs/msg/PoseArray`` as declared in DDS:
    ``geometry_msgs::msg::dds_::PoseArray_``."""
    package, kind, name = _type_parts(_TYPE_NAME, type_name, "package/msg/Name")
    return f"{package}::{kind}::dds_::{name}_"


def ros_type_name(dds_name: str) -> str:
    """:func:`dds_type_name`'s inverse."""
    return "/".join(_type_parts(_DDS_TYPE, dds_name, "package::msg::dds_::Name_"))


def _check_hash(type_hash: str) -> None:
    if _TYPE_HASH.fullmatch(type_hash) is None:
        raise WireError(f"type hash {type_hash!r} is not RIHS01_ and 64 hex digits")


def topic_key(domain_id: int, name: str, type_name: str, type_hash: str) -> str:
    """The key a topic's messages are put on:
    ``<domain_id>/<fully qualified name without its leading />/<DDS type>/<type hash>``."""
    _check_name(name, "topic")
    _check_hash(type_hash)
    return f"{domain_id}/{name[1:]}/{dds_type_name(type_name)}/{type_hash}"


def topic_key_pattern(domain_id: int, name: str) -> str:
    """The key expression of topic ``name`` whatever its type and type hash."""
    _check_name(name, "topic")
    return f"{domain_id}/{name[1:]}/*/*"


class TopicKey(msgspec.Struct, frozen=True):
    """A topic's data key, read back."""

    domain_id: int
    name: str  # fully qualified
    type_name: str  # package/msg/Name
    type_hash: str


def parse_topic_key(key: str) -> TopicKey:
    """The parts of a data key (:func:`topic_key`'s inverse)."""
    parts = key.split("/")
    if len(parts) < 4 or not parts[0].isdigit():
        raise WireError(f"key {key!r} is not <domain>/<topic>/<type>/<hash>")
    name = "/" + "/".join(parts[1:-2])
    parsed = TopicKey(int(parts[0]), name, ros_type_name(parts[-2]), parts[-1])
    if topic_key(parsed.domain_id, name, parsed.type_name, parsed.type_hash) != key:
        raise WireError(f"key {key!r} does not follow <domain>/<topic>/<type>/<hash>")
    return parsed


def node_token(
    domain_id: int, zid: str, node_id: int, namespace: str, node: str, enclave: str = "/"
) -> str:
    """A node's liveliness token:
    ``@ros2_lv/<domain_id>/<session_id>/<node_id>/<node_id>/NN/<mangled enclave>/
    <mangled namespace>/<node name>``."""
    _check_node(namespace, node)
    return (
        f"{ADMIN_SPACE}/{domain_id}/{zid}/{node_id}/{node_id}/NN/{mangle(enclave)}/"
        f"{mangle(namespace)}/{node}"
    )


def entity_token(
    kind: EntityKind,
    domain_id: int,
    zid: str,
    node_id: int,
    entity_id: int,
    namespace: str,
    node: str,
    topic: str,
    type_name: str,
    type_hash: str,
    qos: QoS,
    enclave: str = "/",
) -> str:
    """A publisher's (``MP``) or subscription's (``MS``) liveliness token:
    ``@ros2_lv/<domain_id>/<session_id>/<node_id>/<entity_id>/<kind>/<mangled enclave>/
    <mangled namespace>/<node name>/<mangled qualified name>/<DDS type>/<type hash>/<qos>``."""
    if kind == "NN":
        raise WireError("a node's token is node_token()")
    _check_node(namespace, node)
    _check_name(topic, "topic")
    _check_hash(type_hash)
    return (
        f"{ADMIN_SPACE}/{domain_id}/{zid}/{node_id}/{entity_id}/{kind}/{mangle(enclave)}/"
        f"{mangle(namespace)}/{node}/{mangle(topic)}/{dds_type_name(type_name)}/"
        f"{type_hash}/{qos_text(qos)}"
    )


def _check_node(namespace: str, node: str) -> None:
    if namespace != "/":
        _check_name(namespace, "namespace")
    if _NAME_TOKEN.fullmatch(node) is None:
        raise WireError(f"node name {node!r}: letters, digits and '_', not starting with a digit")


class Token(msgspec.Struct, frozen=True, kw_only=True):
    """A liveliness token, read back (topic fields empty for a node)."""

    domain_id: int
    zid: str
    node_id: int
    entity_id: int
    kind: EntityKind
    enclave: str
    namespace: str
    node: str
    topic: str = ""
    type_name: str = ""
    type_hash: str = ""
    qos: QoS | None = None


def parse_token(key: str) -> Token:
    """The parts of a liveliness token; it must be exactly what :func:`node_token` or
    :func:`entity_token` would write for them."""
    parts = key.split("/")
    if len(parts) not in (9, 13) or parts[0] != ADMIN_SPACE or parts[5] not in ENTITY_KINDS:
        raise WireError(f"token {key!r}: not @ros2_lv/<domain>/<zid>/<nid>/<id>/<kind>/…")
    if not (parts[1].isdigit() and parts[3].isdigit() and parts[4].isdigit()):
        raise WireError(f"token {key!r}: domain, node and entity ids must be numbers")
    head = dict(
        domain_id=int(parts[1]),
        zid=parts[2],
        node_id=int(parts[3]),
        entity_id=int(parts[4]),
        kind=parts[5],
        enclave=demangle(parts[6]),
        namespace=demangle(parts[7]),
        node=parts[8],
    )
    if len(parts) == 9:
        token = Token(**head)  # type: ignore[arg-type]
        again = node_token(token.domain_id, token.zid, token.node_id, token.namespace,
                           token.node, token.enclave)  # fmt: skip
        if token.kind != "NN" or token.entity_id != token.node_id or again != key:
            raise WireError(f"token {key!r} is not a node's token")
        return token
    token = Token(
        **head,  # type: ignore[arg-type]
        topic=demangle(parts[9]),
        type_name=ros_type_name(parts[10]),
        type_hash=parts[11],
        qos=parse_qos(parts[12]),
    )
    assert token.qos is not None
    again = entity_token(token.kind, token.domain_id, token.zid, token.node_id,
                         token.entity_id, token.namespace, token.node, token.topic,
                         token.type_name, token.type_hash, token.qos, token.enclave)  # fmt: skip
    if again != key:
        raise WireError(f"token {key!r} does not follow the entity token layout")
    return token


def entity_gid(token: str) -> bytes:
    """An entity's GID as rmw_zenoh makes it: the XXH3-128 hash of its liveliness token,
    its low 64 bits then its high 64 bits, each little-endian."""
    return xxhash.xxh3_128_intdigest(token.encode()).to_bytes(GID_SIZE, "little")


class Attachment(msgspec.Struct, frozen=True):
    """What a message carries besides its payload."""

    sequence_number: int
    source_timestamp_ns: int  # since the Unix epoch
    gid: bytes


_ATTACHMENT = struct.Struct(f"<qqB{GID_SIZE}s")


def encode_attachment(sequence_number: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """8 bytes sequence number (int64 little-endian), 8 bytes source timestamp (ns since
    the Unix epoch, int64 little-endian), 1 byte the GID's length (16), the GID."""
    if len(gid) != GID_SIZE:
        raise WireError(f"a GID has {GID_SIZE} bytes, not {len(gid)}")
    return _ATTACHMENT.pack(sequence_number, source_timestamp_ns, GID_SIZE, gid)


def decode_attachment(data: bytes) -> Attachment:
    """:func:`encode_attachment`'s inverse."""
    if len(data) != _ATTACHMENT.size:
        raise WireError(f"an attachment has {_ATTACHMENT.size} bytes, not {len(data)}")
    seq, stamp, size, gid = _ATTACHMENT.unpack(data)
    if size != GID_SIZE:
        raise WireError(f"attachment GID length {size}, expected {GID_SIZE}")
    return Attachment(seq, stamp, gid)
