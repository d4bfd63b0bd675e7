"""A pytest plugin that fails the test which leaves something behind for the next one.

Integration tests start routers, services and Zenoh sessions; one that leaves a process
running, a session open, a thread running, a port listening or the test process changed
(its cores, priority, environment, working directory, signal handling) slows or breaks
the tests that run after it, far from the cause. After every test, and after every
module (for module-scoped fixtures), this plugin compares them with what was there
before; it fails the test (an error at its teardown) naming what was left, and undoes
what it can (kills the processes, closes the sessions, restores the process) so that
one leak does not spread to the rest of the run. Processes and threads still exiting
get :data:`GRACE_S`, and the next test starts only once they are gone.

The processes of this run are the pytest process's descendants and, for those whose
parent died (orphans, adopted by init), every process whose environment carries
:data:`MARKER` with this pytest's pid: children inherit it.

No ovis import: a test file that must not import ovis (test_adversarial.py) runs under it.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import pytest
import zenoh

__all__ = ["GRACE_S", "HANDS_OVER", "MARKER", "Proc", "Snapshot", "leaks", "processes", "snapshot"]

#: Environment variable that marks every process started by this pytest run.
MARKER = "OVIS_TEST_RUN"
#: How long a test's processes and threads get, after its teardown, to finish exiting.
GRACE_S = 5.0
#: Set by pytest itself while a test runs.
_PYTEST_ENV = {"PYTEST_CURRENT_TEST"}
#: Libraries that change the environment when first imported (OpenCV sets
#: LD_LIBRARY_PATH): imported before the first test, so that no test is blamed for it.
_IMPORTED_FIRST = ("cv2",)
_HANDLED = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGPIPE, signal.SIGCHLD)

_sessions: list[zenoh.Session] = []  # every session opened in this process, while open
_said: set[object] = set()  # threads and ports already named (left to their owner)
_real_open: Callable[..., zenoh.Session] = zenoh.open


@dataclass(frozen=True)
class Proc:
    """One live process: pid and start time (together unique), parent, command line."""

    pid: int
    start: int
    ppid: int = field(compare=False)
    cmd: str = field(compare=False)

    def __str__(self) -> str:
        parent = "orphan, adopted by pid 1" if self.ppid == 1 else f"parent {self.ppid}"
        return f"pid {self.pid} ({parent}): {self.cmd[:200]}"


@dataclass
class Snapshot:
    """What a test could leave behind, at one moment."""

    procs: dict[int, Proc]
    threads: set[threading.Thread]
    sessions: set[int]
    ports: set[int]
    affinity: set[str]
    cores: set[int]
    nice: int
    env: dict[str, str]
    cwd: str
    handlers: dict[signal.Signals, Any]
    ignored: frozenset[int]
    blocked: frozenset[int]


def snapshot() -> Snapshot:
    return Snapshot(
        procs=processes(),
        threads=_threads(),
        sessions={id(s) for s in _sessions},
        ports=_listening_ports(),
        affinity=_affinities(),
        cores=os.sched_getaffinity(0),
        nice=os.getpriority(os.PRIO_PROCESS, 0),
        env={k: v for k, v in os.environ.items() if k not in _PYTEST_ENV},
        cwd=os.getcwd(),
        handlers={s: signal.getsignal(s) for s in _HANDLED},
        ignored=_signal_mask("SigIgn"),
        blocked=_signal_mask("SigBlk"),
    )


def _read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError:
        return b""


def _read_dir(path: Path) -> list[Path]:
    try:
        return list(path.iterdir())
    except OSError:
        return []


def processes(root: int | None = None) -> dict[int, Proc]:
    """The live (not zombie) processes of this run: descendants of ``root`` (this
    process) and processes started since it that carry :data:`MARKER` = ``root``."""
    root = os.getpid() if root is None else root
    every: dict[int, Proc] = {}
    for entry in _read_dir(Path("/proc")):
        if entry.name.isdigit():
            fields = _read(entry / "stat").decode(errors="replace").rpartition(")")[2].split()
            if len(fields) > 19 and fields[0] not in "ZX":  # not gone, nor a zombie
                every[int(entry.name)] = Proc(int(entry.name), int(fields[19]), int(fields[1]), "")
    born = every[root].start if root in every else 0
    ours = {
        pid: p
        for pid, p in every.items()
        if pid != root
        and (
            _under(p, {root}, every)
            or (p.start >= born and root in _marks(_read(Path(f"/proc/{pid}/environ"))))
        )
    }
    return {pid: replace(p, cmd=_cmdline(pid)) for pid, p in ours.items()}


def _cmdline(pid: int) -> str:
    raw = _read(Path(f"/proc/{pid}/cmdline"))
    return raw.replace(b"\0", b" ").decode(errors="replace").strip()


def _marks(environ: bytes) -> set[int]:
    """The pytest runs (pids) a process was started by, from its environment."""
    for entry in environ.split(b"\0"):
        if entry.startswith(MARKER.encode() + b"="):
            return {int(p) for p in entry.split(b"=", 1)[1].split(b",") if p.isdigit()}
    return set()


def _under(proc: Proc, owners: set[int], procs: dict[int, Proc]) -> bool:
    """Whether ``proc`` descends from one of ``owners`` (or is one)."""
    seen: set[int] = set()
    while proc.pid not in seen:
        if proc.pid in owners or proc.ppid in owners:
            return True
        seen.add(proc.pid)
        parent = procs.get(proc.ppid)
        if parent is None:
            return False
        proc = parent
    return False


def _threads() -> set[threading.Thread]:
    # A _DummyThread is a thread Python did not start (Zenoh's, calling back into Python).
    return {
        t
        for t in threading.enumerate()
        if t.is_alive() and not isinstance(t, threading._DummyThread)
    }


def _affinities() -> set[str]:
    """The cores each thread of this process may run on."""
    masks = set()
    for task in _read_dir(Path("/proc/self/task")):
        for line in _read(task / "status").decode(errors="replace").splitlines():
            if line.startswith("Cpus_allowed_list:"):
                masks.add(line.split(":", 1)[1].strip())
    return masks


def _signal_mask(field: str) -> frozenset[int]:
    """The signals the kernel ignores or blocks for this process's main thread (what a
    child inherits), whoever set them: Python or a native library."""
    for line in _read(Path("/proc/self/status")).decode().splitlines():
        if line.startswith(field + ":"):
            mask = int(line.split()[1], 16)
            return frozenset(n for n in range(1, 65) if mask >> (n - 1) & 1)
    return frozenset()


def _signal_names(numbers: frozenset[int]) -> list[str]:
    names = []
    for n in sorted(numbers):
        try:
            names.append(signal.Signals(n).name)
        except ValueError:
            names.append(f"signal {n}")
    return names


def _listening_ports() -> set[int]:
    """The TCP ports this process listens on (its own sockets, not its children's)."""
    ports = set()
    for fd in _read_dir(Path("/proc/self/fd")):
        with contextlib.suppress(OSError, ValueError):
            if os.readlink(fd).startswith("socket:["):
                with socket.socket(fileno=os.dup(int(fd.name))) as sock:
                    inet = sock.family in (socket.AF_INET, socket.AF_INET6)
                    if inet and sock.getsockopt(socket.SOL_SOCKET, socket.SO_ACCEPTCONN):
                        ports.add(sock.getsockname()[1])
    return ports


def _left_open(before: set[int]) -> list[zenoh.Session]:
    """Sessions opened since ``before``, still open and held by someone; those no one
    holds any more are let go here (Zenoh closes a session nobody holds)."""
    kept, left = [], []
    for i in range(len(_sessions)):
        s = _sessions[i]
        # references: the list, s, getrefcount's argument; any more are someone's
        if s.is_closed() or sys.getrefcount(s) <= 3:
            continue
        kept.append(s)
        if id(s) not in before:
            left.append(s)
    _sessions[:] = kept
    return left


def leaks(before: Snapshot, *, processes_too: bool = True) -> list[str]:
    """What was left behind since ``before``, one line each (after waiting up to
    :data:`GRACE_S` for processes and threads that are exiting); kills the processes,
    closes the sessions and restores the test process."""
    deadline = time.monotonic() + GRACE_S
    left: list[Proc] = []
    while processes_too:
        now = processes()
        owners = {p.pid for p in before.procs.values() if now.get(p.pid) == p}
        left = [p for p in now.values() if not _under(p, owners, now)]
        if not left or time.monotonic() >= deadline:
            break
        time.sleep(0.1)
    found = [f"process left running: {p}" for p in left]
    _kill(left)
    for t in _threads() - before.threads - _said:
        t.join(max(0.0, deadline - time.monotonic()))
        if t.is_alive():
            found.append(f"thread left running: {t!r}")
            _said.add(t)
    for s in _left_open(before.sessions):
        found.append(f"Zenoh session left open in the test process: zid {s.zid()}")
        with contextlib.suppress(zenoh.ZError):
            s.close()
    after = snapshot()
    ports = after.ports - before.ports - _said
    found += [f"port left listening by the test process: {p}" for p in sorted(ports)]
    _said.update(ports)
    found += _changes(before, after)
    _restore(before, after)
    return found


def _changes(before: Snapshot, after: Snapshot) -> list[str]:
    """How the test process itself was changed, one line each."""
    found = []
    for what, was, now in (
        ("cores (sched affinity) of its threads", before.affinity, after.affinity),
        ("CPU priority (nice)", before.nice, after.nice),
        ("working directory", before.cwd, after.cwd),
        ("signal handlers", *_handlers_changed(before.handlers, after.handlers)),
        ("ignored signals", _signal_names(before.ignored), _signal_names(after.ignored)),
        ("blocked signals", _signal_names(before.blocked), _signal_names(after.blocked)),
    ):
        if was != now:
            found.append(f"test process changed: {what} {was!r} -> {now!r} (children inherit it)")
    for k in sorted(before.env.keys() | after.env.keys()):
        if before.env.get(k) != after.env.get(k):
            found.append(
                f"test process changed: environment variable {k} "
                f"{before.env.get(k)!r} -> {after.env.get(k)!r}"
            )
    return found


def _handlers_changed(
    before: dict[signal.Signals, Any], after: dict[signal.Signals, Any]
) -> tuple[dict[str, str], dict[str, str]]:
    """The Python signal handlers that changed, by name, before and after."""
    changed = [s for s in before if before[s] != after[s]]
    return ({s.name: _name(before[s]) for s in changed}, {s.name: _name(after[s]) for s in changed})


def _name(handler: Any) -> str:
    return getattr(handler, "__qualname__", None) or getattr(handler, "name", None) or repr(handler)


def _restore(before: Snapshot, after: Snapshot) -> None:
    """Put the test process back as it was, for the tests that come next."""
    if after.affinity != before.affinity and len(before.affinity) == 1:
        for task in _read_dir(Path("/proc/self/task")):
            with contextlib.suppress(OSError):
                os.sched_setaffinity(int(task.name), before.cores)
    if after.nice != before.nice:
        with contextlib.suppress(OSError):  # raising it back needs CAP_SYS_NICE
            os.setpriority(os.PRIO_PROCESS, 0, before.nice)
    if after.cwd != before.cwd:
        os.chdir(before.cwd)
    for sig, handler in before.handlers.items():
        changed = after.handlers[sig] != handler or sig in after.ignored ^ before.ignored
        if changed and handler is not None:
            signal.signal(sig, handler)
    if after.blocked != before.blocked:
        signal.pthread_sigmask(signal.SIG_SETMASK, before.blocked)
    if after.env != before.env:
        for key in after.env.keys() - before.env.keys():
            del os.environ[key]
        os.environ.update(before.env)


def _kill(procs: list[Proc]) -> None:
    """SIGKILL these processes (each checked to be the same process, not a reused pid)."""
    for p in procs:
        if processes().get(p.pid) == p:
            with contextlib.suppress(OSError):
                os.kill(p.pid, signal.SIGKILL)


def _tracked_open(*args: Any, **kwargs: Any) -> zenoh.Session:
    session = _real_open(*args, **kwargs)
    _sessions.append(session)
    return session


def _guard(what: str, *, processes_too: bool = True) -> Iterator[None]:
    before = snapshot()
    yield
    found = leaks(before, processes_too=processes_too)
    if found:
        pytest.fail(f"{what} left behind:\n  " + "\n  ".join(found), pytrace=False)


#: Marks a test whose processes a module-scoped fixture keeps and stops (checked when
#: the module ends, not after the test).
HANDS_OVER = "processes_kept_by_the_module"


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        f"{HANDS_OVER}: the processes this test starts are stopped by a module-scoped "
        "fixture; the leak guard checks them when the module ends",
    )
    for name in _IMPORTED_FIRST:
        importlib.import_module(name)
    # a pytest run by a test (pytester) adds its own pid: both guards see its processes
    os.environ[MARKER] = ",".join(filter(None, (os.environ.get(MARKER), str(os.getpid()))))
    zenoh.open = _tracked_open


def pytest_unconfigure(config: pytest.Config) -> None:
    zenoh.open = _real_open


@pytest.fixture(autouse=True, scope="module")
def _nothing_left_by_the_module(request: pytest.FixtureRequest) -> Iterator[None]:
    """Set up before the module's other fixtures, torn down after them: checks what the
    module-scoped fixtures leave."""
    yield from _guard(f"module {request.module.__name__} (its module-scoped fixtures)")


@pytest.fixture(autouse=True)
def _nothing_left_by_the_test(request: pytest.FixtureRequest) -> Iterator[None]:
    """Set up after the module's fixtures, torn down after the test's other fixtures."""
    kept = request.node.get_closest_marker(HANDS_OVER) is not None
    yield from _guard(request.node.nodeid, processes_too=not kept)
