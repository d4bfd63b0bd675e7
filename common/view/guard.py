"""Who may use the view's WebSocket and API, as pure logic (a clock is passed in):
which origins (a page from another site must not read the arena), how strong an
operator token must be, how fast a client may guess it (a back-off per address, the
socket closed after a few refusals), how many sockets a client and all clients may
hold (the operator's token always gets in), and how often a refusal is logged (a
flood of them must not fill the log)."""

from __future__ import annotations

import collections
import ipaddress
import math
import secrets
import string
import time
from collections.abc import Callable, Iterable
from typing import NamedTuple
from urllib.parse import urlsplit

__all__ = [
    "FREE_GUESSES",
    "MAX_BACKOFF_S",
    "MIN_TOKEN_BITS",
    "GuessLimiter",
    "LogThrottle",
    "OriginPolicy",
    "Seats",
    "canonical_origin",
    "new_token",
    "token_bits",
    "token_problem",
]

#: The least an operator token must be worth (an estimate, see :func:`token_bits`).
MIN_TOKEN_BITS = 128
#: Wrong tokens a client may give before it must wait; then the wait doubles from 1 s
#: up to :data:`MAX_BACKOFF_S`.
FREE_GUESSES = 3
MAX_BACKOFF_S = 60.0
#: Clients (addresses) whose guesses are remembered; the oldest is forgotten first.
MAX_TRACKED = 10_000

_CLASSES = (string.digits, string.ascii_lowercase, string.ascii_uppercase)


def token_bits(token: str) -> float:
    """What a token is worth at most, in bits: its length × log2 of the characters
    of the classes it uses (digits 10, lower case 26, upper case 26, anything else
    33). Only an upper bound: a word or a repeated pattern is worth far less."""
    pool = sum(len(chars) for chars in _CLASSES if any(c in chars for c in token))
    if any(not any(c in chars for chars in _CLASSES) for c in token):
        pool += 33
    return len(token) * math.log2(pool) if pool > 1 else 0.0


def token_problem(token: str) -> str | None:
    """Why an operator token is too weak to guard recalibration, or None."""
    bits = token_bits(token)
    if bits >= MIN_TOKEN_BITS:
        return None
    return (
        f"the operator token ({len(token)} characters) is worth at most {bits:.0f} bits, "
        f"{MIN_TOKEN_BITS} are needed: use `--operator-token auto` to have one made, or "
        "make one with `python3 -c 'import secrets; print(secrets.token_urlsafe(24))'`"
    )


def new_token() -> str:
    """A random operator token (192 bits, URL-safe: it can ride in the page's URL)."""
    return secrets.token_urlsafe(24)


def canonical_origin(origin: str) -> str | None:
    """``scheme://host:port`` of an origin, lower case, the port always written (80
    or 443 by default, as a browser leaves it out); None if it is not an http(s)
    origin (``null``, a path, garbage)."""
    try:
        parts = urlsplit(origin.strip())
        port = parts.port
    except ValueError:
        return None
    if parts.scheme not in ("http", "https") or not parts.hostname or parts.path not in ("", "/"):
        return None
    if parts.query or parts.fragment or parts.username or parts.password:
        return None
    host = parts.hostname.lower()
    if ":" in host:
        host = f"[{host}]"
    return f"{parts.scheme}://{host}:{port or (443 if parts.scheme == 'https' else 80)}"


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class OriginPolicy:
    """The origins whose pages may use ``/ws`` and ``/api``: the view's own (the
    address it listens on, and the loopback names when that is loopback; listening on
    every address, any name the page was loaded under: the Origin must then match the
    Host it asked) and the ``allowed`` list."""

    def __init__(self, host: str, port: int, allowed: Iterable[str] = ()) -> None:
        self.any_host = host in ("", "0.0.0.0", "::")
        names = {host}
        if _is_loopback(host):
            names |= {"localhost", "127.0.0.1", "::1"}
        own = (canonical_origin(f"http://{_bracketed(n)}:{port}") for n in names)
        self.own = {o for o in own if o is not None}
        self.allowed = {o for o in map(canonical_origin, allowed) if o is not None}

    def problem(self, origin: str | None, host: str | None, *, required: bool) -> str | None:
        """Why a request with this Origin (and Host) header is refused, or None. A
        request without an Origin comes from a program, not a page (browsers always
        send one on WebSockets and on requests from another site): refused only when
        ``required``."""
        if origin is None:
            if not required:
                return None
            return (
                "no Origin header: a WebSocket client must send the view's own origin "
                "(or one of --allow-origin) as its Origin"
            )
        canonical = canonical_origin(origin)
        if canonical is not None and canonical in self.own | self.allowed:
            return None
        if canonical is not None and self.any_host and host:
            scheme = canonical.split(":", 1)[0]
            if canonical == canonical_origin(f"{scheme}://{host}"):
                return None
        return (
            f"origin {origin!r} is not allowed: only pages of the view itself, or of an "
            "origin given with --allow-origin, may use it"
        )


