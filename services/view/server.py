"""The view's web server: one page (``static/``) and a WebSocket (``/ws``) that pushes
each browser the pictures, obstacles and health of the arena it watches.

Every browser has one slot per kind of update (picture, obstacles, health, …): a newer
update replaces one not yet sent, so a slow browser gets fewer pictures, never a
growing queue. Pictures are made once per tick for all browsers of an arena, at most
``max_fps`` a second, and only while someone watches. What a browser sends is parsed
into a few known messages; anything else gets an error message back (and after
``MAX_BAD`` of them the connection is closed). Recalibration needs the operator token
(compared in constant time) on every request.

Who may use it (:mod:`ovis.common.view.guard`): ``/ws`` and ``/api`` only for pages of
the view's own origin or of ``allow_origins`` (a WebSocket must say its Origin); wrong
tokens slowed down per client address and the socket closed after
``MAX_WRONG_TOKENS``; a client holds at most ``max_clients_per_address`` sockets and all
at most ``max_clients``, but a page that sends the operator token first gets one of
``OPERATOR_SEATS`` seats of its own; refusals are logged at most once per kind every
few seconds.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import logging
import socket
import struct
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Annotated, Any

import msgspec
import uvicorn
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import HTMLResponse, JSONResponse, PlainTextResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect

from ovis.common.messages import CalibrateRequest, Topics
from ovis.common.view.grid import map_grid_step
from ovis.common.view.guard import GuessLimiter, LogThrottle, OriginPolicy, Seats
from ovis.common.view.scene import scene_objects
from ovis.common.view.settings import ViewSettings
from ovis.services.view.feed import ArenaFeed, Bus
from ovis.services.view.pictures import KINDS, Picture, make_pictures

__all__ = ["STATIC", "ViewServer", "bind", "pack_picture", "serve"]

log = logging.getLogger("ovis.view")

STATIC = Path(__file__).resolve().parent / "static"
#: Bad messages a browser may send before it is disconnected.
MAX_BAD = 50
#: Largest message accepted from a browser, bytes.
MAX_MESSAGE = 4096
HEALTH_PERIOD_S = 0.5
#: Refused operator tokens (wrong, or sent while the client must wait) before the
#: socket is closed.
MAX_WRONG_TOKENS = 5
#: Sockets of the operator beyond the viewers' seats.
OPERATOR_SEATS = 4
#: How long a socket beyond the seats may take to send the operator token, s.
AUTH_WAIT_S = 2.0

_json = msgspec.json.Encoder()
Count = Annotated[int, msgspec.Meta(ge=0, le=10000)]


class Select(msgspec.Struct, tag="select", tag_field="type", forbid_unknown_fields=True):
    """Watch another arena."""

    arena: Annotated[str, msgspec.Meta(max_length=64)]


class Show(msgspec.Struct, tag="show", tag_field="type", forbid_unknown_fields=True):
    """Which picture to receive: the camera frame or the binarised one."""

    kind: Annotated[str, msgspec.Meta(pattern="^(camera|binary)$")]


class Recalibrate(msgspec.Struct, tag="recalibrate", tag_field="type", forbid_unknown_fields=True):
    """Ask the calibrator to recalibrate (optional GA size; default: as configured)."""

    token: Annotated[str, msgspec.Meta(max_length=256)] = ""
    population: Annotated[int, msgspec.Meta(ge=2, le=10000)] | None = None
    generations: Annotated[int, msgspec.Meta(ge=1, le=10000)] | None = None
    seed: Count | None = None


class Auth(msgspec.Struct, tag="auth", tag_field="type", forbid_unknown_fields=True):
    """The operator token, sent first by a page that has it: checked at once, and it
    gets a socket beyond the viewers' seats in."""

    token: Annotated[str, msgspec.Meta(max_length=256)]


_incoming = msgspec.json.Decoder(Select | Show | Recalibrate | Auth)


