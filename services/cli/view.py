"""`ovis view`: the live web view (a page that shows the frame with what was detected,
the arena from above and the health of every stage)."""

from __future__ import annotations

import logging
import os
import sys
from typing import Annotated

import typer

from ovis.services.cli.errors import UserError
from ovis.services.cli.options import ConfigOpt, ConnectOpt, TrustOpt

__all__ = ["DEFAULT_LISTEN", "register", "view"]

DEFAULT_LISTEN = "127.0.0.1:8080"


def view(
    listen: Annotated[
        str,
        typer.Option(
            envvar="OVIS_VIEW_LISTEN",
            help="HOST:PORT to serve the page on (port 0: any free port). Use 0.0.0.0:PORT "
            "to let other machines see it.",
        ),
    ] = DEFAULT_LISTEN,
    arena: Annotated[
        list[str] | None,
        typer.Option(
            help="Arena to show (repeatable: the page gets a selector). Default: the "
            "configured arena, and every arena found alive on the bus."
        ),
    ] = None,
    connect: ConnectOpt = None,
    config: ConfigOpt = None,
    max_fps: Annotated[
        float, typer.Option(help="Pictures per second sent to each browser, at most (≤ 30).")
    ] = 10.0,
    max_side: Annotated[
        int, typer.Option(help="Longer side of the pictures, pixels (frames are only shrunk).")
    ] = 640,
    quality: Annotated[int, typer.Option(help="JPEG quality, 10-100.")] = 80,
    max_clients: Annotated[
        int, typer.Option(help="Browsers served at once; more are asked to come back later.")
    ] = 32,
    max_clients_per_address: Annotated[
        int,
        typer.Option(
            help="Browsers served at once from one address (the operator's token gets in "
            "beyond this and --max-clients)."
        ),
    ] = 8,
    operator_token: Annotated[
        str | None,
        typer.Option(
            envvar="OVIS_OPERATOR_TOKEN",
            help="Secret that lets the page recalibrate: the button appears and asks for "
            "it, and the server checks it on every request (wrong ones are slowed down, "
            "per client). 'auto' makes a random one and prints the page's URL with it. "
            "Refused if worth under 128 bits (e.g. 22 random letters and digits). Without "
            "it the page is read-only. Prefer the environment variable (not in `ps`).",
            show_default=False,
        ),
    ] = None,
    allow_origin: Annotated[
        list[str] | None,
        typer.Option(
            help="Another origin whose pages may use the view's WebSocket and API, e.g. "
            "https://ovis.example.org behind a proxy (repeatable). Default: only the "
            "view's own pages."
        ),
    ] = None,
    nice: Annotated[
        int,
        typer.Option(
            min=0,
            max=19,
            help="Lower this process's CPU priority by this much, so that on a busy machine "
            "the frame path (capture → pose) wins over drawing pictures.",
        ),
    ] = 10,
    cpus: Annotated[
        str | None,
        typer.Option(
            help="Cores to run on, e.g. '0' (`ovis up --view` keeps it off the frame path's "
            "cores); default any."
        ),
    ] = None,
    trust: TrustOpt = None,
) -> None:
    """Serve a live web page of what ovis sees: the camera frame with blobs, ids, robot
    headings and control points drawn on it (or the binarised frame), the arena from
    above in cm (objects, planner lines, the camera's footprint), the health of every
    stage (alive, frames/s, latency p50/p99, drops, errors, last calibration) and, with
    --operator-token, a recalibration button.

    It joins the bus like any subscriber (it may run on a laptop far from the cameras)
    and takes frames from the bus only while a browser watches, so the frame path does
    not pay for it. Obstacles and health are shown only with the pose stage's proof of
    origin, calibrations with the calibrator's (--trust); the others are dropped and the
    health panel counts them. Stop it with Ctrl-C.
    """
    from ovis.common.messages import Topics
    from ovis.common.view.guard import new_token
    from ovis.common.view.settings import parse_listen, view_settings
    from ovis.services.bus import open_session
    from ovis.services.cli.options import config_with_options, with_trust
    from ovis.services.view.feed import Bus
    from ovis.services.view.server import bind, serve, url_of

    made_token = operator_token == "auto"
    if made_token:
        operator_token = new_token()
    try:
        host, port = parse_listen(listen)
        cfg = with_trust(config_with_options(config, connect=connect), trust)
        arenas = list(arena or [cfg.service.arena])
        for name in arenas:
            Topics(name)  # a bad name is refused here
        settings = view_settings(
            host=host,
            port=port,
            arenas=list(arena or []),
            discover=not arena,
            max_fps=max_fps,
            max_side=max_side,
            jpeg_quality=quality,
            max_clients=max_clients,
            operator_token=operator_token or None,
            max_clients_per_address=max_clients_per_address,
            allow_origins=list(allow_origin or []),
        )
        sock = bind(host, port)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    logging.basicConfig(
        level=os.environ.get("OVIS_LOG", "INFO").upper(),
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    give_way(nice, cpus)
    with open_session(cfg.zenoh) as session:
        bus = Bus(session, arenas, discover=settings.discover, config=cfg)
        mode = (
            "operator mode: the page asks for the token to recalibrate"
            if settings.operator_token
            else "read-only"
        )
        print(
            f"ovis view: {url_of(sock)} (arena {', '.join(arenas)}; {mode}; up to "
            f"{settings.max_fps:g} pictures/s per browser)",
            flush=True,
        )
        if made_token:
            print(f"ovis view: operator page {url_of(sock)}#token={operator_token}", flush=True)
        try:
            serve(bus, settings, sock)
        finally:
            bus.close()
    sys.stdout.flush()


def register(app: typer.Typer) -> None:
    app.command()(view)


def give_way(nice: int, cpus: str | None) -> None:
    """Keep the view out of the frame path's way: a lower CPU priority and, if given,
    other cores (before Zenoh and uvicorn start their threads, which inherit both)."""
    from ovis.services.placement import pick_cpus, pin_to_cpus

    log = logging.getLogger("ovis.view")
    if nice:
        try:
            os.nice(nice)
        except OSError as exc:
            log.warning("cannot lower the view's priority (%s): running at normal priority", exc)
    if cpus:
        try:
            pin_to_cpus(pick_cpus(cpus), log)
        except ValueError as exc:
            raise UserError(str(exc)) from None
