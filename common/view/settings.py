"""Settings of ``ovis view``, validated on load like every ovis configuration."""

from __future__ import annotations

import re
from typing import Annotated

import msgspec

from ovis.common.view.guard import canonical_origin, token_problem

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
    #: when set, the page offers recalibration to whoever gives this token (strong
    #: enough: see ovis.common.view.guard.token_problem)
    operator_token: Annotated[str, msgspec.Meta(min_length=1, max_length=256)] | None = None
    #: how long a recalibration may take, s
    recalibrate_timeout_s: Annotated[float, msgspec.Meta(gt=0.0, le=3600.0)] = 300.0
    #: sockets one client (address) may hold; the operator's token gets in beyond
    max_clients_per_address: Annotated[int, msgspec.Meta(ge=1, le=1000)] = 8
    #: origins (scheme://host[:port]) besides the view's own whose pages may use it
    allow_origins: Annotated[list[str], msgspec.Meta(max_length=64)] = []

    def __post_init__(self) -> None:
        if self.operator_token is not None and (problem := token_problem(self.operator_token)):
            raise ValueError(f"operator_token: {problem}")
        for origin in self.allow_origins:
            if canonical_origin(origin) is None:
                raise ValueError(
                    f"allow_origins: {origin!r} is not an origin such as "
                    "https://ovis.example.org or http://10.0.0.5:8080"
                )


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