def pack_picture(picture: Picture) -> bytes:
    """A binary WebSocket message: 4-byte big-endian header length, the JSON header
    (the picture's fields but the JPEG), the JPEG."""
    header = _json.encode(msgspec.structs.replace(picture, jpeg=b""))
    return struct.pack(">I", len(header)) + header + picture.jpeg


class Viewer:
    """One browser: the arena it watches, the picture it wants, its pending updates."""

    def __init__(self, ws: WebSocket, arena: str, client: str = "unknown") -> None:
        self.ws = ws
        self.arena = arena
        self.client = client  # the remote address
        self.kind = "camera"
        self.slots: dict[str, str | bytes] = {}
        self.wake = asyncio.Event()
        self.bad = 0
        self.wrong_tokens = 0
        self.replaced = 0  # updates overwritten before they could be sent (slow browser)

    def offer(self, slot: str, data: str | bytes) -> None:
        if slot in self.slots:
            self.replaced += 1
        self.slots[slot] = data
        self.wake.set()

    async def pump(self) -> None:
        while True:
            await self.wake.wait()
            self.wake.clear()
            await self.send_pending()

    async def send_pending(self) -> None:
        items, self.slots = self.slots, {}
        for data in items.values():
            if isinstance(data, bytes):
                await self.ws.send_bytes(data)
            else:
                await self.ws.send_text(data)


def _text(kind: str, **fields: Any) -> str:
    return _json.encode({"type": kind, **fields}).decode()


