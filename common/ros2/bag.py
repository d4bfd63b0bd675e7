"""A rosbag2 bag of ovis's ROS 2 messages, what ``ros2 bag play`` and rosbags read.

A session file (MCAP with ovis's msgpack channels and JSON Schemas) is not a rosbag2
bag: ``ros2 bag`` and rosbags' rosbag2 reader want a directory with a
``metadata.yaml`` and its storage file, and channels of ``cdr`` messages only. So
``ovis record --ros2`` writes one beside the session, with rosbags' own rosbag2 writer
(format version 9, MCAP storage): ``S.mcap`` → ``S.ros2/`` holding ``metadata.yaml``
and ``S.ros2.mcap``. Each topic's connection carries its type's ``ros2msg`` definition
and ``RIHS01`` hash, and the QoS a player offers it with: ovis's ROS 2 node's
(:mod:`ovis.common.ros2.topics`: reliable, and transient local for what late
subscribers need, ``/tf_static`` and CameraInfo). A message's bag time is when the
recorder received it (as ``ros2 bag record`` stamps); its header keeps the frame's
capture time.

rosbags writes ``metadata.yaml`` and the MCAP's index when the bag is closed: a
recorder stopped by Ctrl-C or SIGTERM closes it; one killed outright leaves a bag
without them.
"""

from __future__ import annotations

from pathlib import Path

from rosbags.interfaces import (
    Connection,
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError

from ovis.common.ros2.cdr import RosMessage, message_definition, type_hash
from ovis.common.ros2.topics import qos_of
from ovis.common.ros2.wire import QoS

__all__ = ["BagError", "RosBag", "bag_path"]

_ZERO = QosTime(0, 0)  # ROS 2's default (infinite) deadline, lifespan and lease


class BagError(RuntimeError):
    """The bag cannot be written (says why)."""


def bag_path(session: Path) -> Path:
    """Where the bag of session file ``session`` goes: ``S.mcap`` → ``S.ros2``."""
    return session.with_suffix(".ros2")


def _bag_qos(qos: QoS) -> Qos:
    """A topic's QoS (:func:`~ovis.common.ros2.topics.qos_of`, the node's) as rosbags
    writes it (the same rmw enum numbers)."""
    return Qos(
        QosHistory(qos.history),
        qos.depth,
        QosReliability(qos.reliability),
        QosDurability(qos.durability),
        _ZERO,
        _ZERO,
        QosLiveliness.AUTOMATIC,
        _ZERO,
        False,
    )


class RosBag:
    """A rosbag2 bag being written (one thread); topics are added as they come."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        try:
            self._writer.open()
        except (WriterError, OSError) as exc:
            raise BagError(f"cannot write the ROS 2 bag {path}: {exc}") from None
        self._connections: dict[str, Connection] = {}
        self.counts: dict[str, int] = {}

    def write(self, topic: str, message: RosMessage, time_ns: int) -> None:
        """``message`` on its full topic name (``/ovis/obstacles``) at bag time
        ``time_ns`` (ns since the epoch)."""
        connection = self._connections.get(topic)
        if connection is None:
            try:
                connection = self._writer.add_connection(
                    topic,
                    message.type,
                    msgdef=message_definition(message.type),
                    rihs01=type_hash(message.type),
                    offered_qos_profiles=[_bag_qos(qos_of(message.topic))],
                )
            except WriterError as exc:  # the same topic with another type
                raise BagError(f"{topic}: {exc}") from None
            self._connections[topic] = connection
        if connection.msgtype != message.type:
            raise BagError(f"{topic} is {connection.msgtype} in the bag, not {message.type}")
        self._writer.write(connection, time_ns, message.cdr)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def close(self) -> None:
        """Write the index and ``metadata.yaml``: the bag is then readable."""
        self._writer.close()
