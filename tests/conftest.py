"""Shared by every test file: the leak guard (tests/leak_guard.py) fails the test that
leaves a process, a Zenoh session, a thread, a listening port or a changed test process
(cores, priority, environment, signals) behind for the tests that run after it."""

pytest_plugins = ["leak_guard", "pytester"]