class ViewServer:
    """The ASGI app and its per-arena broadcast loop."""

    def __init__(self, bus: Bus, settings: ViewSettings, origins: OriginPolicy) -> None:
        self.bus = bus
        self.settings = settings
        self.origins = origins
        self.guesses = GuessLimiter()
        self.throttle = LogThrottle()
        self.seats = Seats(settings.max_clients, settings.max_clients_per_address, OPERATOR_SEATS)
        self.viewers: set[Viewer] = set()
        self.recalibrating: dict[str, dict[str, Any]] = {}
        self.last_result: dict[str, dict[str, Any]] = {}
        self._shown: dict[str, dict[str, int]] = {}
        self._counts: dict[str, int] = {}
        self._drive_counts: dict[str, int] = {}
        self._tasks: set[asyncio.Task[None]] = set()

    # --- app --------------------------------------------------------------------------
    def app(self) -> Starlette:
        @contextlib.asynccontextmanager
        async def lifespan(_app: Starlette) -> AsyncIterator[None]:
            task = asyncio.create_task(self._ticker())
            try:
                yield
            finally:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task

        return Starlette(
            routes=[
                Route("/", self._index),
                Route("/api/state", self._state),
                WebSocketRoute("/ws", self._socket),
                Mount("/static", StaticFiles(directory=STATIC), name="static"),
            ],
            lifespan=lifespan,
        )

    async def _index(self, _request: Request) -> Response:
        return HTMLResponse((STATIC / "index.html").read_text("utf-8"))

    async def _state(self, request: Request) -> Response:
        """Everything the page shows but the pictures, as JSON (for scripts; a page of
        another origin is refused)."""
        headers = request.headers
        problem = self.origins.problem(headers.get("origin"), headers.get("host"), required=False)
        if problem is not None:
            self._say("origin", f"refused /api/state to {_client(request)}: {problem}")
            return JSONResponse({"error": problem}, status_code=403)
        out = {}
        for arena in self.bus.arenas():
            feed = self.bus.feed(arena)
            count, latest = self._latest(feed)
            _drives, robots = feed.robots_shown()
            out[arena] = {
                "health": msgspec.to_builtins(feed.health()),
                "obstacle_messages": count,
                "obstacles": latest,
                "robots": msgspec.to_builtins(robots),
            }
        return JSONResponse({"arenas": out, "viewers": len(self.viewers)})

    def default_arena(self) -> str:
        if self.settings.arenas:
            return self.settings.arenas[0]
        arenas = self.bus.arenas()
        return "default" if not arenas or "default" in arenas else arenas[0]

    # --- one browser --------------------------------------------------------------------
    async def _socket(self, ws: WebSocket) -> None:
        client = _client(ws)
        headers = ws.headers
        problem = self.origins.problem(headers.get("origin"), headers.get("host"), required=True)
        if problem is not None:
            self._say("origin", f"refused a WebSocket from {client}: {problem}")
            await ws.send_denial_response(PlainTextResponse(problem, status_code=403))
            return
        await ws.accept()
        operator = False
        full = self.seats.take(client)
        if full is not None:
            operator = await self._operator_despite(ws, client, full)
            if not operator:
                return
        viewer = Viewer(ws, self.default_arena(), client)
        if operator:
            viewer.offer("auth", _text("auth", ok=True, message="operator (an operator seat)"))
        try:
            await self._serve(ws, viewer)
        finally:
            self.seats.leave(client, operator)

    async def _operator_despite(self, ws: WebSocket, client: str, full: str) -> bool:
        """A socket beyond the viewers' seats: in (on an operator seat) only if its first
        message, within ``AUTH_WAIT_S``, is the right operator token; else told why and
        closed."""
        reason = full
        if self.settings.operator_token is not None:
            try:
                first = await asyncio.wait_for(ws.receive(), AUTH_WAIT_S)
            except (TimeoutError, WebSocketDisconnect, RuntimeError):
                first = {}
            token = _auth_token(first.get("text"))
            if token is not None:
                refusal = self._check_token(client, token)
                seat = self.seats.take_operator() if refusal is None else refusal
                if seat is None:
                    return True
                reason = seat
        self._say("full", f"refused a viewer from {client}: {reason}")
        with contextlib.suppress(WebSocketDisconnect, RuntimeError, OSError):
            await ws.send_text(_text("error", fatal=True, message=reason))
            await ws.close(code=1013)
        return False

    async def _serve(self, ws: WebSocket, viewer: Viewer) -> None:
        self.viewers.add(viewer)
        self.bus.feed(viewer.arena).watch()
        pump = asyncio.create_task(viewer.pump())
        try:
            await ws.send_text(self._hello(viewer))
            self._push_health(viewer.arena, [viewer])
            while True:
                msg = await ws.receive()
                if msg["type"] == "websocket.disconnect":
                    break
                if pump.done():
                    break
                await self._handle(viewer, msg.get("text"), msg.get("bytes"))
                closing = ""
                if viewer.bad >= MAX_BAD:
                    closing = f"{MAX_BAD} bad messages: disconnected"
                elif viewer.wrong_tokens >= MAX_WRONG_TOKENS:
                    closing = (
                        f"{MAX_WRONG_TOKENS} operator tokens refused: disconnected; wait "
                        f"{max(1.0, self.guesses.wait_s(viewer.client)):.0f} s before trying again"
                    )
                if closing:  # what it was told so far, then why it is closed
                    pump.cancel()
                    with contextlib.suppress(asyncio.CancelledError):
                        await pump
                    await viewer.send_pending()
                    await ws.send_text(_text("error", fatal=True, message=closing))
                    await ws.close(code=1008)
                    break
        except (WebSocketDisconnect, RuntimeError, OSError):
            pass
        finally:
            pump.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await pump
            self.viewers.discard(viewer)
            self.bus.feed(viewer.arena).unwatch()

    def _hello(self, viewer: Viewer) -> str:
        s = self.settings
        return _text(
            "hello",
            arena=viewer.arena,
            arenas=self.bus.arenas(),
            operator=s.operator_token is not None,
            max_fps=s.max_fps,
            max_side=s.max_side,
            health_period_s=HEALTH_PERIOD_S,
        )

    async def _handle(self, viewer: Viewer, text: str | None, data: bytes | None) -> None:
        if text is None:
            viewer.bad += 1
            size = len(data or b"")
            viewer.offer(
                "error",
                _text(
                    "error",
                    message=f"ignored a {size}-byte binary message: "
                    "the view understands JSON text messages only",
                ),
            )
            return
        if len(text) > MAX_MESSAGE:
            msg: Any = None
            problem = f"message of {len(text)} characters is longer than {MAX_MESSAGE}"
        else:
            try:
                msg, problem = _incoming.decode(text), ""
            except (msgspec.DecodeError, msgspec.ValidationError) as exc:
                msg, problem = None, str(exc)
        if msg is None:
            viewer.bad += 1
            viewer.offer(
                "error",
                _text(
                    "error",
                    message=f"ignored a bad message ({problem}); expected JSON such "
                    'as {"type": "select", "arena": "default"}',
                ),
            )
        elif isinstance(msg, Select):
            self._select(viewer, msg.arena)
        elif isinstance(msg, Show):
            viewer.kind = msg.kind
            self._shown.pop(viewer.arena, None)  # send the new kind at once
        elif isinstance(msg, Auth):
            refusal = self._viewer_token(viewer, msg.token)
            viewer.offer("auth", _text("auth", ok=refusal is None, message=refusal or "operator"))
        else:
            self._recalibrate(viewer, msg)

    def _select(self, viewer: Viewer, arena: str) -> None:
        try:
            Topics(arena)
            if self.settings.arenas and arena not in self.settings.arenas:
                raise ValueError(f"this view follows only {', '.join(self.settings.arenas)}")
        except ValueError as exc:
            viewer.bad += 1
            viewer.offer("error", _text("error", message=f"cannot watch arena {arena!r}: {exc}"))
            return
        if arena != viewer.arena:
            self.bus.feed(arena).watch()
            self.bus.feed(viewer.arena).unwatch()
            viewer.arena = arena
            viewer.slots.pop("picture", None)
        viewer.offer("hello", self._hello(viewer))
        self._shown.pop(arena, None)
        self._counts.pop(arena, None)
        self._drive_counts.pop(arena, None)
        self._push_health(arena, [viewer])

    # --- recalibration ------------------------------------------------------------------
    def _recalibrate(self, viewer: Viewer, msg: Recalibrate) -> None:
        arena, token = viewer.arena, self.settings.operator_token

        def answer(state: str, message: str) -> None:
            viewer.offer(
                "recalibration", _text("recalibration", arena=arena, state=state, message=message)
            )

        if token is None:
            answer(
                "refused",
                "this view is read-only: start it with --operator-token (or "
                "OVIS_OPERATOR_TOKEN) to allow recalibration",
            )
            return
        refusal = self._viewer_token(viewer, msg.token)
        if refusal is not None:
            answer("refused", refusal)
            return
        if arena in self.recalibrating:
            answer("running", "a recalibration of this arena is already running")
            return
        running = {
            "state": "running",
            "started_ns": time.time_ns(),
            "message": "the calibrator is running the GA…",
        }
        self.recalibrating[arena] = running
        self._broadcast(arena, "recalibration", _text("recalibration", arena=arena, **running))
        request = CalibrateRequest(
            population=msg.population, generations=msg.generations, seed=msg.seed
        )
        task = asyncio.create_task(self._run_recalibration(self.bus.feed(arena), request))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _run_recalibration(self, feed: ArenaFeed, request: CalibrateRequest) -> None:
        arena, started = feed.arena, self.recalibrating[feed.arena]["started_ns"]
        try:
            reply = await asyncio.to_thread(
                feed.recalibrate, request, self.settings.recalibrate_timeout_s
            )
            result = {
                "state": "done" if reply.ok else "failed",
                "started_ns": started,
                "reply": msgspec.to_builtins(reply),
                "message": (
                    f"calibration v{reply.version} on frame {reply.frame_seq}: DIPE "
                    f"{reply.dipe_px:.3f} px = {reply.dipe_mm:.4f} mm in {reply.elapsed_s:.1f} s"
                    if reply.ok
                    else f"recalibration failed: {reply.error}"
                ),
            }
        except Exception as exc:  # the session closing, …: say so, keep serving
            result = {"state": "failed", "started_ns": started, "message": f"{exc}"}
        self.recalibrating.pop(arena, None)
        self.last_result[arena] = result
        self._broadcast(arena, "recalibration", _text("recalibration", arena=arena, **result))

    # --- the operator token -------------------------------------------------------------
    def _check_token(self, client: str, token: str) -> str | None:
        """None if ``token`` is the operator's; else why it is refused: wrong (counted
        against ``client``, who then may have to wait), or sent while it must wait (not
        even compared)."""
        expected = self.settings.operator_token
        if expected is None:
            return "this view is read-only: it has no operator token"
        wait = self.guesses.wait_s(client)
        if wait > 0:
            self._say("token", f"refused an operator token from {client}: it must wait")
            return f"too many wrong operator tokens from {client}: wait {wait:.0f} s"
        if hmac.compare_digest(token.encode(), expected.encode()):
            self.guesses.right(client)
            return None
        backoff = self.guesses.wrong(client)
        self._say("token", f"refused a wrong operator token from {client}")
        return "wrong operator token" + (f"; wait {backoff:.0f} s to try again" if backoff else "")

    def _viewer_token(self, viewer: Viewer, token: str) -> str | None:
        """:meth:`_check_token` for a seated viewer, whose refusals are counted (the
        socket is closed after ``MAX_WRONG_TOKENS``)."""
        refusal = self._check_token(viewer.client, token)
        if refusal is not None and self.settings.operator_token is not None:
            viewer.wrong_tokens += 1
        return refusal

    def _say(self, kind: str, message: str) -> None:
        """Log a refusal, at most once per ``kind`` every few seconds (with how many
        were left out): a flood of them must not fill the log."""
        left_out = self.throttle.allow(kind)
        if left_out is not None:
            more = f" ({left_out} more refusals like it since the last line)" if left_out else ""
            log.warning("%s%s", message, more)

    # --- broadcasting -------------------------------------------------------------------
    def _broadcast(self, arena: str, slot: str, data: str | bytes, kind: str | None = None) -> None:
        for v in self.viewers:
            if v.arena == arena and (kind is None or v.kind == kind):
                v.offer(slot, data)

    @staticmethod
    def _latest(feed: ArenaFeed) -> tuple[int, dict[str, Any] | None]:
        with feed.lock:
            latest = next(reversed(feed.obstacles.values()), None)
            return feed.obstacle_messages, latest

    def _push_health(self, arena: str, viewers: list[Viewer]) -> None:
        feed = self.bus.feed(arena)
        _count, latest = self._latest(feed)
        with feed.lock:
            footprint = list(feed.footprint)
            frames_seen = feed.frames_seen
            refused = dict(feed.refused)
        objects = [(o.x_cm, o.y_cm) for o in scene_objects(latest)] if latest else []
        text = _text(
            "health",
            arena=arena,
            arenas=self.bus.arenas(),
            summary=feed.health(),
            footprint=footprint,
            grid_step_cm=map_grid_step([*footprint, *objects]),
            frames_seen=frames_seen,
            refused=refused,
            viewers=sum(v.arena == arena for v in self.viewers),
            recalibration=self.recalibrating.get(arena) or self.last_result.get(arena),
        )
        for v in viewers:
            v.offer("health", text)

    async def _ticker(self) -> None:
        period = 1.0 / self.settings.max_fps
        last_health = 0.0
        loop = asyncio.get_running_loop()
        while True:
            t0 = loop.time()
            health_due = t0 - last_health >= HEALTH_PERIOD_S
            if health_due:
                last_health = t0
            try:
                await self._tick(health_due)
            except Exception as exc:  # never let one bad tick stop the view
                log.warning("view update failed: %s: %s", type(exc).__name__, exc)
            await asyncio.sleep(max(0.0, period - (loop.time() - t0)))

    async def _tick(self, health_due: bool) -> None:
        arenas: dict[str, list[Viewer]] = {}
        for v in self.viewers:
            arenas.setdefault(v.arena, []).append(v)
        s = self.settings
        for arena, viewers in arenas.items():
            feed = self.bus.feed(arena)
            kinds = {v.kind for v in viewers} & set(KINDS)
            shown = self._shown.setdefault(arena, {})
            pictures = await asyncio.to_thread(
                make_pictures, feed, kinds, s.max_side, s.jpeg_quality, shown
            )
            for picture in pictures:
                self._broadcast(arena, "picture", pack_picture(picture), kind=picture.kind)
            count, latest = self._latest(feed)
            if latest is not None and count != self._counts.get(arena):
                self._counts[arena] = count
                self._broadcast(
                    arena,
                    "obstacles",
                    _text("obstacles", arena=arena, received=count, message=latest),
                )
            self._push_robots(feed, health_due)
            if health_due:
                self._push_health(arena, viewers)

    def _push_robots(self, feed: ArenaFeed, due: bool) -> None:
        """The driven robots' goals, commands and world trails: on every new command or
        drive report, and with the health (a command turns stale with no new message)."""
        count, robots = feed.robots_shown()
        if robots and (due or count != self._drive_counts.get(feed.arena)):
            self._drive_counts[feed.arena] = count
            text = _text("robots", arena=feed.arena, received=count, robots=robots)
            self._broadcast(feed.arena, "robots", text)


