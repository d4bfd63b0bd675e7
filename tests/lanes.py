"""A pytest plugin: the suite runs on two workers (pytest-xdist, ``-n``) without one
test file's load falsifying another's timing.

Most test files compute (calibrations, renders, detection on photos) or run live
pipelines whose checks allow a busy host. A few assert what a neighbour's CPU use would
falsify: a stage back within 1.5 s, a robot stopped within 0.3 s, a timeout kept to a
tenth of a second, a latency percentile. Those files carry
``pytestmark = pytest.mark.alone``: no other ``alone`` file runs beside one, and every
other file runs at a lower CPU priority (:data:`SHARED_NICE`, inherited by the
processes it starts), so an ``alone`` file's processes have the CPU when they want it
and a neighbour only what they leave; the others run two at once, at the same priority.

Under ``--dist loadfile`` the ``alone`` files are one unit of work
(:func:`pytest_xdist_make_scheduler`): one worker runs them one after another while the
other runs the rest, giving way. They are collected first, then the ``long`` ones (and
xdist keeps that order: ``--no-loadscope-reorder``), so a worker runs its ``alone``
files before it lowers its priority for the others (a process may lower its own
priority, not raise it again). Where ``alone`` files do meet on two workers (another
``--dist``), a worker that gives back an ``alone`` lane waits :data:`HANDOVER_S` before
it takes the next, so the other worker's waiting ``alone`` file has its turn.

An ``alone`` file holds its lane for its whole run (a module-scoped fixture, set up
before the module's own fixtures start their services): ``flock`` on a file in the
temporary folder named after the xdist run; without xdist (one process) nothing is
locked or lowered. A file that waits :data:`WAIT_S` runs without its lane, with a
warning: the run never hangs on a lane.

No ovis import: a test file that must not import ovis (test_adversarial.py) runs under it.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import tempfile
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import pytest

__all__ = ["ALONE", "LONG", "SHARED_NICE", "alone_files", "give_way", "lane"]

#: The marker of a test file that runs with no other test file beside it.
ALONE = "alone"
#: The marker of a test file that runs for minutes: it starts before the short ones, so
#: the run does not end with one worker busy on it and the other idle.
LONG = "long"


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        f"{ALONE}: this test file asserts timing a neighbour's CPU use would falsify; "
        "with several workers (-n) it runs with no other test file beside it",
    )
    config.addinivalue_line(
        "markers", f"{LONG}: this test file runs for minutes; it starts before the short ones"
    )


#: How long a worker that gave back an ``alone`` lane lets the other worker take one
#: before it tries again (several of :data:`POLL_S`).
HANDOVER_S = 0.5
#: How often a waiting file tries for its lane.
POLL_S = 0.1


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The ``alone`` files' tests first, then the ``long`` files', then the rest; each
    file's tests in their order."""
    items.sort(
        key=lambda item: (
            item.get_closest_marker(ALONE) is None,
            item.get_closest_marker(LONG) is None,
        )
    )


#: How long a file waits for its lane before it runs anyway (said on the terminal): no
#: file of the suite runs this long, so only a lane never given back (a worker stopped
#: with a file open) makes a file wait it out; the run goes on instead of hanging.
WAIT_S = 420.0


#: The CPU priority (nice) of a worker once it runs files that are not ``alone``: a
#: tenth of the CPU an ``alone`` file's processes would have when both want it.
SHARED_NICE = 10


def give_way() -> None:
    """Lower this process's CPU priority to :data:`SHARED_NICE` (never raise it)."""
    now = os.getpriority(os.PRIO_PROCESS, 0)
    if now < SHARED_NICE:
        os.setpriority(os.PRIO_PROCESS, 0, SHARED_NICE)


def _take(f: IO[str], deadline: float) -> bool:
    """flock ``f`` exclusively by ``deadline`` (monotonic s)."""
    while True:
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            if time.monotonic() >= deadline:
                return False
            time.sleep(POLL_S)


@contextlib.contextmanager
def lane(folder: Path, *, wait_s: float = WAIT_S) -> Iterator[bool]:
    """Hold the ``alone`` lane of the run whose lock file is in ``folder``; yields False
    when it was not had within ``wait_s`` (the file runs without it)."""
    folder.mkdir(parents=True, exist_ok=True)
    with (folder / "alone").open("a") as lock:
        had = _take(lock, time.monotonic() + wait_s)
        try:
            yield had
        finally:
            if had:
                fcntl.flock(lock, fcntl.LOCK_UN)
                time.sleep(HANDOVER_S)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_protocol(item: pytest.Item) -> None:
    """Before a test of a file that is not ``alone`` starts (its fixtures too): give way."""
    if os.environ.get("PYTEST_XDIST_TESTRUNUID") and item.get_closest_marker(ALONE) is None:
        give_way()


def alone_files(root: Path) -> frozenset[str]:
    """The test files under ``root`` that say they run alone (their source's
    ``pytestmark`` line: the scheduler runs before any file is imported)."""
    return frozenset(
        f"{root.name}/{path.name}"
        for path in root.glob("test_*.py")
        if re.search(r"^pytestmark = .*pytest\.mark\.alone", path.read_text(), re.M)
    )


def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object | None:
    """Under ``--dist loadfile``: every ``alone`` file in one unit of work, so one worker
    runs them one after another while the other runs the rest, giving way."""
    if config.getoption("dist", None) != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    alone = alone_files(Path(__file__).parent)

    class AloneOnOneWorker(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            path = nodeid.split("::", 1)[0]
            return "alone files" if path in alone else path

    return AloneOnOneWorker(config, log)


@pytest.fixture(autouse=True, scope="module")
def _lane(request: pytest.FixtureRequest) -> Iterator[None]:
    """An ``alone`` module's lane, held from before its fixtures start to after they stop."""
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    if run is None or request.node.get_closest_marker(ALONE) is None:
        yield
        return
    with lane(Path(tempfile.gettempdir()) / f"ovis-test-lanes-{run}") as had:
        if not had:  # shown in the run's warnings summary
            warnings.warn(f"no lane within {WAIT_S:.0f} s: ran beside another file", stacklevel=1)
        yield
