"""`ovis up` on the shared real photos, as a user runs it: the frame size comes from the
source and is checked against the calibration at start (used, scaled, or refused with
both sizes), a real source needs a calibration of its own, a start that fails is exit 2
within 10 s with one line, a run with nothing usable is exit 3 with the reason, one run
per router endpoint; and the client commands give up (exit 4) or stop on a signal."""

from __future__ import annotations

import contextlib
import json
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import msgspec
import pytest
from cli_helpers import assert_one_line_error, ovis
from pipeline_helpers import Recorder, run_up, start_up
from real_photos import photo_calibration, photo_paths
from zenoh_helpers import client, free_port, ovis_cmd, wait_for

from ovis.common.calibration.file import Calibration, calibration_from_config
from ovis.common.calibration.store import CalibrationStore
from ovis.common.config import load_config
from ovis.common.messages import CalibrationUpdate, ObstacleFrame, encode
from ovis.common.recording.calibration import adopt_recorded_calibration
from ovis.common.recording.session import SessionWriter
from ovis.services.cli.errors import UserError
from ovis.services.cli.startup import calibration_for_run

# long: minutes of work, started early so the run ends with both workers busy
pytestmark = pytest.mark.long

#: A start that fails says so within this long (the issue's bound).
START_FAILS_S = 10.0