def _client(connection: Request | WebSocket) -> str:
    """The remote address of a request or socket."""
    return connection.client.host if connection.client is not None else "unknown"


def _auth_token(text: str | None) -> str | None:
    """The token of an ``auth`` message, or None (not one)."""
    if text is None or len(text) > MAX_MESSAGE:
        return None
    try:
        msg = _incoming.decode(text)
    except (msgspec.DecodeError, msgspec.ValidationError):
        return None
    return msg.token if isinstance(msg, Auth) else None


def bind(host: str, port: int) -> socket.socket:
    """A listening socket on host:port; OSError (e.g. the port is taken) as ValueError
    saying what to do."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise ValueError(
            f"cannot listen on {host}:{port}: {exc.strerror or exc}; choose another "
            "address or port with --listen"
        ) from None
    sock.listen(128)
    sock.set_inheritable(True)
    return sock


def url_of(sock: socket.socket) -> str:
    host, port = sock.getsockname()[:2]
    return f"http://[{host}]:{port}/" if ":" in host else f"http://{host}:{port}/"


def serve(bus: Bus, settings: ViewSettings, sock: socket.socket) -> None:
    """Serve the page on ``sock`` until SIGINT/SIGTERM (uvicorn handles both)."""
    host, port = sock.getsockname()[:2]
    origins = OriginPolicy(host, port, settings.allow_origins)
    config = uvicorn.Config(
        ViewServer(bus, settings, origins).app(),
        log_level="warning",
        ws="websockets-sansio",
        ws_max_size=MAX_MESSAGE * 4,
        lifespan="on",
    )
    logging.getLogger("uvicorn.error").addFilter(_no_denial_noise)  # after its set-up
    uvicorn.Server(config).run(sockets=[sock])


def _no_denial_noise(record: logging.LogRecord) -> bool:
    """uvicorn logs "ASGI callable returned without completing handshake" after every
    refused WebSocket (it does not count a denial response as one): a line per refusal,
    unthrottled. The view logs its refusals itself (``ViewServer._say``)."""
    return "without completing handshake" not in record.getMessage()
