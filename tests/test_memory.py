"""keep_freed_memory: frame-sized buffers freed each frame are reused, not faulted in
again (a fresh process for each setting: glibc's thresholds are per process)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

FRAMES = """
import json, resource, sys
import numpy as np
from ovis.services.memory import keep_freed_memory
mode = sys.argv[1]
kept = keep_freed_memory() if mode == "keep" else None
if mode.isdigit():  # fitted to the largest message
    kept = keep_freed_memory(int(mode))
def frame():  # what a stage allocates per 640x480 frame: payload, images, the encoded reply
    bufs = [np.ones(640 * 480, np.uint8) for _ in range(4)]
    return int(sum(b[::4096].sum() for b in bufs))
for _ in range(20):
    frame()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(100):
    frame()
after = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
print(json.dumps({"kept": kept, "faults_per_frame": (after - before) / 100}))
"""


def _faults(mode: str) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", FRAMES, mode], capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_kept_memory_takes_no_page_fault_per_frame() -> None:
    kept, default = _faults("keep"), _faults("default")
    assert kept["kept"] is True
    assert kept["faults_per_frame"] < 2  # the same pages, frame after frame
    # with glibc's defaults the four 300 KB blocks are given back and faulted in again
    assert default["faults_per_frame"] > 100


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_thresholds_fitted_to_a_stage_camera_still_take_no_page_fault_per_frame() -> None:
    """What `ovis run` sets for the 640x480 camera: its largest message (a blob list)
    stays in the heaps, anything larger is mapped on its own and unmapped when freed."""
    from ovis.common.config import PinholeParams
    from ovis.common.pipeline.limits import PayloadLimits

    pose = {"rvec": [0.0, 0.0, 0.0], "tvec_cm": [0.0, 0.0, 100.0]}
    camera = PinholeParams(rows=480, cols=640, fx=500.0, fy=500.0, cx=320.0, cy=240.0, **pose)
    fitted = _faults(str(max(PayloadLimits.of(camera))))
    assert fitted["kept"] is True
    assert fitted["faults_per_frame"] < 2


BURST = """
import json, sys, time
from ovis.services.memory import MemoryGuard, keep_freed_memory, resident_bytes
keep_freed_memory()
guard = MemoryGuard()
threaded = sys.argv[1] == "thread"
if threaded:  # the guard's own thread: it looks every second
    guard.start()
    time.sleep(1.5)  # its first look notes what the start left free
else:
    guard.look()
in_use = [bytearray(1 << 20) for _ in range(64)]  # memory in use: no reason to trim
trimmed_in_use = None if threaded else guard.look()
start = resident_bytes()
burst = [bytearray(1 << 20) for _ in range(200)]  # 1 MiB blocks: from the heaps
pin = bytearray(1 << 10)  # above them: freed, they are not the heap's top (not trimmed)
peak = resident_bytes()
del burst
freed = resident_bytes()
trimmed = None
if threaded:
    deadline = time.monotonic() + 10.0
    while resident_bytes() - start > 20 << 20 and time.monotonic() < deadline:
        time.sleep(0.1)
else:
    trimmed = guard.look()
print(json.dumps({"start": start, "peak": peak, "freed": freed, "after": resident_bytes(),
                  "trimmed_in_use": trimmed_in_use, "trimmed": trimmed, "kept": len(in_use)}))
"""


def _burst(how: str) -> tuple[dict, dict]:
    """The burst script's answers, and its memory figures in MiB."""
    out = subprocess.run(
        [sys.executable, "-c", BURST, how], capture_output=True, text=True, check=True
    )
    found = json.loads(out.stdout)
    mb = {k: found[k] / 2**20 for k in ("start", "peak", "freed", "after")}
    return found, mb


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim")
def test_the_memory_guard_gives_back_what_a_burst_left() -> None:
    """200 MiB allocated and freed in heap-sized blocks stay resident (the thresholds
    keep freed blocks), until the guard's next look sees the heaps hold them free and
    trims; 64 MiB more in use before is no reason to trim."""
    found, mb = _burst("look")
    assert found["trimmed_in_use"] is False
    assert mb["peak"] - mb["start"] > 190, mb
    assert mb["freed"] - mb["start"] > 150, mb  # kept by the heaps: no look since
    assert found["trimmed"] is True
    assert mb["after"] - mb["start"] < 20, mb


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim")
def test_the_guard_thread_gives_back_a_burst() -> None:
    """The guard's own thread, looking every second, trims the burst."""
    _, mb = _burst("thread")
    assert mb["peak"] - mb["start"] > 190, mb
    assert mb["after"] - mb["start"] < 20, mb
