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
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

__all__ = ["keep_freed_memory"]

_M_TRIM_THRESHOLD = -1  # mallopt parameters, from glibc's <malloc.h>
_M_MMAP_THRESHOLD = -3
#: Free memory a heap may keep at its top before glibc gives it back.
TRIM_BYTES = 64 << 20
#: Blocks up to this size come from a heap (glibc's ceiling for this setting is 32 MiB).
MMAP_BYTES = 32 << 20


def keep_freed_memory() -> bool:
    """Raise glibc's trim and mmap thresholds for this process (call it before threads
    start allocating); False where the C library is not glibc (nothing is changed)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # musl and others have no mallopt
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    return bool(mallopt(_M_TRIM_THRESHOLD, TRIM_BYTES) and mallopt(_M_MMAP_THRESHOLD, MMAP_BYTES))
