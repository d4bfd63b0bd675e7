"""How a process that moves camera frames keeps the memory it frees (glibc ``malloc``).

glibc returns a large freed block to the kernel straight away: a block over the mmap
threshold is unmapped, and the top of a heap over the trim threshold is given back.
A stage allocates and frees several frame-sized buffers per frame (the received
payload, numpy's images, the encoded message and Zenoh's copy of it), so with the
defaults every frame maps fresh pages and takes a page fault per 4 KiB of each, on
the path from capture to world. Raising both thresholds above a frame's size keeps
those blocks in the process for the next frame; what a process holds grows by at most
the trim threshold per malloc arena. The per-message cost with and without is measured
in ``benchmarks/frame_hop.py``.

The price: a message larger than a frame (a forged one, refused once its length is
seen, but Zenoh has received it by then; or one a router passes on) would leave the
process at its high-water mark for good, the blocks Zenoh and Python freed kept in the
heaps. So the thresholds are fitted to the largest message a process accepts
(``keep_freed_memory(largest)``: a stage's from its camera): a larger block is mapped on
its own and unmapped when freed, and a heap keeps at most :data:`KEPT_MESSAGES` such
messages free at its top; and :func:`guard_memory` gives back the free blocks left
inside the heaps (``malloc_trim``) shortly after a stage refuses an oversized message,
and whenever the memory its heaps hold free has grown by :data:`GROWTH_BYTES` since it
last gave memory back (not when the process merely uses more: a trim stalls every
thread that allocates meanwhile, and memory in use is not given back by it).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os
import sys
import threading
import time
from typing import Any

__all__ = [
    "DEFAULT_LARGEST",
    "MemoryGuard",
    "give_back_freed_memory",
    "guard_memory",
    "keep_freed_memory",
]

_M_TRIM_THRESHOLD = -1  # mallopt parameters, from glibc's <malloc.h>
_M_MMAP_THRESHOLD = -3
#: Free memory a heap may keep at its top before glibc gives it back.
TRIM_BYTES = 64 << 20
#: Blocks up to this size come from a heap (glibc's ceiling for this setting is 32 MiB).
MMAP_BYTES = 32 << 20
#: With the largest message known: how many of them a heap may keep free at its top.
KEPT_MESSAGES = 2
#: The largest message a process that knows no camera keeps memory for (a stage fits
#: the thresholds to its own camera): a 1280x1024 colour frame.
DEFAULT_LARGEST = 1280 * 1024 * 3
#: glibc's own default mmap threshold, the least we set.
_MIN_MMAP_BYTES = 128 << 10


#: How long after an oversized message its memory is given back: by then Zenoh and the
#: callback have let go of it, and the messages of a flood are given back together.
TRIM_DELAY_S = 0.5
#: How often the guard looks at the memory the heaps hold free, and by how much it must
#: have grown above the least seen since the last trim to be given back.
GUARD_PERIOD_S = 1.0
GROWTH_BYTES = 16 << 20


@functools.cache
def _glibc(name: str) -> Any | None:
    """glibc's function ``name``, or None (not Linux, or a C library without it)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        return getattr(ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6"), name)
    except (OSError, AttributeError):  # musl and others have no mallopt / malloc_trim
        return None


def keep_freed_memory(largest: int | None = None) -> bool:
    """Raise glibc's trim and mmap thresholds for this process (call it before threads
    start allocating): to :data:`TRIM_BYTES` and :data:`MMAP_BYTES`, or, given the
    ``largest`` message the process accepts, to that and :data:`KEPT_MESSAGES` times
    it. False where the C library is not glibc (nothing is changed)."""
    mallopt = _glibc("mallopt")
    if mallopt is None:
        return False
    mmap, trim = MMAP_BYTES, TRIM_BYTES
    if largest is not None:
        mmap = min(max(largest, _MIN_MMAP_BYTES), MMAP_BYTES)
        trim = min(KEPT_MESSAGES * mmap, TRIM_BYTES)
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    return bool(mallopt(_M_TRIM_THRESHOLD, trim) and mallopt(_M_MMAP_THRESHOLD, mmap))


def give_back_freed_memory() -> bool:
    """Return the free memory of every malloc arena to the kernel (``malloc_trim(0)``),
    whatever the thresholds; False where the C library has no ``malloc_trim``."""
    trim = _glibc("malloc_trim")
    if trim is None:
        return False
    trim.argtypes = (ctypes.c_size_t,)
    trim(0)
    return True


class _MallInfo2(ctypes.Structure):
    """glibc's ``struct mallinfo2`` (glibc 2.33 and later)."""

    _fields_ = [
        (name, ctypes.c_size_t)
        for name in (
            "arena",
            "ordblks",
            "smblks",
            "hblks",
            "hblkhd",
            "usmblks",
            "fsmblks",
            "uordblks",
            "fordblks",
            "keepcost",
        )
    ]


def free_held_bytes() -> int | None:
    """The memory glibc's heaps hold free (``mallinfo2``'s ``fordblks``: free chunks, the
    fast bins' among them), resident or not; None where the C library cannot say."""
    info = _glibc("mallinfo2")
    if info is None:
        return None
    info.restype = _MallInfo2
    return int(info().fordblks)


def resident_bytes() -> int:
    """This process's resident memory (0 where /proc is unavailable)."""
    try:
        with open("/proc/self/statm", encoding="ascii") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


class MemoryGuard:
    """Gives freed memory back (:func:`give_back_freed_memory`) from a thread of its
    own: :data:`TRIM_DELAY_S` after :meth:`request` (once for all the requests made
    meanwhile), and whenever the memory the heaps hold free (what a large message left
    when it was let go, maybe after the last trim) has grown by :data:`GROWTH_BYTES`
    above the least seen since its last trim (:meth:`look`)."""

    def __init__(
        self,
        period_s: float = GUARD_PERIOD_S,
        growth_bytes: int = GROWTH_BYTES,
        delay_s: float = TRIM_DELAY_S,
    ) -> None:
        self.period_s, self.growth_bytes, self.delay_s = period_s, growth_bytes, delay_s
        self._floor: int | None = None
        self._asked = threading.Event()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None

    def start(self) -> MemoryGuard:
        with self._lock:
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="memory", daemon=True)
                self._thread.start()
        return self

    def request(self) -> None:
        """Give memory back soon (a large message has just been refused)."""
        self.start()
        self._asked.set()

    def look(self, asked: bool = False) -> bool:
        """One look (the guard's thread makes one every ``period_s``): give memory back
        when ``asked`` or when the heaps hold :data:`GROWTH_BYTES` more free than the
        least seen since the last trim (the first look only notes it); True if it did."""
        free = free_held_bytes() or 0
        floor = free if self._floor is None else self._floor
        if asked or free > floor + self.growth_bytes:
            give_back_freed_memory()
            self._floor = free_held_bytes() or 0
            return True
        self._floor = min(floor, free)
        return False

    def _run(self) -> None:
        self.look()
        while True:
            asked = self._asked.wait(self.period_s)
            if asked:
                time.sleep(self.delay_s)
                self._asked.clear()
            self.look(asked)


#: The guard of this process (started by :func:`guard_memory`).
GUARD = MemoryGuard()


def guard_memory(largest: int | None = DEFAULT_LARGEST) -> MemoryGuard:
    """Keep freed memory for messages up to ``largest`` bytes (:func:`keep_freed_memory`)
    and start this process's :data:`GUARD`."""
    keep_freed_memory(largest)
    return GUARD.start()
