"""What every benchmark shares: result rows, timing statistics, scaled configurations
and a description of the machine."""

from __future__ import annotations

import datetime as dt
import os
import platform
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from importlib import metadata
from typing import Any

import msgspec
import numpy as np

from ovis.common.config import OvisConfig, load_config

__all__ = [
    "SIZES",
    "CpuMeter",
    "Row",
    "Stats",
    "machine_info",
    "scaled_config",
    "size_label",
    "stats",
    "time_call",
]

#: (rows, cols) of the frame sizes measured.
SIZES = ((480, 640), (720, 1280), (1080, 1920))

#: Threshold and size filter (cm²) of the "calibration" the benchmarks use.
THRESHOLD = 150
SIZE_FILTER_CM2 = 25.0


@dataclass
class Row:
    """One line of ``results.json`` and of the README table.

    ``floor`` is the reference measured in the same run (same unit as ``value``),
    ``ratio`` = value / floor; ``target`` says what ``met`` checks, e.g. "ratio ≤ 1.0"
    or "≤ 4 ms"; ``met`` is None where no target applies.
    """

    name: str
    unit: str
    value: float | bool | None
    floor: float | None = None
    ratio: float | None = None
    target: str | None = None
    met: bool | None = None

    def as_dict(self) -> dict[str, Any]:
        return {k: _plain(v) for k, v in asdict(self).items()}


def _plain(v: Any) -> Any:
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float):
        if not np.isfinite(v):
            return None
        return float(f"{v:.6g}")
    return v


def ratio(value: float | None, floor: float | None) -> float | None:
    if value is None or floor is None or floor == 0:
        return None
    return value / floor


@dataclass
class Stats:
    """Summary of repeated timings, in milliseconds."""

    p50: float
    p99: float
    mean: float
    n: int


def stats(samples_ms: Sequence[float]) -> Stats:
    a = np.asarray(samples_ms, dtype=np.float64)
    if a.size == 0:
        return Stats(float("nan"), float("nan"), float("nan"), 0)
    return Stats(
        float(np.percentile(a, 50)), float(np.percentile(a, 99)), float(a.mean()), int(a.size)
    )


def time_call(fn: Callable[[], Any]) -> float:
    """Wall time of one call, in milliseconds (time.perf_counter)."""
    t0 = time.perf_counter()
    fn()
    return (time.perf_counter() - t0) * 1e3


def size_label(rows: int, cols: int) -> str:
    return f"{cols}×{rows}"


def scaled_config(rows: int, cols: int, base: OvisConfig | None = None) -> OvisConfig:
    """The default camera scaled to ``rows × cols`` with the same field of view
    (N_fx = rows, N_fy = cols, principal point at the centre), threshold 150 and a
    25 cm² size filter."""
    cfg = base or load_config()
    camera = msgspec.structs.replace(
        cfg.camera,
        rows=rows,
        cols=cols,
        N_fx=float(rows),
        N_fy=float(cols),
        c_x=rows / 2.0,
        c_y=cols / 2.0,
    )
    image = msgspec.structs.replace(cfg.image, threshold=THRESHOLD, size_filter_cm2=SIZE_FILTER_CM2)
    return msgspec.structs.replace(cfg, camera=camera, image=image)


class CpuMeter:
    """CPU time used by the whole machine and by this process and its (reaped) children
    between construction and :meth:`other_cores`: what other programs took meanwhile,
    in average cores (the benchmarks are not alone on a shared machine)."""

    def __init__(self) -> None:
        self.t0 = time.monotonic()
        self.busy0 = self._busy_s()
        self.own0 = self._own_s()

    @staticmethod
    def _busy_s() -> float | None:
        try:
            with open("/proc/stat", encoding="ascii") as fh:
                fields = [int(x) for x in fh.readline().split()[1:]]
        except (OSError, ValueError):
            return None
        idle = fields[3] + (fields[4] if len(fields) > 4 else 0)  # idle + iowait
        total = sum(fields[:8])  # guest time is already inside user
        return (total - idle) / os.sysconf("SC_CLK_TCK")

    @staticmethod
    def _own_s() -> float:
        t = os.times()
        return t.user + t.system + t.children_user + t.children_system

    def other_cores(self) -> float | None:
        busy = self._busy_s()
        if busy is None or self.busy0 is None:
            return None
        wall = time.monotonic() - self.t0
        other = (busy - self.busy0) - (self._own_s() - self.own0)
        return max(0.0, other / wall) if wall > 0 else None


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def machine_info() -> dict[str, Any]:
    """CPU, cores, versions and date of this run."""
    import cv2

    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:
        affinity = os.cpu_count()
    return {
        "date": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "cores_usable": affinity,
        "os": f"{platform.system()} {platform.release()}",
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "opencv": cv2.__version__,
        "zenoh": _version("eclipse-zenoh"),
        "msgspec": _version("msgspec"),
        "ovis": _version("ovis"),
        "load_average_start": list(os.getloadavg()),
    }
