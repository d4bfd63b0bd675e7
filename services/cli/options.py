"""What the `ovis` commands share: their common options (configuration, connection,
arena, JSON), the configuration with the command line laid over it, the arena's topics,
and a clean stop on Ctrl-C/SIGTERM. Every command module takes these from here, so no
command module imports another's internals."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import Annotated, Any

import typer

from ovis.services.cli.errors import UserError
from ovis.services.stopping import Stop, stop_on

__all__ = [
    "CONNECT_S",
    "DEFAULT_ENDPOINT",
    "STARTUP_S",
    "ArenaOpt",
    "ConfigOpt",
    "ConnectOpt",
    "ConnectTimeoutOpt",
    "JsonOpt",
    "OfflineConfigOpt",
    "PaperPresetOpt",
    "PresetOpt",
    "SummaryJsonOpt",
    "TrustOpt",
    "WorldOpt",
    "arena_topics",
    "config_with_options",
    "stop_on_signals",
    "time_left",
    "with_trust",
]

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
#: `ovis up` starts the capture once the other stages are alive, or after this long.
STARTUP_S = 30.0
#: Seconds a client command (watch, status, recalibrate) waits for a router to answer.
CONNECT_S = 5.0


def _process_age_s() -> float:
    """Seconds since this process started (Linux: /proc; elsewhere 0)."""
    try:
        with open("/proc/self/stat", encoding="ascii") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        started = int(fields[19]) / os.sysconf("SC_CLK_TCK")
        return max(0.0, time.clock_gettime(time.CLOCK_BOOTTIME) - started)
    except (OSError, ValueError, IndexError, AttributeError):
        return 0.0


#: When the process started (monotonic clock): a client's --timeout counts from here.
STARTED = time.monotonic() - _process_age_s()
#: Of a client's --timeout, what is kept to say why it gives up and exit.
EXIT_MARGIN_S = 0.5

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
        help="Built-in preset when no --config is given: 'default', 'paper', 'pinhole' or "
        "'physical'."
    ),
]
ConnectOpt = Annotated[
    list[str] | None,
    typer.Option(help=f"Zenoh endpoint to connect to (repeatable); default {DEFAULT_ENDPOINT}."),
]
ConnectTimeoutOpt = Annotated[
    float,
    typer.Option(
        "--timeout",
        min=0.1,
        help="Seconds to wait for a router to answer; then exit code 4 with the reason.",
    ),
]
TrustOpt = Annotated[
    Path | None,
    typer.Option(
        "--trust",
        help="The pose stage's public key file (PEM), or a folder with pose.pub and "
        "calibrator.pub: only what it signed is shown. Default: [trust] in --config, "
        "else <state_dir>/keys/ (ovis-state/keys/, where `ovis up` makes them); copy "
        "pose.pub from the pose stage's host to watch from another (docs/trust.md).",
    ),
]
WorldOpt = Annotated[
    str | None,
    typer.Option(
        help="The simulated world: 'light' (flat top faces painted, fast) or 'physical' "
        "(solid objects rendered by MuJoCo; the `physical` preset unless --config says "
        "otherwise; docs/physical.md). Default: [simulator] world of the configuration.",
    ),
]
ArenaOpt = Annotated[
    str | None, typer.Option(help="Arena name: key expressions are rooted at ovis/<arena>/.")
]


def config_with_options(config: Path | None, **options: Any):
    """The configuration with command-line options laid over it (and validated)."""
    from ovis.common.config import with_options

    return with_options(config, **options)


def with_trust(cfg, trust: Path | None):
    """The configuration with ``--trust`` laid over its ``[trust]``: a folder gives every
    role's public key (``<role>.pub``), a file the pose stage's."""
    import msgspec

    from ovis.common.trust.keys import ROLES

    if trust is None:
        return cfg
    if trust.is_dir():
        keys = {f"{role}_public": str(trust / f"{role}.pub") for role in ROLES}
    else:
        keys = {"pose_public": str(trust)}
    return msgspec.structs.replace(cfg, trust=msgspec.structs.replace(cfg.trust, **keys))


def arena_topics(cfg):
    """The configured arena's topics, or a usage error naming what is wrong."""
    from ovis.common.messages import Topics

    try:
        return Topics(cfg.service.arena)
    except ValueError as exc:
        raise UserError(str(exc)) from None


def stop_on_signals() -> Stop:
    """An event that Ctrl-C or SIGTERM sets: the command then stops cleanly."""
    return stop_on(signal.SIGTERM, signal.SIGINT)


def time_left(timeout_s: float) -> float:
    """What is left of ``timeout_s`` counted from the process's start, less
    :data:`EXIT_MARGIN_S` (at least a tenth of a second): a client gives up within its
    --timeout, start-up and exit included."""
    return max(0.1, timeout_s - (time.monotonic() - STARTED) - EXIT_MARGIN_S)
