"""Shared by every test file.

- The leak guard (tests/leak_guard.py) fails the test that leaves a process, a Zenoh
  session, a thread, a listening port or a changed test process (cores, priority,
  environment, signals) behind for the tests that run after it.
- Once the tests are collected, the objects that exist then (every imported module and
  collected test: over a hundred thousand in the whole suite) are put out of the garbage
  collector's sight (``gc.freeze``, as the services do at start): a full collection walks
  every object it tracks and holds the interpreter meanwhile, and the one that came due
  inside a test publishing on a live schedule paused it (issue 27, item 12).
"""

from __future__ import annotations

import gc

import pytest

pytest_plugins = ["leak_guard", "pytester"]


def pytest_collection_finish(session: pytest.Session) -> None:
    gc.collect()
    gc.freeze()
