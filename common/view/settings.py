"""Settings of ``ovis view``, validated on load like every ovis configuration."""

from __future__ import annotations

import re
from typing import Annotated

import msgspec

__all__ = ["ViewSettings", "parse_listen", "view_settings"]

_LISTEN = re.compile(
    r"^(?:\[(?P<v6>[0-9A-Fa-f:.]+)\]|(?P<host>[A-Za-z0-9_.-]+)):(?P<port>\d{1,5})$"
)


class ViewSettings(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """How the view serves browsers."""

    host: str = "127.0.0.1"
    port: Annotated[int, msgspec.Meta(ge=0, le=65535)] = 8080  # 0: any free port
    arenas: list[str] = []
    discover: bool = True  # also follow arenas found alive on the bus
    #: pictures per second sent to each browser, at most
    max_fps: Annotated[float, msgspec.Meta(gt=0.0, le=30.0)] = 10.0
    #: longer side of the pictures, pixels (frames are only ever shrunk)
    max_side: Annotated[int, msgspec.Meta(ge=64, le=4096)] = 640
    jpeg_quality: Annotated[int, msgspec.Meta(ge=10, le=100)] = 80
    #: browsers served at once; more are told to come back later
    max_clients: Annotated[int, msgspec.Meta(ge=1, le=1000)] = 32
    #: when set, the page offers recalibration to whoever gives this token
    operator_token: Annotated[str, msgspec.Meta(min_length=8, max_length=256)] | None = None
    #: how long a recalibration may take, s
    recalibrate_timeout_s: Annotated[float, msgspec.Meta(gt=0.0, le=3600.0)] = 300.0


def parse_listen(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (or ``[IPv6]:PORT``) as (host, port); ValueError saying what is wrong."""
    m = _LISTEN.match(text.strip())
    if not m or int(m["port"]) > 65535:
        raise ValueError(
            f"--listen {text!r}: expected HOST:PORT such as 127.0.0.1:8080 or [::1]:8080 "
            "(port 0-65535; 0 picks a free one)"
        )
    return m["v6"] or m["host"], int(m["port"])


def view_settings(**fields: object) -> ViewSettings:
    """Settings from keyword values (None: the default), validated; ValueError naming the
    bad field."""
    given = {k: v for k, v in fields.items() if v is not None}
    try:
        return msgspec.convert(given, ViewSettings)
    except msgspec.ValidationError as exc:
        raise ValueError(f"view settings: {exc}") from None
