"""The live view's cost to the frame path (issue 17): capture → obstacle latency at 30
frames/s with ``ovis view`` running and browsers (WebSocket clients that take every
picture it sends) connected, against the same pipeline without the view, in the same
run. Phases alternate (without, with, without, with, …) so that drift in the machine's
load falls on both; each condition's figure is the median of its phases' p50.

The pipeline is placed as ``ovis up`` places it (:class:`benchmarks.bus.Bench`); the
view is a Zenoh client of the router, as ``ovis up --view`` starts it.
"""

from __future__ import annotations

import tempfile
import threading
import time
import urllib.request
from pathlib import Path

import msgspec
import numpy as np
from websockets.sync.client import connect

from benchmarks.bus import ARENA, LATENCY_FPS, PIPELINE, PRERENDER, Bench, free_port
from benchmarks.core import Row, ratio, scaled_config
from ovis.services.placement import off_path_option

__all__ = ["view_rows"]

#: Browsers connected during the "with" phases.
CLIENTS = 2


class Browsers:
    """``n`` WebSocket clients of the view that receive (and count) every message."""

    def __init__(self, url: str, n: int) -> None:
        self.stop = threading.Event()
        self.pictures = [0] * n
        self.threads = [threading.Thread(target=self._run, args=(url, i)) for i in range(n)]
        for t in self.threads:
            t.start()

    def _run(self, url: str, i: int) -> None:
        with connect(url, max_size=2**24) as ws:
            while not self.stop.is_set():
                try:
                    data = ws.recv(timeout=0.5)
                except TimeoutError:
                    continue
                if isinstance(data, bytes):
                    self.pictures[i] += 1

    def close(self) -> int:
        self.stop.set()
        for t in self.threads:
            t.join(5)
        return sum(self.pictures)


def _wait_http(url: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while True:
        try:
            with urllib.request.urlopen(url, timeout=2):
                return
        except OSError:
            if time.monotonic() > deadline:
                raise RuntimeError(f"the view did not answer at {url} in {timeout:g} s") from None
            time.sleep(0.2)


def view_rows(quick: bool, log=print) -> list[Row]:
    phase_s = 8.0 if quick else 15.0
    repeats = 2 if quick else 3
    config = scaled_config(480, 640)
    n_pre = PRERENDER[480]
    config = msgspec.structs.replace(
        config, service=msgspec.structs.replace(config.service, prerender=n_pre)
    )
    p50: dict[bool, list[float]] = {False: [], True: []}
    p99: dict[bool, list[float]] = {False: [], True: []}
    pictures_per_s: list[float] = []
    with (
        tempfile.TemporaryDirectory(prefix="ovis-bench-") as tmp,
        Bench(Path(tmp), config, PIPELINE, prerender=n_pre) as bench,
    ):
        for _ in range(repeats):
            for with_view in (False, True):
                browsers = None
                if with_view:
                    port = free_port()
                    bench.fleet.start(
                        "view",
                        [
                            "view",
                            "--connect",
                            bench.endpoint,
                            "--arena",
                            ARENA,
                            "--listen",
                            f"127.0.0.1:{port}",
                            *off_path_option(bench.cpus),  # as `ovis up --view` places it
                        ],
                    )
                    _wait_http(f"http://127.0.0.1:{port}/api/state")
                    browsers = Browsers(f"ws://127.0.0.1:{port}/ws", CLIENTS)
                log(f"  {'with' if with_view else 'without'} the view, {phase_s:g} s")
                t0 = time.monotonic()
                step = bench.run_capture(LATENCY_FPS, phase_s, log)
                if browsers is not None:
                    got = browsers.close()
                    pictures_per_s.append(got / CLIENTS / (time.monotonic() - t0))
                    bench.fleet.stop("view")
                p50[with_view].append(step.latency.p50)
                p99[with_view].append(step.latency.p99)
    shown = float(np.median(pictures_per_s)) if pictures_per_s else 0.0
    setup = (
        f"`ovis view` and {CLIENTS} browsers taking its pictures ({shown:.1f} pictures/s "
        f"each), floor: without the view, same run ({repeats} alternating phases of "
        f"{phase_s:g} s each)"
    )
    rows = []
    for which, samples in (("p50", p50), ("p99", p99)):
        value, floor = float(np.median(samples[True])), float(np.median(samples[False]))
        r = ratio(value, floor)
        judged = which == "p50"  # the target is on the median; p99 is reported
        rows.append(
            Row(
                name=f"Live view: capture → obstacle latency {which} at {LATENCY_FPS:g} "
                f"frames/s with {setup}",
                unit="ms",
                value=value,
                floor=floor,
                ratio=r,
                target="ratio ≤ 1.05" if judged else None,
                met=bool(r <= 1.05) if judged and r is not None else None,
            )
        )
    return rows
