"""The five services on loopback Zenoh for the integration tests: start them (each as
`ovis run`, or all through `ovis up`), record what they publish, score it against the
simulator's ground truth."""

from __future__ import annotations

import contextlib
import json
import re
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import zenoh
from zenoh_helpers import alive, client, free_port, ovis_cmd, spawn, stop, wait_for

from ovis.common.analysis.evaluation import match_objects
from ovis.common.messages import ObstacleFrame, TruthFrame, decode

STAGES = ("capture", "preprocess", "label", "pose", "calibrator")


class Recorder:
    """Collects obstacle and truth messages from a client session."""

    def __init__(self, session: zenoh.Session, arena: str = "default") -> None:
        self.obstacles: list[ObstacleFrame] = []
        self.truth: dict[int, TruthFrame] = {}
        self.receipt: list[float] = []
        self.lock = threading.Lock()
        session.declare_subscriber(f"ovis/{arena}/obstacles", self._obs)
        session.declare_subscriber(f"ovis/{arena}/truth", self._truth)

    def _obs(self, sample: zenoh.Sample) -> None:
        msg = decode(sample.payload.to_bytes(), ObstacleFrame)
        with self.lock:
            self.obstacles.append(msg)
            self.receipt.append(time.monotonic())

    def _truth(self, sample: zenoh.Sample) -> None:
        msg = decode(sample.payload.to_bytes(), TruthFrame)
        with self.lock:
            self.truth[msg.seq] = msg

    def since(self, n: int) -> list[ObstacleFrame]:
        with self.lock:
            return list(self.obstacles[n:])

    def count(self) -> int:
        with self.lock:
            return len(self.obstacles)


def errors_of(msgs: list[ObstacleFrame], truth: dict[int, TruthFrame]) -> tuple[list, int, int]:
    """Position errors (cm) of every matched object, and the objects missed and the
    spurious or mislabelled ones, over the messages whose truth is known."""
    errors, missed, spurious = [], 0, 0
    for m in msgs:
        t = truth.get(m.seq)
        if t is None:
            continue
        objs = ([m.robot] if m.robot else []) + m.obstacles
        acc = match_objects(objs, t.objects)
        errors.extend(acc.position_error_cm)
        missed += acc.missed
        spurious += acc.spurious + int((~acc.kind_correct).sum())
    return errors, missed, spurious


@dataclass
class Pipeline:
    endpoint: str
    session: zenoh.Session
    rec: Recorder
    procs: dict[str, subprocess.Popen[bytes]]
    tmp: Path
    config: Path


@contextlib.contextmanager
def running_pipeline(
    tmp: Path,
    service_toml: str = "",
    timeout: float = 60,
    *,
    config_text: Callable[[str], str] | None = None,
    stages: tuple[str, ...] = STAGES,
) -> Iterator[Pipeline]:
    """`ovis router` plus each stage as its own `ovis run` process, with ``service_toml``
    lines added to the [service] table (or the configuration ``config_text(endpoint)``);
    yields once obstacles flow (with the calibrator among ``stages``: calibrated ones).
    On exit every process is stopped and no stage log may hold a traceback."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = tmp / "config.toml"
    config.write_text(
        config_text(endpoint)
        if config_text is not None
        else f'preset = "default"\n[service]\n{service_toml}\nstate_dir = "{tmp / "state"}"\n'
        f'[zenoh]\nconnect = ["{endpoint}"]\n'
    )
    procs = {"router": spawn(ovis_cmd("router", "--listen", endpoint), tmp / "router.log")}
    for stage in stages:
        procs[stage] = spawn(ovis_cmd("run", stage, "--config", str(config)), tmp / f"{stage}.log")
    least = 1 if "calibrator" in stages else 0
    try:
        with client(endpoint) as session:
            wait_for(lambda: alive(session) >= set(stages), timeout, f"{stages} alive")
            rec = Recorder(session)
            wait_for(
                lambda: any(m.calibration_version >= least for m in rec.since(0)),
                timeout,
                "obstacle messages" + (" made with the initial calibration" if least else ""),
            )
            yield Pipeline(endpoint, session, rec, procs, tmp, config)
    finally:
        stop([p for n, p in procs.items() if n != "router"])
        stop([procs["router"]])
    for stage in stages:
        log = (tmp / f"{stage}.log").read_text()
        assert "Traceback" not in log, f"{stage} log:\n{log}"


def start_up(tmp: Path, *args: str) -> tuple[subprocess.Popen[bytes], str, Path]:
    """`ovis up --json` on a free port with its state in ``tmp``; returns the process,
    the router endpoint and the file its stderr goes to."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    err = tmp / "up.err"
    with open(err, "wb") as fh:
        proc = subprocess.Popen(
            ovis_cmd(
                "up", "--listen", endpoint, "--state-dir", str(tmp / "state"), "--json", *args
            ),
            stdout=subprocess.PIPE,
            stderr=fh,
        )
    return proc, endpoint, err


def run_up(tmp: Path, *args: str, timeout: float = 180) -> tuple[int, dict | None, str, float]:
    """`ovis up --json --pin none` (as :func:`start_up`) to its end: exit code, summary,
    stderr, seconds it took."""
    t0 = time.monotonic()
    proc, _, err = start_up(tmp, "--pin", "none", *args)
    out, _ = proc.communicate(timeout=timeout)
    text = out.decode().strip()
    return (
        proc.returncode,
        json.loads(text) if text else None,
        err.read_text(),
        time.monotonic() - t0,
    )


def up_log_dir(err: Path) -> str:
    """The folder of the children's logs that `ovis up` names on stderr."""
    m = re.search(r"logs in (\S+)", err.read_text())
    assert m, err.read_text()
    return m.group(1)
