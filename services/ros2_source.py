"""Frames from a ROS 2 camera (``--source ros2:/camera/image/compressed``): a
``sensor_msgs/msg/CompressedImage`` or ``Image`` topic received through rmw_zenoh, on the
key of that topic whatever its type hash (:mod:`ovis.common.ros2.wire`), decoded by
rosbags (:mod:`ovis.common.ros2.images`). It needs a Zenoh session, so it lives here
and not in :mod:`ovis.common.capture.sources`; it behaves as the network streams there
do: :data:`STREAM_OPEN_TIMEOUT_S` for the router and the first image,
:data:`STREAM_READ_TIMEOUT_S` for each next one, else :class:`SourceError` saying what
the ROS 2 graph holds."""

from __future__ import annotations

import contextlib
import time
from typing import Any

import numpy as np
import zenoh
from numpy.typing import NDArray

from ovis.common.capture.sources import (
    STREAM_OPEN_TIMEOUT_S,
    STREAM_READ_TIMEOUT_S,
    FrameSource,
    SourceError,
)
from ovis.common.capture.sources import open_source as open_common_source
from ovis.common.config import OvisConfig, ZenohConfig
from ovis.common.pipeline.stages import MAX_CLOCK_SKEW_S
from ovis.common.ros2 import wire
from ovis.common.sim.arena import FrameTruth
from ovis.services.bus import zenoh_config
from ovis.services.inbox import Inbox

__all__ = ["PREFIX", "Ros2Source", "open_source"]

PREFIX = "ros2:"
#: How long the ROS 2 graph (liveliness tokens) is asked, to say what it holds.
GRAPH_S = 0.5


def open_source(spec: str, config: OvisConfig, **options: Any) -> FrameSource:
    """Any capture source: ``ros2:/topic`` here, the others (with their ``options``:
    ``loop``, ``progress``) by :func:`ovis.common.capture.sources.open_source`."""
    if spec.startswith(PREFIX):
        return Ros2Source(spec, config)
    return open_common_source(spec, config, **options)


class Ros2Source:
    """The images of one ROS 2 topic; ``capture_ns`` is the last one's capture time
    (its header stamp, or its receipt when the stamp is unset or far from this clock)."""

    def __init__(self, spec: str, config: OvisConfig) -> None:
        # ROS 2's message types load here, not where the capture starts: rosbags' type
        # store is slow to import and every other source does without it
        from ovis.common.ros2 import images

        self._images = images
        self.topic = spec.removeprefix(PREFIX)
        cfg = config.ros2
        self.domain_id = cfg.domain_id
        try:
            pattern = wire.topic_key_pattern(cfg.domain_id, self.topic)
        except wire.WireError as exc:
            raise SourceError(f"{spec}: {exc}") from None
        self.endpoints = cfg.connect or config.zenoh.connect
        where = ", ".join(self.endpoints)
        self.description = f"ROS 2 topic {self.topic} (domain {cfg.domain_id}, via {where})"
        zc = ZenohConfig(mode="peer", connect=self.endpoints)
        try:
            self.session = zenoh.open(zenoh_config(zc, timeout_s=STREAM_OPEN_TIMEOUT_S))
        except zenoh.ZError as exc:
            raise SourceError(
                f"cannot reach the ROS 2 router at {where} within {STREAM_OPEN_TIMEOUT_S:g} s "
                f"({exc}): is rmw_zenohd running there? Set [ros2] connect to its endpoint"
            ) from None
        self._box = Inbox(2)
        self._first = True
        self.capture_ns: int | None = None
        self._sub = self.session.declare_subscriber(pattern, self._on_sample)
        # The graph as rmw_zenoh keeps it: liveliness tokens followed from the start, so
        # an error after the wait names what was there even if a last query is slow.
        self._tokens: dict[str, wire.Token] = {}
        self._graph_sub = self.session.liveliness().declare_subscriber(
            f"{wire.ADMIN_SPACE}/{self.domain_id}/**", self._on_token, history=True
        )

    def _on_token(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        if sample.kind == zenoh.SampleKind.DELETE:
            self._tokens.pop(key, None)
            return
        with contextlib.suppress(wire.WireError):
            self._tokens[key] = wire.parse_token(key)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        self._box.put((str(sample.key_expr), sample.payload.to_bytes(), time.time_ns()))

    def read(self) -> tuple[NDArray[np.uint8], FrameTruth | None]:
        wait = STREAM_OPEN_TIMEOUT_S if self._first else STREAM_READ_TIMEOUT_S
        item = self._box.get(wait)
        if item is None:
            raise SourceError(
                f"{self.description} delivered no image for {wait:g} s: {self._graph()}"
            )
        self._first = False
        key, payload, receipt = item
        try:
            type_name = wire.parse_topic_key(key).type_name
            image, stamp = self._images.image_from_cdr(payload, type_name)
        except (wire.WireError, self._images.ImageError) as exc:
            raise SourceError(f"{self.description}: {exc}") from None
        trusted = stamp > 0 and abs(stamp - receipt) < MAX_CLOCK_SKEW_S / 2 * 1e9
        self.capture_ns = stamp if trusted else receipt
        return image, None

    def _graph(self) -> str:
        """What the ROS 2 graph says of this topic's publishers (liveliness tokens followed
        since the start, and a last query for any the subscription has not yet had)."""
        found: list[wire.Token] = list(self._tokens.values())
        try:
            for reply in self.session.liveliness().get(
                f"{wire.ADMIN_SPACE}/{self.domain_id}/**", timeout=GRAPH_S
            ):
                if reply.ok is not None:
                    try:
                        found.append(wire.parse_token(str(reply.ok.key_expr)))
                    except wire.WireError:
                        continue
        except zenoh.ZError:
            pass
        mine = [t for t in found if t.kind == "MP" and t.topic == self.topic]
        if mine:
            types = ", ".join(sorted({t.type_name for t in mine}))
            readable = " or ".join(self._images.IMAGE_TYPES)
            return f"its publisher ({types}) sends nothing ovis reads ({readable})"
        others = sorted({t.topic for t in found if t.kind == "MP"})
        graph = (
            f"publishers on domain {self.domain_id}: {', '.join(others)}"
            if others
            else (f"no ROS 2 publisher at all on domain {self.domain_id}")
        )
        return f"no ROS 2 node publishes it ({graph}); check the topic and [ros2] domain_id"

    def close(self) -> None:
        with contextlib.suppress(zenoh.ZError):
            self._sub.undeclare()
            self._graph_sub.undeclare()
        self.session.close()
