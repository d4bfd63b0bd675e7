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
import json, time
from ovis.services.memory import guard_memory, resident_bytes
guard = guard_memory()
time.sleep(1.5)  # the guard's first looks: the start's own memory
start = resident_bytes()
burst = [bytearray(1 << 20) for _ in range(200)]  # 1 MiB blocks: from the heaps
pin = bytearray(1 << 10)  # above them: freed, they are not the heap's top (not trimmed)
peak = resident_bytes()
del burst
time.sleep(0.2)
freed = resident_bytes()
time.sleep(2.5)
print(json.dumps({"start": start, "peak": peak, "freed": freed, "after": resident_bytes()}))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim")
def test_the_memory_guard_gives_back_what_a_burst_left() -> None:
    """200 MiB allocated and freed in heap-sized blocks stay resident (the thresholds
    keep freed blocks), until the guard sees the heaps hold them free and trims."""
    out = subprocess.run([sys.executable, "-c", BURST], capture_output=True, text=True, check=True)
    mb = {k: v / 2**20 for k, v in json.loads(out.stdout).items()}
    assert mb["peak"] - mb["start"] > 190, mb
    assert mb["freed"] - mb["start"] > 150, mb  # kept by the heaps at first
    assert mb["after"] - mb["start"] < 20, mb
