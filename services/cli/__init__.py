"""The `ovis` command line (typer).

Every command parses its arguments and calls into :mod:`ovis.common`; failures the user
can fix (bad files, bad values, an infeasible calibration) end with a one-line
``error: …`` on stderr and a non-zero exit, never a traceback (set ``OVIS_DEBUG=1`` to
see one).
"""

from __future__ import annotations

import os
import signal
import sys


def _quit_quietly(signum: int, _frame: object) -> None:
    raise SystemExit(128 + signum)


# Ctrl-C while the commands load ends the process quietly (no traceback); each command
# then has Python's own handler back (see main), or installs its own.
if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
    signal.signal(signal.SIGINT, _quit_quietly)

import typer  # noqa: E402

from ovis.services.cli.errors import UserError  # noqa: E402

app = typer.Typer(
    name="ovis",
    help=(
        "Overhead-camera vision for mobile robots: calibrate a camera with a genetic "
        "algorithm, find the robot and the obstacles in each frame, and compute the "
        "motion planner's inputs. Start with `ovis simulate`, then `ovis calibrate` and "
        "`ovis detect` on what it wrote."
    ),
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
    add_completion=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)

# One module per command group; each registers its commands.
from ovis.services.cli import (  # noqa: E402
    analysis,
    camera,
    cameras,
    export,
    launcher,
    navigate,
    offline,
    recording,
    view,
)

offline.register(app)
launcher.register(app)
analysis.register(app)
export.register(app)
view.register(app)
recording.register(app)
camera.register(app)
cameras.register(app)
navigate.register(app)


def main() -> None:
    """Console entry point: run the app and turn known failures into one-line errors."""
    from ovis.common.calibration.errors import InfeasibleCalibrationError
    from ovis.common.calibration.file import CalibrationFileError
    from ovis.common.config import ConfigError
    from ovis.common.vision.frames import ImageError
    from ovis.services.bus import ZenohUnreachableError
    from ovis.services.memory import guard_memory

    guard_memory()  # before Zenoh's threads start: frames are allocated per message
    if signal.getsignal(signal.SIGINT) is _quit_quietly:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        app()  # click itself handles usage errors, --help and Ctrl-C, then exits
    except UserError as exc:
        _fail(str(exc), exc.exit_code)
    except (ConfigError, CalibrationFileError, ImageError) as exc:
        _fail(str(exc), 2)
    except ZenohUnreachableError as exc:
        _fail(str(exc), 4)
    except InfeasibleCalibrationError as exc:
        _fail(f"calibration failed: {exc}", 3)
    except Exception as exc:  # last line of defence: one line, not a traceback
        if os.environ.get("OVIS_DEBUG"):
            raise
        _fail(f"{type(exc).__name__}: {exc} (set OVIS_DEBUG=1 for a traceback)", 1)


def _fail(message: str, code: int) -> None:
    print(f"error: {message}", file=sys.stderr)
    sys.exit(code)
