"""The order `ovis up` stops its children in: the cameras first, then (after the frames
in flight had time to arrive) the stages, then the router: a recording or a last
obstacle message is not cut off by its own stage stopping before the frame came."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from ovis.services import supervisor

#: A child that, on SIGTERM, writes when it got the signal and exits 0.
CHILD = """
import signal, sys, time
out = sys.argv[1]
def stop(*_):
    open(out, "w").write(repr(time.monotonic()))
    sys.exit(0)
signal.signal(signal.SIGTERM, stop)
open(out + ".up", "w").close()
while True:
    time.sleep(0.01)
"""


def started(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, scripts: dict[str, str]
) -> supervisor.Supervisor:
    """A supervisor whose children (name → script) run and have said so."""

    def spawn(self, child: supervisor.Child, *, spare: bool = False) -> subprocess.Popen[bytes]:
        return subprocess.Popen(
            [sys.executable, "-c", scripts[child.name], str(tmp_path / child.name)]
        )

    monkeypatch.setattr(supervisor.Supervisor, "_spawn", spawn)
    fleet = supervisor.Supervisor(tmp_path)
    for name in scripts:
        fleet.start(name, [])
    deadline = time.monotonic() + 30
    while not all((tmp_path / f"{n}.up").exists() for n in scripts):
        assert time.monotonic() < deadline, "the children did not start"
        time.sleep(0.05)
    return fleet


def test_cameras_stop_first_then_the_stages_then_the_router(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    names = ("router", "preprocess", "recorder", "capture")
    fleet = started(tmp_path, monkeypatch, dict.fromkeys(names, CHILD))
    codes = fleet.stop(sources=("capture",))
    assert codes == dict.fromkeys(("capture", "router", "preprocess", "recorder"), 0)
    at = {n: float((tmp_path / n).read_text()) for n in names}
    # The stages get the signal once the camera has gone and the drain time has passed;
    # the recorder once they have stopped (their last messages recorded), the router last.
    assert at["preprocess"] - at["capture"] >= supervisor.DRAIN_S
    assert at["capture"] < at["preprocess"] < at["recorder"] < at["router"]


def test_a_recorder_slow_to_write_its_file_is_given_its_time_not_killed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A recorder still writing when the stages' 5 s are over (its backlog on a busy
    machine) finishes: SIGKILL would leave its recording without an index."""
    slow = CHILD.replace("sys.exit(0)", "time.sleep(1.5); sys.exit(0)")
    fleet = started(tmp_path, monkeypatch, {"preprocess": CHILD, "recorder": slow})
    assert fleet.stop(timeout=0.5) == {"preprocess": 0, "recorder": 0}


def test_a_child_that_gave_up_does_not_hide_another_that_exited_abnormally(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    scripts = {
        "label": "import sys; sys.exit(1)",  # dies at once: with no restarts, given up
        "pose": CHILD.replace("sys.exit(0)", "sys.exit(2)"),  # exits 2 when stopped
        "preprocess": CHILD,
    }

    def spawn(self, child: supervisor.Child, *, spare: bool = False) -> subprocess.Popen[bytes]:
        return subprocess.Popen(
            [sys.executable, "-c", scripts[child.name], str(tmp_path / child.name)]
        )

    monkeypatch.setattr(supervisor.Supervisor, "_spawn", spawn)
    fleet = supervisor.Supervisor(tmp_path, max_restarts=0)
    for name in scripts:
        fleet.start(name, [])
    deadline = time.monotonic() + 30
    while not (
        fleet.gave_up() and all((tmp_path / f"{n}.up").exists() for n in ("pose", "preprocess"))
    ):
        assert time.monotonic() < deadline, "the children did not start, or label did not die"
        fleet.supervise()
        time.sleep(0.05)
    codes = fleet.stop()
    assert codes == {"label": 1, "pose": 2, "preprocess": 0}
    gave_up = "label died (exit code 1) and used its restart budget (0 in 60 s): left stopped"
    assert fleet.failures(codes) == [gave_up, "process(es) pose (exit code 2) exited abnormally"]
