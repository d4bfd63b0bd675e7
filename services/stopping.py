"""A stop flag that a signal handler may set.

``threading.Event.set`` takes the event's lock. A Python signal handler runs in the main
thread between two bytecodes, so when the main thread was itself inside ``Event.wait``
holding that lock, ``set`` from the handler waits for it forever: Ctrl-C then never
stops the process. :class:`Stop` keeps the flag in a plain attribute and wakes the
waiters through a pipe (``os.write`` takes no lock), with ``Event``'s ``set``,
``is_set`` and ``wait``.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
from typing import Protocol

__all__ = ["Stop", "Stopping", "stop_on"]


class Stopping(Protocol):
    """What waits on a stop: a :class:`Stop` or a ``threading.Event``."""

    def set(self) -> None: ...
    def is_set(self) -> bool: ...
    def wait(self, timeout: float | None = None) -> bool: ...


class Stop:
    """``set`` once, from any thread or signal handler; ``wait`` from any thread."""

    def __init__(self) -> None:
        self._set = False
        self._read, self._write = os.pipe()
        os.set_blocking(self._write, False)

    def set(self) -> None:
        if not self._set:
            self._set = True
            with contextlib.suppress(BlockingIOError):  # already woken: the pipe is full
                os.write(self._write, b"!")

    def is_set(self) -> bool:
        return self._set

    def wait(self, timeout: float | None = None) -> bool:
        """Whether it is set, once set or after ``timeout`` seconds (``None``: until set).
        The pipe is never read: once written it wakes every waiter at once."""
        if not self._set:
            select.select([self._read], [], [], timeout)
        return self._set

    def __del__(self) -> None:
        for fd in (self._read, self._write):
            with contextlib.suppress(OSError):
                os.close(fd)


def stop_on(*signums: signal.Signals) -> Stop:
    """A :class:`Stop` that each of ``signums`` sets (main thread only)."""
    stop = Stop()
    for signum in signums:
        signal.signal(signum, lambda *_: stop.set())
    return stop
