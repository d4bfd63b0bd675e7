"""CPU placement: which cores the frame path runs on (``ovis up --pin``, ``ovis run
--cpus``) and pinning a process to them."""

from __future__ import annotations

import contextlib
import logging
import os

__all__ = [
    "ALLOWED_ENV",
    "FRAME_PATH",
    "allowed_cpus",
    "cpus_option",
    "off_path_cpus",
    "off_path_option",
    "pick_cpus",
    "pin_to_cpus",
]

#: The services every frame passes through, in order.
FRAME_PATH = ("capture", "preprocess", "label", "pose")


def pick_cpus(spec: str) -> list[int]:
    """Cores from ``--pin`` (``ovis up``: for the frame path, :data:`FRAME_PATH`) or
    ``--cpus`` (``ovis run``): "auto" (the last core this process may use, when it may
    use two or more: the others stay free for the router, the calibrator and
    subscribers), "none", or core numbers such as "1" or "0,2".

    Why one core: at camera rates every stage sleeps between frames and each hand-over
    wakes the next one; on the same core it finds numpy's and Zenoh's code still in
    cache and needs no cross-core wake-up. The latency and rates on one core and on any
    core are measured in ``benchmarks/`` (bus and pipeline).
    """
    spec = spec.strip().lower()
    if spec == "none":
        return []
    allowed = allowed_cpus()
    if spec == "auto":
        return allowed[-1:] if len(allowed) >= 2 else []
    try:
        cpus = sorted({int(part) for part in spec.split(",") if part.strip()})
    except ValueError:
        cpus = []
    if not cpus:
        raise ValueError(
            f"cores {spec!r}: expected 'auto', 'none' or core numbers such as 1 or 0,2"
        )
    missing = [c for c in cpus if c not in allowed]
    if missing:
        raise ValueError(
            f"cores {spec!r}: {missing} not available; this process may "
            f"use {','.join(map(str, allowed))}"
        )
    return cpus


#: The cores the launching process may use, for a child started on fewer (a spare of
#: ``ovis up`` waits off the frame path but is given the frame path's core later).
ALLOWED_ENV = "OVIS_CPUS_ALLOWED"


def allowed_cpus() -> list[int]:
    """The cores this process may be pinned to: its own, or its launcher's
    (:data:`ALLOWED_ENV`) when it was started on fewer."""
    inherited = os.environ.get(ALLOWED_ENV, "")
    with contextlib.suppress(ValueError):
        if inherited:
            return sorted({int(c) for c in inherited.split(",")})
    return sorted(os.sched_getaffinity(0))


def cpus_option(stage: str, cpus: list[int]) -> list[str]:
    """The ``ovis run STAGE`` arguments that put ``stage`` where ``ovis up`` puts it: on
    ``cpus`` if it is on the frame path (:data:`FRAME_PATH`; [] → "none"), else nothing."""
    if stage not in FRAME_PATH:
        return []
    return ["--cpus", ",".join(map(str, cpus)) or "none"]


def pin_to_cpus(cpus: list[int], log: logging.Logger) -> bool:
    """Restrict this process (and the threads it starts later) to ``cpus``; a core the
    machine does not have is logged and the process runs unpinned."""
    if not cpus:
        return False
    try:
        # Every thread, also those started at import (OpenBLAS's pool), which would not
        # inherit it; threads started later do.
        for tid in os.listdir("/proc/self/task"):
            with contextlib.suppress(ProcessLookupError):
                os.sched_setaffinity(int(tid), cpus)
    except (OSError, ValueError, AttributeError) as exc:
        log.warning(
            "cannot pin to cores %s (%s): running on any core; check [service] cpus",
            cpus,
            exc,
        )
        return False
    return True


def off_path_cpus(cpus: list[int]) -> list[int]:
    """The cores this process may use other than the frame path's ``cpus`` ([] when the
    frame path is not pinned, or has them all)."""
    return sorted(set(os.sched_getaffinity(0)) - set(cpus)) if cpus else []


def off_path_option(cpus: list[int]) -> list[str]:
    """The ``--cpus`` arguments that keep a helper process (the live view) off the frame
    path's cores ``cpus``: the other cores this process may use; none if there are none."""
    others = off_path_cpus(cpus)
    return ["--cpus", ",".join(map(str, others))] if others else []
