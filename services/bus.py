"""The Zenoh session and its settings: our [zenoh] section as a Zenoh configuration,
a session that always closes, and the loopback peers of ``ovis up``."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import msgspec
import zenoh

from ovis.common.config import ZenohConfig

__all__ = [
    "LOOPBACK_PEER",
    "ZenohUnreachableError",
    "local_peers",
    "open_session",
    "zenoh_config",
]


def zenoh_config(zc: ZenohConfig, *, wait: bool = True) -> zenoh.Config:
    """A Zenoh configuration from ours: an optional JSON5 file, then mode/connect/listen.

    With ``wait``, a client keeps trying its routers instead of failing at once (a
    service started before its router waits for it); tools pass ``wait=False`` to say
    "no router" straight away.
    """
    if zc.config_file:
        path = Path(zc.config_file)
        if not path.is_file():
            raise FileNotFoundError(f"Zenoh configuration file {path} does not exist")
        conf = zenoh.Config.from_file(str(path))
    else:
        conf = zenoh.Config()
    conf.insert_json5("mode", msgspec.json.encode(zc.mode).decode())
    if zc.connect:
        conf.insert_json5("connect/endpoints", msgspec.json.encode(zc.connect).decode())
        if wait:
            conf.insert_json5("connect/timeout_ms", "-1")
            conf.insert_json5("connect/exit_on_failure", "false")
    if zc.listen:
        conf.insert_json5("listen/endpoints", msgspec.json.encode(zc.listen).decode())
    conf.insert_json5("scouting/multicast/enabled", "true" if zc.multicast_scouting else "false")
    return conf


#: Where services on the router's machine listen for each other (any free port).
LOOPBACK_PEER = "tcp/127.0.0.1:0"


def local_peers(zc: ZenohConfig) -> ZenohConfig:
    """The Zenoh settings for services that share the router's machine (``ovis up``):
    Zenoh peers listening on loopback instead of clients. They still join through the
    router, which tells them about each other (gossip), and then send each message
    straight to the next stage: one TCP hop per message instead of two through the
    router, which lowers the latency (see ``benchmarks/``). Tools and subscribers on
    other machines still reach them through the router. A configuration with its own
    Zenoh file (TLS, access control) or mode is left as it is.
    """
    if zc.config_file or zc.mode != "client" or zc.listen:
        return zc
    return msgspec.structs.replace(zc, mode="peer", listen=[LOOPBACK_PEER])


class ZenohUnreachableError(RuntimeError):
    """No router answered at the configured endpoints."""


@contextmanager
def open_session(zc: ZenohConfig, *, wait: bool = True) -> Iterator[zenoh.Session]:
    """Open a Zenoh session and always close it (a session left open hangs the exit)."""
    try:
        session = zenoh.open(zenoh_config(zc, wait=wait))
    except zenoh.ZError as exc:
        raise ZenohUnreachableError(
            f"cannot reach Zenoh at {', '.join(zc.connect or zc.listen)}: {exc}. Is a router "
            "running there (`ovis router`, `ovis up`)? Use --connect to name another"
            + (
                f"; or did it refuse the TLS certificate or user/password of {zc.config_file}?"
                if zc.config_file
                else ""
            )
        ) from None
    try:
        yield session
    finally:
        session.close()
