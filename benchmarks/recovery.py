"""Recovery from a killed stage (issue 15).

``ovis up`` (simulated arena, 30 fps) runs as a child; this process subscribes to the
obstacles and the ground truth over Zenoh. Each stage of the frame path is SIGKILLed in
turn; for each kill: the time from the kill to the first obstacle message of a frame
captured after it (the stream is back), and the frames lost (ground truths published
in between whose obstacles never came). The floor is the frame period: a stream can
not come back faster than the next frame.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from statistics import median

import msgspec
import zenoh

from benchmarks.bus import free_port
from benchmarks.core import Row
from ovis.common.config import ZenohConfig
from ovis.common.messages import Topics
from ovis.common.pipeline.restarts import BACKOFF_START_S, HEALTHY_S
from ovis.services.bus import zenoh_config
from ovis.services.cli.watching import query_statuses
from ovis.services.supervisor import SPARE_AFTER_S

__all__ = ["recovery_rows"]

FPS = 30.0
VICTIMS = ("preprocess", "label", "pose")
#: The stream must be back within this after a kill (s).
TARGET_S = 1.5


class _Seq(msgspec.Struct):
    seq: int


class _Arrivals:
    """Obstacle and truth sequence numbers, with this process's receipt time."""

    def __init__(self) -> None:
        self.obstacles: list[tuple[float, int]] = []
        self.truths: list[tuple[float, int]] = []
        self.lock = threading.Condition()  # notified at every arrival
        self._decode = msgspec.msgpack.Decoder(_Seq)

    def wait(self, predicate, timeout: float, what: str):
        """Until ``predicate()`` (called with the lock held) is true: its value."""
        with self.lock:
            value = self.lock.wait_for(predicate, timeout)
        if not value:
            raise RuntimeError(f"timed out after {timeout:g} s waiting for {what}")
        return value

    def listener(self, store: list[tuple[float, int]]):
        def on_sample(sample: zenoh.Sample) -> None:
            try:
                seq = self._decode.decode(sample.payload.to_bytes()).seq
            except msgspec.MsgspecError:
                return
            with self.lock:
                store.append((time.monotonic(), seq))
                self.lock.notify_all()

        return on_sample


def _pid_of(session: zenoh.Session, stage: str) -> int | None:
    """The pid of the stage's running process, from its status (a spare that took over
    has the command line of a spare)."""
    status = query_statuses(session, Topics("default"), timeout=2.0).get(stage)
    return status.pid if status is not None else None


def _connect(endpoint: str, timeout: float = 30.0) -> zenoh.Session:
    """A client session of ``ovis up``'s router, once it listens."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return zenoh.open(zenoh_config(ZenohConfig(connect=[endpoint]), wait=False))
        except zenoh.ZError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


def measure_kills(rounds: int, log=print) -> list[tuple[str, float, int]]:
    """(stage, seconds until the stream is back, frames lost) for each kill."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    state = tempfile.mkdtemp(prefix="ovis-recovery-")
    up = subprocess.Popen(
        [sys.executable, "-m", "ovis.services.cli", "up", "--listen", endpoint, "--json",
         "--fps", str(FPS), "--state-dir", state, "--max-restarts", "100"],
        stdout=subprocess.DEVNULL,
        stderr=open(Path(state) / "up.err", "wb"),  # noqa: SIM115 (the child keeps it)
    )  # fmt: skip
    results: list[tuple[str, float, int]] = []
    try:
        arrivals = _Arrivals()
        session = _connect(endpoint)
        try:
            session.declare_subscriber(
                "ovis/default/obstacles", arrivals.listener(arrivals.obstacles)
            )
            session.declare_subscriber("ovis/default/truth", arrivals.listener(arrivals.truths))
            arrivals.wait(lambda: len(arrivals.obstacles) > 60, 120, "obstacles from ovis up")
            for k in range(rounds):
                stage = VICTIMS[k % len(VICTIMS)]
                time.sleep(SPARE_AFTER_S + 1.0)  # steady state, its spare ready
                pid = _pid_of(session, stage)
                if pid is None:
                    raise RuntimeError(f"no {stage} process under ovis up")
                with arrivals.lock:
                    last_truth = arrivals.truths[-1][1]
                os.kill(pid, signal.SIGKILL)
                t_kill = time.monotonic()

                def back(t_kill=t_kill, last_truth=last_truth) -> tuple[float, int] | None:
                    after = ((t, s) for t, s in arrivals.obstacles if t > t_kill)
                    return next(((t, s) for t, s in after if s > last_truth), None)

                t_back, seq_back = arrivals.wait(back, 30, f"obstacles after killing {stage}")
                time.sleep(1.0)
                with arrivals.lock:
                    sent = {s for t, s in arrivals.truths if last_truth < s <= seq_back}
                    got = {s for _, s in arrivals.obstacles}
                lost = len(sent - got)
                results.append((stage, t_back - t_kill, lost))
                log(f"  killed {stage}: stream back in {t_back - t_kill:.2f} s, {lost} frames lost")
        finally:
            session.close()
    finally:
        up.send_signal(signal.SIGTERM)
        try:
            up.wait(60)
        except subprocess.TimeoutExpired:
            up.kill()
            up.wait()
    return results


def recovery_rows(quick: bool, log=print) -> list[Row]:
    """The first kill of each stage (restarted at once, from its spare), and with the
    full run a second kill of each within ``HEALTHY_S``: that restart waits for the
    back-off (``BACKOFF_START_S``), the cost of a stage that keeps dying."""
    results = measure_kills(len(VICTIMS) if quick else 2 * len(VICTIMS), log)
    first, again = results[: len(VICTIMS)], results[len(VICTIMS) :]
    back = [s for _, s, _ in first]
    lost = [n for _, _, n in first]
    worst = max(back)
    period = 1.0 / FPS
    rows = [
        Row(
            name=f"Recovery: a killed stage's stream back, worst of the first kill of each "
            f"of {', '.join(VICTIMS)} (ovis up, {FPS:g} fps; floor: the frame period)",
            unit="s",
            value=worst,
            floor=period,
            ratio=worst / period,
            target=f"< {TARGET_S:g} s",
            met=worst < TARGET_S,
        ),
        Row(
            name=f"Recovery: frames lost per kill (median of the first kills; worst "
            f"{max(lost)}) at {FPS:g} fps",
            unit="frames",
            value=float(median(lost)),
        ),
    ]
    if again:
        rows.append(
            Row(
                name=f"Recovery: stream back after a second kill within {HEALTHY_S:g} s "
                f"(worst of {len(again)}; the restart waits the {BACKOFF_START_S:g} s "
                f"back-off; median frames lost {median(n for _, _, n in again):g})",
                unit="s",
                value=max(s for _, s, _ in again),
            )
        )
    return rows
