"""Issue 28 item 6 on real filesystems: `ovis up` with its state folder on a full 256 KiB
tmpfs (with no room for its keys: exit 2; with its keys made earlier: it runs), then
the same folder remounted read-only, then an invalid newest calibration.
The calibrator stays alive (same pid, no restart), its status says `cannot save:
<reason>`, `ovis recalibrate` gets the reason (exit 3), it calibrates by itself once
there is room, keeps the calibration in use while the folder is read-only, and a
calibrator that finds an invalid newest version uses the newest valid one instead of
calibrating from scratch.

Mounting needs root (skipped with the reason otherwise). The bus is read by a client
that knows only Zenoh and MessagePack.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from bus_client import BusClient
from zenoh_helpers import free_port, ovis_cmd, spawn, stop, wait_for

from ovis.common.trust.keys import ROLES, load_or_create_private


def _mount(*args: str) -> None:
    subprocess.run(["mount", *args], check=True, capture_output=True, text=True)


@contextlib.contextmanager
def small_tmpfs(path: Path) -> Iterator[Path]:
    """A 256 KiB tmpfs at ``path`` (skips the test where it cannot be mounted)."""
    path.mkdir()
    try:
        _mount("-t", "tmpfs", "-o", "size=256k", "tmpfs", str(path))
    except (OSError, subprocess.CalledProcessError) as exc:
        reason = getattr(exc, "stderr", "") or exc
        pytest.skip(f"cannot mount a small tmpfs (needs root): {reason}")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=False)


def fill(folder: Path) -> Path:
    """Write a file in ``folder`` until the filesystem is full; the file."""
    filler = folder / "filler"
    with open(filler, "wb", buffering=0) as fh, contextlib.suppress(OSError):
        while True:
            fh.write(bytes(4096))
            os.fsync(fh.fileno())
    return filler


def recalibrate(endpoint: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ovis_cmd("recalibrate", "--connect", endpoint, "--timeout", "60"),
        capture_output=True,
        text=True,
        timeout=90,
    )


def test_a_full_then_read_only_state_folder_never_kills_the_calibrator(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with small_tmpfs(tmp_path / "state") as state:
        filler = fill(state)
        # no room for the keys of the proof of origin: nothing starts, one line says why
        t0 = time.monotonic()
        first = subprocess.run(
            ovis_cmd("up", "--listen", endpoint, "--no-live", "--state-dir", str(state)),
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert first.returncode == 2 and time.monotonic() - t0 < 10, first
        assert "cannot write the private key" in first.stderr, first.stderr
        assert "No space left on device" in first.stderr, first.stderr
        # the keys made while there was room (an earlier run), then the folder full again
        filler.unlink()
        for role in ROLES:
            load_or_create_private(state / "keys" / f"{role}.key")
        filler = fill(state)
        up = spawn(
            ovis_cmd(
                "up", "--listen", endpoint, "--no-live", "--fps", "15", "--state-dir", str(state)
            ),
            tmp_path / "up.log",
        )
        client = None
        try:
            client = wait_for(lambda: BusClient.connect(endpoint), 30, "the router of ovis up")
            full = wait_for(
                lambda: (
                    (st := client.status("calibrator"))
                    and st["state"].startswith("cannot save")
                    and st
                ),
                60,
                "the calibrator to say it cannot save",
            )
            assert full["state"] == f"cannot save: No space left on device in {state}", full
            assert full["reason"] == f"No space left on device in {state}"
            assert full["calibration_version"] == 0 and full["errors"]["cannot_save"] >= 1
            time.sleep(5)  # its first calibrations keep failing: it stays alive
            later = client.status("calibrator")
            assert (later["pid"], later["restarts"]) == (full["pid"], 0), later
            assert later["state"].startswith("cannot save")
            answer = recalibrate(endpoint)
            assert answer.returncode == 3, answer
            assert (
                f"recalibration failed: cannot save: No space left on device in {state}: "
                "free space there" in answer.stderr
            ), answer.stderr
            # room again: the calibrator calibrates by itself, saves and says ok
            filler.unlink()
            ok = wait_for(
                lambda: (
                    (st := client.status("calibrator"))
                    and st["calibration_version"] >= 1
                    and st["state"] == "ok"
                    and st
                ),
                60,
                "the first calibration once there is room",
            )
            assert ok["pid"] == full["pid"]
            assert (state / "calibration-v0001.json").exists()
            # read-only: the reply says so, the calibration in use stays
            _mount("-o", "remount,ro", str(state))
            answer = recalibrate(endpoint)
            assert answer.returncode == 3, answer
            assert f"cannot save: Read-only file system in {state}" in answer.stderr
            assert "the calibration in use stays v1@" in answer.stderr
            st = client.status("calibrator")
            assert st["state"] == f"cannot save: Read-only file system in {state}", st
            assert (st["pid"], st["calibration_version"]) == (full["pid"], 1)
            _mount("-o", "remount,rw", str(state))
            answer = recalibrate(endpoint)
            assert answer.returncode == 0, answer
            assert client.status("calibrator")["state"] == "ok"
        finally:
            if client is not None:
                client.close()
            stop([up], 30)
        log = (tmp_path / "up.log").read_text()
        logs = Path(log.split("logs in ", 1)[1].split()[0])
        assert "Traceback" not in (logs / "calibrator.log").read_text()
        assert (state / "calibration-v0002.json").exists()
        # An invalid newest version (a camera for another image size, hand-copied in):
        # a calibrator started on this folder uses v2, the newest valid one, saved again
        # as v4 (stages holding v3 take only a newer version).
        data = json.loads((state / "calibration-v0002.json").read_text())
        data["version"] = 3
        data["camera"]["rows"] = 100
        (state / "calibration-v0003.json").write_text(json.dumps(data))
        router = spawn(ovis_cmd("router", "--listen", endpoint), tmp_path / "router.log")
        calibrator = spawn(
            ovis_cmd("run", "calibrator", "--connect", endpoint, "--state-dir", str(state)),
            tmp_path / "calibrator.log",
        )
        client = None
        try:
            client = wait_for(lambda: BusClient.connect(endpoint), 30, "the router")
            st = wait_for(
                lambda: (st := client.status("calibrator")) and st["state"] != "starting" and st,
                30,
                "the calibrator to have started",
            )
            assert (st["state"], st["calibration_version"]) == ("ok", 4), st
            assert st["errors"] == {"bad_saved_calibration": 1}, st
            assert "calibration-v0003.json: calibration v3 refused" in st["last_error"]
            again = json.loads((state / "calibration-v0004.json").read_text())
            v2 = json.loads((state / "calibration-v0002.json").read_text())
            assert again["camera"] == v2["camera"], "v4 is v2 saved again"
        finally:
            if client is not None:
                client.close()
            stop([calibrator, router])
