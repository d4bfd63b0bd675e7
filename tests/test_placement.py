"""Where the services run: Zenoh peers on the router's machine, the frame path on one
core (``ovis up --pin``, ``ovis run --cpus``, ``[service] cpus``)."""

from __future__ import annotations

import logging
import os
import subprocess
import time
from pathlib import Path

import pytest
from zenoh_helpers import free_port, ovis_cmd

from ovis.common.config import ZenohConfig, config_from_dict
from ovis.services.bus import LOOPBACK_PEER, local_peers
from ovis.services.placement import cpus_option, pick_cpus, pin_to_cpus

ALLOWED = sorted(os.sched_getaffinity(0))


def test_services_beside_the_router_are_loopback_peers() -> None:
    zc = local_peers(ZenohConfig(connect=["tcp/127.0.0.1:7447"]))
    assert (zc.mode, zc.listen, zc.connect) == ("peer", [LOOPBACK_PEER], ["tcp/127.0.0.1:7447"])
    # A configuration that chose its own transport (TLS file, mode, listeners) is kept.
    for own in (
        ZenohConfig(config_file="deploy/zenoh/client.json5"),
        ZenohConfig(mode="peer"),
        ZenohConfig(listen=["tcp/127.0.0.1:7000"]),
    ):
        assert local_peers(own) == own


def test_pick_cpus() -> None:
    assert pick_cpus("none") == []
    assert pick_cpus("auto") == (ALLOWED[-1:] if len(ALLOWED) >= 2 else [])
    assert pick_cpus(f" {ALLOWED[0]} ") == [ALLOWED[0]]
    assert pick_cpus(",".join(map(str, reversed(ALLOWED)))) == ALLOWED
    with pytest.raises(ValueError, match="expected 'auto', 'none' or core numbers"):
        pick_cpus("fast")
    with pytest.raises(ValueError, match="not available"):
        pick_cpus(str(max(ALLOWED) + 1))
    with pytest.raises(ValueError, match="expected 'auto', 'none' or core numbers"):
        pick_cpus(",")
    assert cpus_option("label", [1]) == ["--cpus", "1"]
    assert cpus_option("pose", []) == ["--cpus", "none"]
    assert cpus_option("calibrator", [1]) == []


def test_config_refuses_bad_core_numbers() -> None:
    with pytest.raises(Exception, match="cpus"):
        config_from_dict({"service": {"cpus": [-1]}}, "test")
    assert config_from_dict({"service": {"cpus": [0]}}, "test").service.cpus == [0]


def test_a_core_the_machine_lacks_is_logged_and_ignored(caplog) -> None:
    before = os.sched_getaffinity(0)
    with caplog.at_level(logging.WARNING):
        assert not pin_to_cpus([4095], logging.getLogger("test"))
    assert os.sched_getaffinity(0) == before
    assert "cannot pin to cores [4095]" in caplog.text
    assert not pin_to_cpus([], logging.getLogger("test"))


def _allowed_cpus(pid: int) -> str:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("Cpus_allowed_list:"):
            return line.split(":", 1)[1].strip()
    raise AssertionError("no Cpus_allowed_list")


def test_ovis_run_cpus_pins_the_process_and_its_threads(tmp_path: Path) -> None:
    core = ALLOWED[-1]
    # No router at this port: the service pins itself, then waits for one.
    proc = subprocess.Popen(
        ovis_cmd(
            "run", "preprocess", "--connect", f"tcp/127.0.0.1:{free_port()}", "--cpus", str(core)
        ),
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 30
        threads: list[Path] = []
        while time.monotonic() < deadline:  # until pinned and Zenoh's runtime is up
            threads = list(Path(f"/proc/{proc.pid}/task").glob("*"))
            if _allowed_cpus(proc.pid) == str(core) and len(threads) > 4:
                break
            time.sleep(0.2)
        time.sleep(1.0)
        assert proc.poll() is None
        assert _allowed_cpus(proc.pid) == str(core)
        for task in Path(f"/proc/{proc.pid}/task").glob("*"):
            status = (task / "status").read_text()
            assert f"Cpus_allowed_list:\t{core}\n" in status
    finally:
        proc.terminate()
        proc.wait(10)


def test_bad_cpus_is_a_one_line_usage_error() -> None:
    proc = subprocess.run(
        ovis_cmd("run", "label", "--cpus", "99999"), capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "not available" in lines[0], proc.stderr


@pytest.mark.skipif(len(ALLOWED) < 2, reason="needs two cores: one for the frame path")
def test_a_spare_imports_off_the_frame_path_and_takes_its_core_when_activated(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``ovis up``'s spare of a pinned stage waits on the other cores (its imports must not
    take the running frame path's core) and moves to the stage's core once it replaces a
    stage that died."""
    from ovis.services import supervisor

    monkeypatch.setattr(supervisor, "SPARE_AFTER_S", 0.0)
    path_core, off = ALLOWED[-1], ALLOWED[:-1]
    fleet = supervisor.Supervisor(tmp_path)
    args = ["run", "preprocess", "--connect", f"tcp/127.0.0.1:{free_port()}"]
    fleet.start("preprocess", [*args, "--cpus", str(path_core)], standby=True, spare_cpus=off)
    child = fleet.children["preprocess"]
    try:
        deadline = time.monotonic() + 30
        while child.spare is None and time.monotonic() < deadline:
            fleet.supervise()
            time.sleep(0.05)
        assert child.spare is not None
        spare = child.spare.pid
        assert _allowed_cpus(spare) == ",".join(map(str, off))
        time.sleep(2.0)  # importing, then waiting: still off the frame path
        assert _allowed_cpus(spare) == ",".join(map(str, off))
        child.proc.kill()
        while child.proc.pid != spare and time.monotonic() < deadline:
            fleet.supervise()
            time.sleep(0.05)
        assert child.proc.pid == spare
        while _allowed_cpus(spare) != str(path_core) and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(1.0)  # Zenoh's threads, started after the pin, inherit it
        for task in Path(f"/proc/{spare}/task").glob("*"):
            assert f"Cpus_allowed_list:\t{path_core}\n" in (task / "status").read_text()
    finally:
        fleet.stop()
