"""The newest-wins queue between Zenoh's callbacks and a service's loop: Zenoh's thread
only drops a sample in and returns, so a slow stage drops old frames (counted) instead
of queueing them in the network stack."""

from __future__ import annotations

import collections
import threading
from typing import Any

__all__ = ["Inbox"]


class Inbox:
    """A bounded queue where the newest item wins: when full, the oldest is dropped
    (and counted). Zenoh callbacks put; the service loop gets with a timeout."""

    def __init__(self, depth: int = 2) -> None:
        self._items: collections.deque[Any] = collections.deque(maxlen=depth)
        self._cond = threading.Condition()
        self.dropped = 0
        #: set at every put, when one thread serves several inboxes (services/host.py)
        self.wake: threading.Event | None = None

    def put(self, item: Any) -> None:
        with self._cond:
            if len(self._items) == self._items.maxlen:
                self.dropped += 1
            self._items.append(item)
            self._cond.notify()
        if self.wake is not None:
            self.wake.set()

    def get(self, timeout: float) -> Any | None:
        with self._cond:
            if not self._items and timeout > 0:
                self._cond.wait(timeout)
            return self._items.popleft() if self._items else None

    def __len__(self) -> int:
        return len(self._items)
