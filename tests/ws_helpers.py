"""Raw WebSockets to a running `ovis view`, opened as its own page opens them (the
view's Origin) or with another Origin, from a chosen loopback address (127.0.0.0/8:
each one another client for the view's per-address limits), and their text messages.
Knows only `websockets`: what any client could run."""

from __future__ import annotations

import json
import socket
import time
import urllib.request
from collections.abc import Callable
from typing import Any

from websockets.sync.client import ClientConnection, connect

#: ``origin`` for the view's own page.
OWN = "own"


def serving(url: str) -> bool:
    """Whether the view at ``url`` answers its state (for wait_for)."""
    try:
        urllib.request.urlopen(url + "api/state", timeout=2).close()
        return True
    except OSError:
        return False


def ws_connect(url: str, source: str = "127.0.0.1", origin: str | None = OWN) -> ClientConnection:
    """A WebSocket to the view at ``url`` (``http://HOST:PORT/``) from the loopback
    address ``source``, with ``origin`` as its Origin (None: no Origin header)."""
    host, port = url.removeprefix("http://").rstrip("/").rsplit(":", 1)
    sock = socket.create_connection((host, int(port)), timeout=10, source_address=(source, 0))
    return connect(
        url.replace("http://", "ws://", 1) + "ws",
        sock=sock,
        origin=url.rstrip("/") if origin == OWN else origin,  # type: ignore[arg-type]
        open_timeout=10,
    )


def texts_until(
    ws: ClientConnection, until: Callable[[dict[str, Any]], Any], timeout: float = 10.0
) -> list[dict[str, Any]]:
    """The text messages (JSON) of ``ws`` up to the first for which ``until`` is true."""
    got: list[dict[str, Any]] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        data = ws.recv(timeout=max(0.1, deadline - time.monotonic()))
        if isinstance(data, str):
            got.append(json.loads(data))
            if until(got[-1]):
                return got
    raise AssertionError(f"no matching message in {timeout} s: {got[-5:]}")