def _bracketed(host: str) -> str:
    return f"[{host}]" if ":" in host else host


class _Guesses(NamedTuple):
    wrong: int  # wrong tokens in a row
    until: float  # no token is checked before this (clock time)


class GuessLimiter:
    """Wrong operator tokens per client (address): after :data:`FREE_GUESSES` wrong
    ones in a row, the client must wait 1 s, then 2, 4, … up to :data:`MAX_BACKOFF_S`
    before its next token is even checked; a right one forgives it all."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._clients: collections.OrderedDict[str, _Guesses] = collections.OrderedDict()

    def wait_s(self, client: str) -> float:
        """Seconds before a token of ``client`` is checked again (0: now)."""
        state = self._clients.get(client)
        return 0.0 if state is None else max(0.0, state.until - self._clock())

    def wrong(self, client: str) -> float:
        """Count a wrong token of ``client``; the wait it now has (0: none yet)."""
        wrong = self._clients.pop(client, _Guesses(0, 0.0)).wrong + 1
        wait = 0.0
        if wrong > FREE_GUESSES:
            wait = min(2.0 ** (wrong - FREE_GUESSES - 1), MAX_BACKOFF_S)
        self._clients[client] = _Guesses(wrong, self._clock() + wait)
        while len(self._clients) > MAX_TRACKED:
            self._clients.popitem(last=False)
        return wait

    def right(self, client: str) -> None:
        self._clients.pop(client, None)


class LogThrottle:
    """At most one log line per kind of refusal every ``period_s``, the first at once:
    :meth:`allow` says whether to log now and how many were left out since."""

    def __init__(self, period_s: float = 10.0, clock: Callable[[], float] = time.monotonic) -> None:
        self.period_s = period_s
        self._clock = clock
        self._last: dict[str, float] = {}
        self._skipped: collections.Counter[str] = collections.Counter()

    def allow(self, kind: str) -> int | None:
        """None: do not log this one; else log it, with this many left out before it."""
        now = self._clock()
        last = self._last.get(kind)
        if last is not None and now - last < self.period_s:
            self._skipped[kind] += 1
            return None
        self._last[kind] = now
        return self._skipped.pop(kind, 0)


class Seats:
    """The sockets the view serves: at most ``per_client`` from one address and
    ``total`` in all for viewers; the operator (who gave the token) has
    ``operator_seats`` more of its own, so idle viewers never lock it out."""

    def __init__(self, total: int, per_client: int, operator_seats: int) -> None:
        self.total, self.per_client, self.operator_seats = total, per_client, operator_seats
        self.viewers: collections.Counter[str] = collections.Counter()
        self.operators = 0

    def take(self, client: str) -> str | None:
        """Seat a viewer from ``client``; or why not (it stays unseated)."""
        if self.viewers[client] >= self.per_client:
            return (
                f"too many viewers from {client} ({self.per_client}, the view's "
                "--max-clients-per-address): close another view of ovis there"
            )
        if sum(self.viewers.values()) >= self.total:
            return (
                f"too many viewers ({self.total}, the view's --max-clients): close another "
                "view of ovis or try again later"
            )
        self.viewers[client] += 1
        return None

    def take_operator(self) -> str | None:
        if self.operators >= self.operator_seats:
            return (
                f"the {self.operator_seats} operator seats are taken: close another operator page"
            )
        self.operators += 1
        return None

    def leave(self, client: str, operator: bool) -> None:
        if operator:
            self.operators -= 1
            return
        self.viewers[client] -= 1
        if self.viewers[client] <= 0:
            del self.viewers[client]
