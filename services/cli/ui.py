"""What every command shows the same way: the console, JSON on stdout, and progress
bars for long work (on stderr, so that stdout stays clean for --json)."""

from __future__ import annotations

import sys
from collections.abc import Callable, Collection, Iterable, Iterator
from contextlib import contextmanager
from pathlib import PurePath
from typing import Any

import msgspec

__all__ = [
    "NOT_MEASURED",
    "calibrate_with_progress",
    "console",
    "emit_json",
    "progress",
    "table",
    "velocity_text",
]

#: Shown for a number the system has not measured (a velocity before a second frame).
NOT_MEASURED = "–"


def console():
    """The console commands print to (stdout, no highlighting of numbers)."""
    from rich.console import Console

    return Console(highlight=False)


def table(title: str, columns: Iterable[str], *, left: Collection[str] = ()):
    """A table titled on the left; numbers (every column not in ``left``) on the right."""
    from rich.table import Table

    t = Table(title=title, title_justify="left")
    for col in columns:
        t.add_column(col, justify="left" if col in left else "right")
    return t


def _path_as_text(obj: Any) -> Any:
    if isinstance(obj, PurePath):
        return str(obj)
    raise NotImplementedError(f"cannot write {type(obj).__name__} as JSON")


def emit_json(data: Any) -> None:
    """``data`` (Structs, dicts, lists; paths as text) as indented JSON on stdout."""
    text = msgspec.json.encode(data, enc_hook=_path_as_text)
    sys.stdout.write(msgspec.json.format(text, indent=2).decode() + "\n")


@contextmanager
def progress(what: str, *, show: bool = True) -> Iterator[Callable[[int, int, str], None]]:
    """A progress bar on stderr for ``what``; yields ``update(done, total, label)`` (which
    does nothing when not ``show``)."""
    if not show:
        yield lambda done, total, label: None
        return
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    bar = Progress(
        TextColumn(f"[bold]{what}[/]"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[label]}"),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
        console=Console(stderr=True, highlight=False),
    )
    with bar:
        task = bar.add_task(what, total=None, label="")

        def update(done: int, total: int, label: str) -> None:
            bar.update(task, completed=done, total=total, label=label)

        yield update


def calibrate_with_progress(frame, points, cfg, *, source: str, show: bool = True, con=None):
    """Run the GA calibration, with a progress bar showing the best DIPE so far."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from ovis.common.calibration.calibrate import calibrate as run_calibration

    if not show:
        return run_calibration(frame, points, cfg, source=source)[0]
    bar = Progress(
        TextColumn("[bold]GA[/]"),
        BarColumn(),
        TextColumn("gen {task.completed}/{task.total}"),
        TextColumn("best DIPE {task.fields[best]}"),
        TimeElapsedColumn(),
        console=con or console(),
    )
    task = bar.add_task("ga", total=cfg.ga.generations, best="-")

    def on_generation(stats) -> None:
        best = f"{stats.best_so_far:.3f} px" if stats.best_so_far < 1e6 else "infeasible"
        bar.update(task, completed=stats.generation, best=best)

    with bar:
        return run_calibration(frame, points, cfg, on_generation=on_generation, source=source)[0]


def velocity_text(obj: Any) -> str:
    """An object's or robot's velocity as "(vx, vy)" cm/s, or :data:`NOT_MEASURED` before
    it is measured (``velocity_measured`` false: seen in one frame only)."""
    if not getattr(obj, "velocity_measured", False):
        return NOT_MEASURED
    return f"({obj.vx_cm_s:+.1f}, {obj.vy_cm_s:+.1f})"