@pytest.fixture(scope="module")
def real(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The photos as a source folder, the same photos resized to 1280x1024 and cropped
    to 640x480, and their calibration made as docs/real-camera.md says (the lens from
    the photos, the floor pose from the board in the first)."""
    tmp = tmp_path_factory.mktemp("real")
    folders = {name: tmp / name for name in ("photos", "big", "crop")}
    for folder in folders.values():
        folder.mkdir()
    for p in photo_paths():
        gray = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        shutil.copy(p, folders["photos"] / p.name)
        big = cv2.resize(gray, (1280, 1024), interpolation=cv2.INTER_LINEAR)
        cv2.imwrite(str(folders["big"] / p.name), big)
        cv2.imwrite(str(folders["crop"] / p.name), gray[16:496])
    _, calib = photo_calibration(tmp)
    return {**folders, "calib": calib}


@contextlib.contextmanager
def _never_left_running(proc: subprocess.Popen) -> Iterator[subprocess.Popen]:
    """The process, killed on the way out if the test failed before it ended."""
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def _start_failed(tmp: Path, *args: str) -> str:
    """`ovis up` that must fail at start: exit 2 within 10 s, one line; that line."""
    code, summary, err, took = run_up(tmp, "--duration", "30", *args, timeout=60)
    proc = subprocess.CompletedProcess([], code, "", err)
    assert_one_line_error(proc)
    assert code == 2 and summary is None, (code, err)
    assert took < START_FAILS_S, f"took {took:.1f} s: {err}"
    return err.strip()


def test_real_photos_run_with_their_calibration_and_bigger_ones_with_it_scaled(
    real, tmp_path: Path
) -> None:
    args = ["--duration", "6", "--fps", "10"]
    code, s, err, _ = run_up(tmp_path, "--source", str(real["photos"]), "--calibration",
                          str(real["calib"]), *args)  # fmt: skip
    assert code == 0, err
    assert "stored as version 1" in err and "640x480" not in err
    assert s["frames_processed"] > 0 and s["frames_processed"] <= s["frames_captured"]
    assert (s["calibration_version"], s["exit_code"], s["reason"], s["health"]) == (1, 0, "", {})
    # The same state folder, photos twice the size: its calibration (a real camera's,
    # the newest there) is scaled, said so, stored, and used.
    code, s, err, _ = run_up(tmp_path, "--source", str(real["big"]), *args)
    assert code == 0, err
    assert f"is for 640x512, {real['big']} delivers 1280x1024" in err, err
    assert "scaled by 2" in err and "stored as version 2" in err
    assert s["frames_processed"] > 0 and s["calibration_version"] == 2 and s["exit_code"] == 0
    stored = CalibrationStore(tmp_path / "state").latest()[0]
    assert (stored.camera.cols, stored.camera.rows) == (1280, 1024)


def test_frames_of_another_aspect_ratio_are_refused_naming_both_sizes(real, tmp_path) -> None:
    line = _start_failed(
        tmp_path, "--source", str(real["crop"]), "--calibration", str(real["calib"])
    )
    assert "640x480" in line and "640x512" in line and "calibrate on frames of this source" in line
    assert not (tmp_path / "state").exists()  # nothing stored


def test_a_real_source_without_its_own_calibration_is_refused(real, tmp_path) -> None:
    line = _start_failed(tmp_path, "--source", str(real["photos"]))
    assert "needs a calibration of its own camera" in line
    assert "ovis calibrate" in line and "--calibration" in line and "docs/real-camera.md" in line
    # the simulator's calibration in the state folder is not one for a real camera
    sim = calibration_from_config(load_config())
    CalibrationStore(tmp_path / "state").save(msgspec.structs.replace(sim, simulated=True))
    line = _start_failed(tmp_path, "--source", str(real["photos"]))
    assert "is the simulator's" in line


def _session_with(path: Path, calib: Calibration) -> Path:
    """A session file that carries ``calib`` (as the recorder writes the one in use)."""
    writer = SessionWriter(path, metadata={"arena": "default"})
    writer.bus("ovis/default/calibration", encode(CalibrationUpdate(calibration=calib)), 1, 1)
    writer.close()
    return path


def test_a_recording_runs_with_its_own_calibration_never_a_simulated_one_beside_it(
    tmp_path: Path,
) -> None:
    """`ovis up --source SESSION.mcap` takes the state folder's newest only if it is not
    the simulator's or it is the one the recording carries (adopted from it)."""
    cfg = load_config()
    sim = msgspec.structs.replace(calibration_from_config(cfg), simulated=True)
    real_cam = msgspec.structs.replace(calibration_from_config(cfg), source_image="board.jpg")

    def run_with(recording: Path, state: Path):
        service = msgspec.structs.replace(cfg.service, source=str(recording), state_dir=str(state))
        up = msgspec.structs.replace(cfg, service=service)
        adopt_recorded_calibration(recording, state)
        return calibration_for_run(up, None, None)[0]

    # the simulator's calibration was there before: the recording's is not adopted, and
    # the simulator's is not taken for the recorded camera's
    CalibrationStore(tmp_path / "sim-state").save(sim)
    with pytest.raises(UserError, match="is the simulator's"):
        run_with(_session_with(tmp_path / "real.mcap", real_cam), tmp_path / "sim-state")
    # an empty state folder gets the recording's own, which counts whatever made it
    from_sim = _session_with(tmp_path / "sim.mcap", sim)
    assert run_with(from_sim, tmp_path / "fresh") == sim


@pytest.mark.parametrize("source", ["nosuchdir", "empty", "notes.txt", "camera:9"])
def test_a_source_that_cannot_deliver_is_refused_at_start(tmp_path, source) -> None:
    (tmp_path / "empty").mkdir()
    (tmp_path / "notes.txt").write_text("not a video\n")
    spec = source if source.startswith("camera:") else str(tmp_path / source)
    line = _start_failed(tmp_path, "--source", spec)
    assert "nothing was started" in line
    expect = {"nosuchdir": "is not 'sim'", "empty": "holds no images", "notes.txt": "cannot open",
              "camera:9": "cannot open camera 9"}  # fmt: skip
    assert expect[source] in line, line


def test_a_source_gone_before_any_frame_is_exit_3_with_the_reason(real, tmp_path) -> None:
    """The folder is there at start (its first frame gives the size) and gone before
    the capture opens it: no frame, exit 3, the capture's reason on the terminal and in
    the summary, and a health that does not say ok."""
    folder = tmp_path / "photos"
    shutil.copytree(real["photos"], folder)
    proc, _, err = start_up(tmp_path, "--pin", "none", "--duration", "12", "--source",
                            str(folder), "--calibration", str(real["calib"]))  # fmt: skip
    with _never_left_running(proc):
        wait_for(lambda: "logs in" in err.read_text(), 30, "ovis up to pass its checks")
        folder.rename(tmp_path / "moved")
        out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 3, err.read_text()
    s = json.loads(out)
    assert (s["frames_captured"], s["frames_processed"], s["exit_code"]) == (0, 0, 3)
    assert s["reason"].startswith("no frame was captured: ") and str(folder) in s["reason"]
    assert s["health"]["run"] == "no frame processed"
    last = err.read_text().strip().splitlines()[-1]
    assert last.startswith("error: no frame was captured: ") and "logs in" in last


def test_a_second_up_on_a_taken_endpoint_stops_and_the_first_counts_only_its_own(
    tmp_path: Path,
) -> None:
    first, endpoint, err = start_up(tmp_path, "--pin", "none", "--duration", "18", "--fps", "10")
    with _never_left_running(first), client(endpoint) as session:
        rec = Recorder(session)
        wait_for(lambda: rec.count() >= 5, 60, "the first run's obstacles")
        t0 = time.monotonic()
        second = subprocess.run(
            ovis_cmd("up", "--listen", endpoint, "--state-dir", str(tmp_path / "b"),
                     "--duration", "5", "--json"),
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        took = time.monotonic() - t0
        # another system's frames on this bus (another stream): not the first's
        pub = session.declare_publisher("ovis/default/obstacles")
        for seq in range(300):
            pub.put(encode(ObstacleFrame(
                seq=seq, stamp_ns=time.time_ns(), published_ns=time.time_ns(),
                frame_age_ms=1.0, calibration_version=1, robot=None, obstacles=[],
                planner=[], stream="someone-else",
            )))  # fmt: skip
        out, _ = first.communicate(timeout=90)
    assert_one_line_error(second, endpoint, "--listen")
    assert second.returncode == 2 and second.stdout == "" and took < START_FAILS_S, took
    assert first.returncode == 0, err.read_text()
    s = json.loads(out)
    assert s["exit_code"] == 0 and 0 < s["frames_processed"] <= s["frames_captured"]
    assert s["frames_captured"] <= 10 * s["duration_s"] + 2  # its own camera's frames only


def _has_zenoh_threads(pid: int) -> bool:
    """Whether the process has started Zenoh's runtime (it is inside the connect)."""
    names = [p.read_text().strip() for p in Path(f"/proc/{pid}/task").glob("*/comm")]
    return any(n.startswith("net-") for n in names)


@pytest.mark.parametrize("command", ["watch", "status"])
def test_clients_with_no_router_exit_4_within_their_timeout(command) -> None:
    t0 = time.monotonic()
    proc = ovis(command, "--connect", f"tcp/127.0.0.1:{free_port()}", "--timeout", "3",
                check=False)  # fmt: skip
    took = time.monotonic() - t0
    assert_one_line_error(proc, "no router answered within 3 s", "--connect")
    # the timeout, plus the client's start (its imports: seconds when another test file
    # runs beside this one); without the timeout it would wait for ever
    assert proc.returncode == 4 and took < 3.0 + 2.5, took


@pytest.mark.parametrize(("command", "sig"), [("watch", signal.SIGINT), ("watch", signal.SIGTERM),
                                              ("status", signal.SIGINT)])  # fmt: skip
def test_a_signal_ends_a_client_waiting_for_its_router(command, sig) -> None:
    proc = subprocess.Popen(
        ovis_cmd(command, "--connect", f"tcp/127.0.0.1:{free_port()}", "--timeout", "60"),
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    with _never_left_running(proc):
        wait_for(lambda: _has_zenoh_threads(proc.pid), 30, f"ovis {command} to connect")
        time.sleep(0.5)
        t0 = time.monotonic()
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=10)
        took = time.monotonic() - t0
    assert took < 2.0, took
    assert "Traceback" not in err
    # watch: the user ended it (0); status: it was interrupted before any answer (130)
    assert proc.returncode == (0 if command == "watch" else 130), err
