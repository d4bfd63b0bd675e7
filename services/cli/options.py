"""What the `ovis` commands share: their common options (configuration, connection,
arena, JSON), the configuration with the command line laid over it, the arena's topics,
and a clean stop on Ctrl-C/SIGTERM. Every command module takes these from here, so no
command module imports another's internals."""

from __future__ import annotations

import signal
import threading
from pathlib import Path
from typing import Annotated, Any

import typer

from ovis.services.cli.errors import UserError

__all__ = [
    "DEFAULT_ENDPOINT",
    "STARTUP_S",
    "ArenaOpt",
    "ConfigOpt",
    "ConnectOpt",
    "JsonOpt",
    "OfflineConfigOpt",
    "PaperPresetOpt",
    "PresetOpt",
    "SummaryJsonOpt",
    "arena_topics",
    "config_with_options",
    "stop_on_signals",
]

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
#: `ovis up` starts the capture once the other stages are alive, or after this long.
STARTUP_S = 30.0

JsonOpt = Annotated[bool, typer.Option("--json", help="Print machine-readable JSON.")]
PaperPresetOpt = Annotated[str, typer.Option(help="'default' (640x480) or 'paper' (192x192).")]
SummaryJsonOpt = Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")]
ConfigOpt = Annotated[
    Path | None,
    typer.Option("--config", "-c", help="TOML configuration (ovis config show).", dir_okay=False),
]
OfflineConfigOpt = Annotated[
    Path | None,
    typer.Option(
        "--config",
        "-c",
        help="TOML configuration (may name a preset and override any of its fields).",
        dir_okay=False,
    ),
]
PresetOpt = Annotated[
    str | None,
    typer.Option(
        help="Built-in preset when no --config is given: 'default', 'paper' or 'pinhole'."
    ),
]
ConnectOpt = Annotated[
    list[str] | None,
    typer.Option(help=f"Zenoh endpoint to connect to (repeatable); default {DEFAULT_ENDPOINT}."),
]
ArenaOpt = Annotated[
    str | None, typer.Option(help="Arena name: key expressions are rooted at ovis/<arena>/.")
]


def config_with_options(config: Path | None, **options: Any):
    """The configuration with command-line options laid over it (and validated)."""
    from ovis.common.config import with_options

    return with_options(config, **options)


def arena_topics(cfg):
    """The configured arena's topics, or a usage error naming what is wrong."""
    from ovis.common.messages import Topics

    try:
        return Topics(cfg.service.arena)
    except ValueError as exc:
        raise UserError(str(exc)) from None


def stop_on_signals() -> threading.Event:
    """An event that Ctrl-C or SIGTERM sets: the command then stops cleanly."""
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    return stop
