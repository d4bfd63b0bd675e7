"""A client of the bus that knows only Zenoh and MessagePack (no ovis import): what
anyone on the network could run. For the tests that play an adversary or a fault
against real processes."""

from __future__ import annotations

import json
import time
from typing import Any

import msgpack
import zenoh


class BusClient:
    """A plain Zenoh client of one arena: puts, queries and the services' statuses."""

    def __init__(self, endpoint: str, arena: str = "default") -> None:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(conf)
        self.root = f"ovis/{arena}"

    @classmethod
    def connect(cls, endpoint: str) -> BusClient | None:
        """A client, or None while nothing listens at ``endpoint`` yet (for wait_for)."""
        try:
            return cls(endpoint)
        except zenoh.ZError:
            time.sleep(0.5)
            return None

    def put(self, key: str, payload: bytes) -> None:
        self.session.put(
            f"{self.root}/{key}", payload, congestion_control=zenoh.CongestionControl.BLOCK
        )

    def ask(self, key: str, payload: bytes | None = None, timeout: float = 3.0) -> list[Any]:
        replies = self.session.get(f"{self.root}/{key}", payload=payload, timeout=timeout)
        return [msgpack.unpackb(r.ok.payload.to_bytes()) for r in replies if r.ok is not None]

    def statuses(self) -> dict[str, dict[str, Any]]:
        return {st["service"]: st for st in self.ask("status/*")}

    def status(self, service: str) -> dict[str, Any] | None:
        return self.statuses().get(service)

    def close(self) -> None:
        self.session.close()
