"""Shared by every test file.

- The suite runs on two workers (pytest-xdist, ``-n 2``, a file's tests on one worker);
  a file that asserts timing a neighbour's load would falsify runs alone
  (tests/lanes.py). ``pytest -n 0`` runs in one process (for a debugger).

- The leak guard (tests/leak_guard.py) fails the test that leaves a process, a Zenoh
  session, a thread, a listening port or a changed test process (cores, priority,
  environment, signals) behind for the tests that run after it.
- Once the tests are collected, the objects that exist then (every imported module and
  collected test: over a hundred thousand in the whole suite) are put out of the garbage
  collector's sight (``gc.freeze``, as the services do at start): a full collection walks
  every object it tracks and holds the interpreter meanwhile, and the one that came due
  inside a test publishing on a live schedule paused it (issue 27, item 12).
- Ctrl-C reaches the processes the tests start as it reaches a program in a terminal.
  A shell without job control starts a background command (``pytest &`` in a script,
  ``nohup``, many CI runners) with SIGINT *ignored*, and an ignored signal stays ignored
  in every child: Python then installs no KeyboardInterrupt handler, so a program that
  relies on it (the example subscriber) sent SIGINT by a test never stops, and the test
  fails only when the whole suite was started that way (issue 27, item 12). The suite
  takes SIGINT back at its start; children then inherit the default.
"""

from __future__ import annotations

import gc
import os
import signal

import pytest

# MuJoCo picks its OpenGL back-end when it is first imported, which a test module may do
# before anything of ovis.common.physical (which selects EGL) is imported.
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

pytest_plugins = ["lanes", "leak_guard", "pytester"]


def pytest_sessionstart(session: pytest.Session) -> None:
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_collection_finish(session: pytest.Session) -> None:
    gc.collect()
    gc.freeze()
