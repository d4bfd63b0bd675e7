"""Large messages written once into Zenoh shared memory: a publisher on the same host as
its subscribers hands them a reference to the buffer instead of the bytes; toward a
subscriber that cannot map it (another host, shared memory off) Zenoh sends the bytes
over the network instead, with nothing else changing."""

from __future__ import annotations

import logging

import zenoh

from ovis.common.pipeline.counters import worth_logging

__all__ = ["SHM_MIN_BYTES", "ShmWriter"]

#: Smaller messages are published as plain bytes (a buffer per message costs more than
#: the copy it saves).
SHM_MIN_BYTES = 16 * 1024


class ShmWriter:
    """A pool of shared memory of ``pool_bytes`` and the messages written into it.

    :meth:`payload` copies a message into a buffer of the pool (its only copy on the
    publisher's side: Zenoh sends the buffer as it is). A full pool (subscribers still
    holding earlier messages) is not waited for: the message goes as plain bytes (it
    still arrives, copied as over the network), ``fallbacks`` counts it and ``log`` says
    so (the first 5, then every 100th); the service's status shows both counts."""

    def __init__(self, pool_bytes: int, log: logging.Logger | None = None) -> None:
        from zenoh import shm

        self._shm = shm
        self._provider = shm.ShmProvider.default_backend(pool_bytes)
        self._policy = shm.GarbageCollect()
        self._log = log or logging.getLogger("ovis.shm")
        self.pool_bytes = pool_bytes
        self.written = 0
        self.fallbacks = 0

    def payload(self, data: bytes) -> bytes | zenoh.shm.ZShmMut:
        """What to put for ``data``: a shared buffer holding it, or ``data`` itself (too
        small, or no room in the pool)."""
        if len(data) < SHM_MIN_BYTES:
            return data
        try:
            buf = self._provider.alloc(len(data), self._policy)
        except zenoh.ZError as exc:
            self.fallbacks += 1
            if worth_logging(self.fallbacks):
                self._log.warning(
                    "shared-memory pool of %d bytes full (%s): a %d-byte message sent as "
                    "plain bytes (shm_fallbacks #%d)",
                    self.pool_bytes,
                    exc,
                    len(data),
                    self.fallbacks,
                )
            return data
        buf[:] = data
        self.written += 1
        return buf
