"""The Zenoh session and its settings: our [zenoh] section as a Zenoh configuration,
a session that always closes, and the loopback peers of ``ovis up``."""

from __future__ import annotations

import errno
import socket
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

import msgspec
import zenoh

from ovis.common.config import ZenohConfig
from ovis.services.stopping import Stopping

__all__ = [
    "LOOPBACK_PEER",
    "ZenohUnreachableError",
    "client_session",
    "endpoint_in_use",
    "interruptible",
    "local_peers",
    "open_session",
    "zenoh_config",
]


def zenoh_config(
    zc: ZenohConfig, *, wait: bool = True, timeout_s: float | None = None
) -> zenoh.Config:
    """A Zenoh configuration from ours: an optional JSON5 file, then mode/connect/listen.

    With ``wait``, a client keeps trying its routers instead of failing at once (a
    service started before its router waits for it); tools pass ``wait=False`` to say
    "no router" straight away, or ``timeout_s`` to keep trying that long.
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
        if timeout_s is not None:
            conf.insert_json5("connect/timeout_ms", str(max(1, round(timeout_s * 1000))))
            conf.insert_json5("connect/exit_on_failure", "true")
        elif wait:
            conf.insert_json5("connect/timeout_ms", "-1")
            conf.insert_json5("connect/exit_on_failure", "false")
    if zc.listen:
        conf.insert_json5("listen/endpoints", msgspec.json.encode(zc.listen).decode())
    conf.insert_json5("scouting/multicast/enabled", "true" if zc.multicast_scouting else "false")
    if not zc.shared_memory:
        conf.insert_json5("transport/shared_memory/enabled", "false")
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


def _unreachable(zc: ZenohConfig, why: str) -> ZenohUnreachableError:
    return ZenohUnreachableError(
        f"cannot reach Zenoh at {', '.join(zc.connect or zc.listen)}: {why}. Is a router "
        "running there (`ovis router`, `ovis up`)? Use --connect to name another"
        + (
            f"; or did it refuse the TLS certificate or user/password of {zc.config_file}?"
            if zc.config_file
            else ""
        )
    )


@contextmanager
def open_session(zc: ZenohConfig, *, wait: bool = True) -> Iterator[zenoh.Session]:
    """Open a Zenoh session and always close it (a session left open hangs the exit)."""
    try:
        session = zenoh.open(zenoh_config(zc, wait=wait))
    except zenoh.ZError as exc:
        raise _unreachable(zc, str(exc)) from None
    try:
        yield session
    finally:
        session.close()


T = TypeVar("T")


def interruptible(
    stop: Stopping,
    work: Callable[[], T],
    *,
    discard: Callable[[T], object] | None = None,
) -> T | None:
    """``work()`` in a thread: its result (or its exception), or None as soon as ``stop``
    is set (Ctrl-C, SIGTERM). A main thread blocked in a Zenoh call does not run the
    Python signal handlers until Zenoh returns, which may be never (a client waiting
    for its router). A result that comes after ``stop`` won goes to ``discard`` (a
    session opened too late is closed, not left to hold the interpreter's exit)."""
    done = threading.Event()
    lock = threading.Lock()
    result: list[tuple[bool, Any]] = []
    abandoned = False

    def run() -> None:
        try:
            outcome: tuple[bool, Any] = (True, work())
        except BaseException as exc:  # handed to the caller's thread
            outcome = (False, exc)
        with lock:
            result.append(outcome)
            done.set()
            late = abandoned
        if late and outcome[0] and discard is not None:
            discard(outcome[1])

    threading.Thread(target=run, name="interruptible", daemon=True).start()
    while not done.is_set() and not stop.is_set():
        done.wait(0.05)
    with lock:
        if not done.is_set():
            abandoned = True
            return None
    ok, value = result[0]
    if not ok:
        raise value
    return value


@contextmanager
def client_session(
    zc: ZenohConfig, timeout_s: float, stop: Stopping
) -> Iterator[zenoh.Session | None]:
    """A tool's session: its router must answer within ``timeout_s`` counted from the
    process's start (:func:`~ovis.services.cli.options.time_left`;
    :class:`ZenohUnreachableError` otherwise); None when ``stop`` is set first."""
    from ovis.services.cli.options import time_left

    def open_it() -> zenoh.Session:
        return zenoh.open(zenoh_config(zc, timeout_s=time_left(timeout_s)))

    try:
        session = interruptible(stop, open_it, discard=lambda late: late.close())
    except zenoh.ZError as exc:
        why = "" if "Timeout" in str(exc) else f" ({exc})"
        raise _unreachable(zc, f"no router answered within {timeout_s:g} s{why}") from None
    if session is None:
        yield None
        return
    try:
        yield session
    finally:
        session.close()


def endpoint_in_use(endpoint: str) -> str | None:
    """Why a router could not listen on ``endpoint`` because something holds it (the
    operating system's words), or None: free, not a port, or failing otherwise (the
    router says why). A bind is tried, with SO_REUSEADDR so that only a listener, not a
    closed connection, counts."""
    proto, _, address = endpoint.partition("/")
    address = address.split("#", 1)[0].split("?", 1)[0]
    host, _, port = address.rpartition(":")
    if proto not in ("tcp", "tls", "ws", "udp", "quic") or not port.isdigit() or port == "0":
        return None
    kind = socket.SOCK_DGRAM if proto in ("udp", "quic") else socket.SOCK_STREAM
    try:
        found = socket.getaddrinfo(host.strip("[]") or None, int(port), type=kind)
        family, _, _, _, where = found[0]
    except OSError:
        return None  # the router itself says what is wrong with the address
    with socket.socket(family, kind) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(where)
        except OSError as exc:
            return (exc.strerror or str(exc)) if exc.errno == errno.EADDRINUSE else None
    return None
