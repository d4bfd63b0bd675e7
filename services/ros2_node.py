"""ovis as a ROS 2 node on a Zenoh session, laid out as rmw_zenoh does it
(:mod:`ovis.common.ros2.wire`): the node's liveliness token, one publisher per topic and
type with its own token, GID and sequence numbers, each message put on the topic's key
with its attachment; and subscription tokens for what ovis reads from ROS 2. What must
reach late subscribers (transient local) is published through a Zenoh advanced
publisher with a cache, as rmw_zenoh does."""

from __future__ import annotations

import threading

import zenoh
import zenoh.ext

from ovis.common.config import Ros2Config
from ovis.common.ros2 import wire
from ovis.common.ros2.convert import RosMessage, type_hash

__all__ = ["RosNode", "RosPublisher"]


class RosPublisher:
    """One ROS 2 publisher: its key, liveliness token and GID, its sequence numbers."""

    def __init__(self, node: RosNode, name: str, type_name: str, qos: wire.QoS) -> None:
        cfg = node.cfg
        hash_ = type_hash(type_name)
        self.name = name
        self.key = wire.topic_key(cfg.domain_id, name, type_name, hash_)
        token = wire.entity_token("MP", cfg.domain_id, node.zid, node.node_id,
                                  node.next_id(), cfg.namespace, cfg.node, name, type_name,
                                  hash_, qos)  # fmt: skip
        self.gid = wire.entity_gid(token)
        self.sequence_number = 0
        if qos.durability == wire.TRANSIENT_LOCAL:
            self._pub = zenoh.ext.declare_advanced_publisher(
                node.session,
                self.key,
                cache=zenoh.ext.CacheConfig(qos.depth),
                publisher_detection=True,
            )
        else:
            self._pub = node.session.declare_publisher(
                self.key, congestion_control=zenoh.CongestionControl.DROP
            )
        self.token = token
        self._live = node.session.liveliness().declare_token(token)

    def publish(self, cdr: bytes, stamp_ns: int) -> None:
        """Put one CDR message; its attachment says its sequence number (from 1), its
        source time ``stamp_ns`` and this publisher's GID."""
        self.sequence_number += 1
        attachment = wire.encode_attachment(self.sequence_number, stamp_ns, self.gid)
        self._pub.put(cdr, attachment=attachment)

    def close(self) -> None:
        self._live.undeclare()
        self._pub.undeclare()


class RosNode:
    """A ROS 2 node (``[ros2] namespace``/``node``) on ``session``: its token at once,
    a publisher for each (topic, type) as its first message comes."""

    def __init__(self, session: zenoh.Session, cfg: Ros2Config, node_id: int = 0) -> None:
        self.session = session
        self.cfg = cfg
        self.zid = str(session.info.zid())
        self.node_id = node_id
        self._ids = node_id
        self._lock = threading.Lock()
        self._publishers: dict[tuple[str, str], RosPublisher] = {}
        self._tokens: list[zenoh.LivelinessToken] = []
        self.token = wire.node_token(cfg.domain_id, self.zid, node_id, cfg.namespace, cfg.node)
        self._tokens.append(session.liveliness().declare_token(self.token))

    def next_id(self) -> int:
        """A new entity id within this node."""
        self._ids += 1
        return self._ids

    def publisher(self, topic: str, type_name: str, qos: wire.QoS) -> RosPublisher:
        """The publisher of ``topic`` (relative to the namespace, or absolute) and type."""
        with self._lock:
            found = self._publishers.get((topic, type_name))
            if found is None:
                name = wire.qualified_name(self.cfg.namespace, topic)
                found = RosPublisher(self, name, type_name, qos)
                self._publishers[(topic, type_name)] = found
            return found

    def publish(self, message: RosMessage, qos: wire.QoS, topic: str | None = None) -> RosPublisher:
        """Publish one converted message on ``topic`` (default: its own); the publisher
        it went out on."""
        pub = self.publisher(topic or message.topic, message.type, qos)
        pub.publish(message.cdr, message.stamp_ns)
        return pub

    def subscription_token(self, name: str, type_name: str, qos: wire.QoS) -> str:
        """Declare that this node subscribes to ``name`` (fully qualified) of a type."""
        with self._lock:
            cfg = self.cfg
            token = wire.entity_token("MS", cfg.domain_id, self.zid, self.node_id,
                                      self.next_id(), cfg.namespace, cfg.node, name,
                                      type_name, type_hash(type_name), qos)  # fmt: skip
            self._tokens.append(self.session.liveliness().declare_token(token))
            return token

    def close(self) -> None:
        with self._lock:
            for pub in self._publishers.values():
                pub.close()
            for token in self._tokens:
                token.undeclare()
            self._publishers.clear()
            self._tokens.clear()
