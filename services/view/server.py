"""The view's web server: one page (``static/``) and a WebSocket (``/ws``) that pushes
each browser the pictures, obstacles and health of the arena it watches.

Every browser has one slot per kind of update (picture, obstacles, health, …): a newer
update replaces one not yet sent, so a slow browser gets fewer pictures, never a
growing queue. Pictures are made once per tick for all browsers of an arena, at most
``max_fps`` a second, and only while someone watches. What a browser sends is parsed
into a few known messages; anything else gets an error message back (and after
``MAX_BAD`` of them the connection is closed). Recalibration needs the operator token
(compared in constant time) on every request.
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
from starlette.responses import HTMLResponse, JSONResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect

from ovis.common.messages import CalibrateRequest, Topics
from ovis.common.view.grid import map_grid_step
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


_incoming = msgspec.json.Decoder(Select | Show | Recalibrate)


def pack_picture(picture: Picture) -> bytes:
    """A binary WebSocket message: 4-byte big-endian header length, the JSON header
    (the picture's fields but the JPEG), the JPEG."""
    header = _json.encode(msgspec.structs.replace(picture, jpeg=b""))
    return struct.pack(">I", len(header)) + header + picture.jpeg


class Viewer:
    """One browser: the arena it watches, the picture it wants, its pending updates."""

    def __init__(self, ws: WebSocket, arena: str) -> None:
        self.ws = ws
        self.arena = arena
        self.kind = "camera"
        self.slots: dict[str, str | bytes] = {}
        self.wake = asyncio.Event()
        self.bad = 0
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

    def __init__(self, bus: Bus, settings: ViewSettings) -> None:
        self.bus = bus
        self.settings = settings
        self.viewers: set[Viewer] = set()
        self.recalibrating: dict[str, dict[str, Any]] = {}
        self.last_result: dict[str, dict[str, Any]] = {}
        self._shown: dict[str, dict[str, int]] = {}
        self._counts: dict[str, int] = {}
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

    async def _state(self, _request: Request) -> Response:
        """Everything the page shows but the pictures, as JSON (for scripts)."""
        out = {}
        for arena in self.bus.arenas():
            feed = self.bus.feed(arena)
            count, latest = self._latest(feed)
            out[arena] = {
                "health": msgspec.to_builtins(feed.health()),
                "obstacle_messages": count,
                "obstacles": latest,
            }
        return JSONResponse({"arenas": out, "viewers": len(self.viewers)})

    def default_arena(self) -> str:
        if self.settings.arenas:
            return self.settings.arenas[0]
        arenas = self.bus.arenas()
        return "default" if not arenas or "default" in arenas else arenas[0]

    # --- one browser --------------------------------------------------------------------
    async def _socket(self, ws: WebSocket) -> None:
        await ws.accept()
        if len(self.viewers) >= self.settings.max_clients:
            await ws.send_text(
                _text(
                    "error",
                    fatal=True,
                    message=f"too many viewers ({self.settings.max_clients}, the view's "
                    "--max-clients): close another view of ovis or try again later",
                )
            )
            await ws.close(code=1013)
            return
        viewer = Viewer(ws, self.default_arena())
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
                if viewer.bad >= MAX_BAD:
                    await ws.send_text(
                        _text("error", fatal=True, message=f"{MAX_BAD} bad messages: disconnected")
                    )
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
        if not hmac.compare_digest(msg.token.encode(), token.encode()):
            log.warning("refused a recalibration with a wrong operator token")
            answer("refused", "wrong operator token")
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
            if health_due:
                self._push_health(arena, viewers)


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
    config = uvicorn.Config(
        ViewServer(bus, settings).app(),
        log_level="warning",
        ws="websockets-sansio",
        ws_max_size=MAX_MESSAGE * 4,
        lifespan="on",
    )
    uvicorn.Server(config).run(sockets=[sock])
