"""Real Zenoh on loopback for the integration tests: free ports, processes, sessions.

ovis is imported only inside the functions that need it, so that a test that must not
import ovis (tests/test_adversarial.py) can use the rest."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import zenoh


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def ovis_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "ovis.services.cli", *args]


def spawn(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    """Start a child that gets SIGTERM if the test process dies (no orphans)."""
    from ovis.services.supervisor import die_with_parent

    fh = open(log, "wb")  # noqa: SIM115 (the child keeps it)
    return subprocess.Popen(
        args,
        stdout=fh,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        preexec_fn=die_with_parent,
    )


def stop(procs: list[subprocess.Popen[bytes]], timeout: float = 10.0) -> None:
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + timeout
    for p in procs:
        try:
            p.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


@contextlib.contextmanager
def client(endpoint: str) -> Iterator[zenoh.Session]:
    from ovis.common.config import ZenohConfig
    from ovis.services.bus import zenoh_config

    session = zenoh.open(zenoh_config(ZenohConfig(connect=[endpoint])))
    try:
        yield session
    finally:
        session.close()


def wait_for(predicate: Callable[[], object], timeout: float, what: str) -> object:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")


def wait_subscribed(endpoint: str, key: str, timeout: float = 10.0) -> None:
    """Wait until the router at ``endpoint`` has a subscriber for ``key``: a publisher on
    a session of its own sees it match (what a process started next will also see)."""
    with client(endpoint) as probe:
        publisher = probe.declare_publisher(key)
        wait_for(lambda: publisher.matching_status.matching, timeout, f"a subscriber of {key}")
        publisher.undeclare()


def alive(session: zenoh.Session, arena: str = "default") -> set[str]:
    names = set()
    for reply in session.liveliness().get(f"ovis/{arena}/alive/*", timeout=1.0):
        if reply.ok is not None:
            names.add(str(reply.ok.key_expr).rsplit("/", 1)[-1])
    return names


def pids_with(text: str) -> list[int]:
    """Processes whose command line contains ``text`` (to check for orphans)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if text in cmd:
            found.append(int(entry.name))
    return found


def frame_map(seq: int, data: bytes, rows: int = 480, cols: int = 640) -> dict[str, object]:
    """A grey frame as a plain map, the way a client with only msgpack writes it (the
    attack tests forge frames with it: ``data`` may be any length)."""
    return {
        "type": "frame",
        "seq": seq,
        "stamp_ns": time.time_ns(),
        "rows": rows,
        "cols": cols,
        "channels": 1,
        "dtype": "uint8",
        "data": data,
    }
