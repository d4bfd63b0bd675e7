"""docs/real-camera.md, run as written: every ``console`` block of the walkthrough
(marked ``<!-- test: NAME -->``) is parsed from the page and its ``$ ovis …`` lines run
as real processes, on the shared real photos, in a folder holding the files the page
names: ``photos/`` (13 photos), ``floor.jpg`` (the 14th), ``frames/`` (all 14),
``run.avi`` (the 14 as an MJPG video) and ``frames-640x480/`` (cropped). The lines the
page shows under a command must be in what it printed (``…``: anything). So the page and
the test cannot drift apart.

What the test changes, and nothing else: ``ovis up`` gets its own router port
(``--listen``, never 7447) and ``--json`` (the summary, to read it), ``ovis watch`` and
``ovis status`` the same port (``--connect``); ``ovis up`` runs as a shell job (a process
group of its own) and is ended as Ctrl-C ends one: SIGINT to the group; the terminal is
wide (``COLUMNS=200``); the page's network camera is a local MJPEG server of the photos
(tests/mjpeg_server.py) and the web view listens on a free port (``OVIS_VIEW_LISTEN``).
Printed addresses are mapped back to the page's before comparing."""

from __future__ import annotations

import contextlib
import json
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import time
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pytest
from cli_helpers import assert_one_line_error
from mjpeg_server import mjpeg_camera
from real_photos import photo_paths
from zenoh_helpers import free_port, ovis_cmd, wait_for

from ovis.services.supervisor import die_with_parent

# alone: the page's commands run as written, with their default timeouts (`ovis watch`
# gives its router 5 s); at a neighbour's lower priority a client's start alone took
# longer than that in CI
pytestmark = pytest.mark.alone

DOC = Path(__file__).resolve().parents[1] / "docs" / "real-camera.md"
#: What the page calls the network camera, the router and the web view.
DOC_STREAM = "http://192.168.1.20:8080/stream"
DOC_ENDPOINT = "tcp/127.0.0.1:7447"
DOC_VIEW = "127.0.0.1:8080"
#: The marked console blocks of the page, and every console block.
MARKED = re.compile(r"^<!-- test: ([\w-]+) -->\n```console\n(.*?)^```", re.M | re.S)
CONSOLE = re.compile(r"^```console$", re.M)
#: The blocks this file runs, each in the test named after its step.
RUN = {
    *("lens", "floor", "locate", "detect", "floor-arena", "locate-arena"),
    *("up-frames", "watch", "status", "second-up", "up-video", "up-stream", "status-lost"),
    *("no-calibration", "wrong-size", "no-camera"),
}
#: The issue's bound for a start that fails.
START_FAILS_S = 10.0
#: The five services of `ovis up`.
SERVICES = ("capture", "preprocess", "label", "pose", "calibrator")


@dataclass(frozen=True)
class Command:
    """One ``$`` line of the page and the output lines it shows under it."""

    line: str
    shown: tuple[str, ...]


def doc_blocks(text: str) -> dict[str, list[Command]]:
    """The page's marked console blocks by name: their commands, in order."""
    blocks: dict[str, list[Command]] = {}
    for name, body in MARKED.findall(text):
        assert name not in blocks, f"two console blocks are marked {name!r}"
        commands: list[Command] = []
        for line in body.splitlines():
            if line.startswith("$ "):
                commands.append(Command(line[2:], ()))
            elif line.strip():
                assert commands, f"block {name!r} shows output before any command"
                commands[-1] = Command(commands[-1].line, (*commands[-1].shown, line))
        blocks[name] = commands
    return blocks


BLOCKS = doc_blocks(DOC.read_text("utf-8"))


@dataclass
class Place:
    """Where the commands run (``cwd``), on which router port, camera and view."""

    cwd: Path
    endpoint: str = field(default_factory=lambda: f"tcp/127.0.0.1:{free_port()}")
    stream: str = DOC_STREAM
    view: str = DOC_VIEW

    def argv(self, command: Command) -> list[str]:
        words = shlex.split(command.line.replace(DOC_STREAM, self.stream))
        assert words[0] == "ovis", command.line
        extra = {
            "up": ["--listen", self.endpoint, "--json"],
            "watch": ["--connect", self.endpoint],
            "status": ["--connect", self.endpoint],
        }
        return ovis_cmd(*words[1:], *extra.get(words[1], []))

    def env(self) -> dict[str, str]:
        return {**os.environ, "COLUMNS": "200", "OVIS_VIEW_LISTEN": self.view}

    def as_in_doc(self, text: str) -> str:
        """``text`` with this place's addresses written as the page writes them."""
        for real, doc in ((self.endpoint, DOC_ENDPOINT), (self.stream, DOC_STREAM),
                          (self.view, DOC_VIEW)):  # fmt: skip
            text = re.sub(re.escape(real) + r"(?!\d)", doc, text)
        return text

    def run(self, command: Command, timeout: float = 120) -> subprocess.CompletedProcess[str]:
        """Run one command to its end; what it printed must hold what the page shows."""
        proc = subprocess.run(self.argv(command), cwd=self.cwd, env=self.env(),
                              capture_output=True, text=True, timeout=timeout)  # fmt: skip
        assert "Traceback" not in proc.stderr, proc.stderr
        assert_shown(command, self.as_in_doc(proc.stdout + proc.stderr))
        return proc

    def ok(self, command: Command, timeout: float = 120) -> subprocess.CompletedProcess[str]:
        proc = self.run(command, timeout)
        assert proc.returncode == 0, f"`{command.line}`: {proc.returncode}\n{proc.stderr}"
        return proc


def assert_shown(command: Command, printed: str) -> None:
    """Each output line the page shows under ``command`` is in ``printed`` (whitespace
    as the terminal wraps it does not count; ``…`` in a line stands for anything)."""
    flat = " ".join(printed.split())
    for line in command.shown:
        want = " ".join(line.split())
        if want == "…":
            continue
        pattern = ".*?".join(re.escape(part) for part in want.split("…"))
        assert re.search(pattern, flat), (
            f"docs/real-camera.md shows {line!r} under `{command.line}`; it printed:\n{printed}"
        )


def block(name: str) -> list[Command]:
    assert name in RUN and name in BLOCKS, name
    return BLOCKS[name]


def test_every_console_block_of_the_page_is_marked_and_run() -> None:
    text = DOC.read_text("utf-8")
    assert len(CONSOLE.findall(text)) == len(MARKED.findall(text)), (
        "a console block of docs/real-camera.md has no <!-- test: NAME --> line"
    )
    assert set(BLOCKS) == RUN
    for commands in BLOCKS.values():
        assert commands and all(c.line.startswith("ovis ") for c in commands)


def test_the_checker_catches_a_line_the_command_did_not_print() -> None:
    shown = Command("ovis x", ("wrote CAM.yaml", "RMS … px over 13 views", "…"))
    assert_shown(shown, "RMS 0.1249 px over\n 13 views\nwrote CAM.yaml\n")
    with pytest.raises(AssertionError, match="RMS"):
        assert_shown(shown, "RMS 0.1249 px over 12 views\nwrote CAM.yaml\n")


# --- the files a user makes ------------------------------------------------------------------


def _video(paths: list[Path], out: Path) -> None:
    """The photos as an MJPG video, checked to read back as the photos."""
    writer = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (640, 512))
    assert writer.isOpened()
    greys = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths]
    for grey in greys:
        writer.write(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR))
    writer.release()
    cap = cv2.VideoCapture(str(out))
    back = []
    while (got := cap.read())[0]:
        back.append(cv2.cvtColor(got[1], cv2.COLOR_BGR2GRAY))
    cap.release()
    assert len(back) == len(greys) and back[0].shape == (512, 640)
    for grey, frame in zip(greys, back, strict=True):
        assert np.abs(grey.astype(int) - frame).mean() < 5.0  # JPEG's loss only


@pytest.fixture(scope="module")
def home(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A user's folder: the photos, the floor photo, frames, a video, cropped frames."""
    home = tmp_path_factory.mktemp("walkthrough")
    paths = photo_paths()
    for name in ("photos", "frames", "frames-640x480"):
        (home / name).mkdir()
    for p in paths:
        shutil.copy(p, home / "frames" / p.name)
        grey = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        cv2.imwrite(str(home / "frames-640x480" / p.name), grey[16:496])
    for p in paths[:13]:
        shutil.copy(p, home / "photos" / p.name)
    shutil.copy(paths[13], home / "floor.jpg")
    _video(paths, home / "run.avi")
    return home


@pytest.fixture(scope="module")
def calibrated(home: Path) -> Path:
    """Steps 1 and 2: CAM.yaml and calib.json in ``home``."""
    place = Place(home)
    (lens,) = block("lens")
    (floor,) = block("floor")
    place.ok(lens)
    place.ok(floor)
    return home


def _place(calibrated: Path, tmp: Path, *names: str) -> Place:
    """A fresh folder (no ovis-state yet) holding ``names`` of the user's folder."""
    for name in names:
        (tmp / name).symlink_to(calibrated / name)
    return Place(tmp)


# --- steps 1 to 4: offline -------------------------------------------------------------------


def test_steps_1_and_2_the_lens_and_the_floor_pose_from_the_photos(calibrated: Path) -> None:
    fs = cv2.FileStorage(str(calibrated / "CAM.yaml"), cv2.FILE_STORAGE_READ)
    size = (fs.getNode("image_width").real(), fs.getNode("image_height").real())
    fx = fs.getNode("camera_matrix").mat()[0, 0]
    fs.release()
    assert size == (640, 512) and 500 < fx < 530
    calib = json.loads((calibrated / "calib.json").read_text())
    assert (calib["camera"]["cols"], calib["camera"]["rows"]) == (640, 512)


def test_steps_3_and_4_locate_the_board_corners_and_detect_one_frame(calibrated: Path) -> None:
    place = Place(calibrated)
    (locate,) = block("locate")
    out = place.ok(locate).stdout
    xy = [tuple(map(float, m)) for m in re.findall(r"x (\S+) cm, y (\S+) cm", out)]
    # the board's first and last inner corners: (0, 0) and (8, -5) squares of 2.5 cm
    assert np.allclose(xy, [(0.0, 0.0), (20.0, -12.5)], atol=0.03), xy
    (detect,) = block("detect")
    place.ok(detect)


def test_step_2_the_board_placed_in_the_arena(calibrated: Path) -> None:
    """The board said to lie with its origin corner at (40, 30) cm and its first row along
    the arena's +x: the same corners come back at arena positions."""
    place = Place(calibrated)
    (floor,) = block("floor-arena")
    place.ok(floor)
    (locate,) = block("locate-arena")
    out = place.ok(locate).stdout
    xy = [tuple(map(float, m)) for m in re.findall(r"x (\S+) cm, y (\S+) cm", out)]
    assert np.allclose(xy, [(40.0, 30.0), (60.0, 17.5)], atol=0.03), xy


# --- step 5: live ----------------------------------------------------------------------------


def _router_listens(endpoint: str) -> bool:
    host, port = endpoint.removeprefix("tcp/").rsplit(":", 1)
    with socket.socket() as s, contextlib.suppress(OSError):
        s.settimeout(0.5)
        s.connect((host, int(port)))
        return True
    return False


@contextlib.contextmanager
def live(place: Place, command: Command) -> Iterator[subprocess.Popen[bytes]]:
    """``ovis up`` started as the page says, as a shell job (a process group of its own),
    once its router listens; killed on the way out if the test failed before it ended."""
    err = place.cwd / "up.err"
    with open(err, "wb") as fh:
        proc = subprocess.Popen(place.argv(command), cwd=place.cwd, env=place.env(),
                                stdout=subprocess.PIPE, stderr=fh, start_new_session=True,
                                preexec_fn=die_with_parent)  # fmt: skip
    try:
        wait_for(lambda: proc.poll() is not None or _router_listens(place.endpoint), 60,
                 "ovis up's router")  # fmt: skip
        assert proc.poll() is None, err.read_text()
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def ctrl_c(place: Place, command: Command, proc: subprocess.Popen[bytes]) -> dict:
    """End ``ovis up`` as Ctrl-C in its terminal does (SIGINT to its process group): its
    summary, after what the page shows is checked."""
    os.killpg(proc.pid, signal.SIGINT)
    out, _ = proc.communicate(timeout=90)
    err = (place.cwd / "up.err").read_text()
    assert "Traceback" not in err, err
    assert_shown(command, place.as_in_doc(err))
    summary = json.loads(out)
    assert proc.returncode == summary["exit_code"], (proc.returncode, err)
    return summary


def assert_processed_with_the_calibration(summary: dict) -> None:
    """Exit 0: frames processed, with the stored calibration, health ok over them."""
    assert (summary["exit_code"], summary["reason"]) == (0, ""), summary
    assert 0 < summary["frames_processed"] <= summary["frames_captured"], summary
    assert summary["calibration_version"] >= 1 and summary["health"] == {}, summary


def watched(place: Place) -> list[dict]:
    """`ovis watch --count 3` and its --json twin, as the page runs them: three frames
    each; the JSON one's obstacle frames."""
    plain, as_json = block("watch")
    text = place.ok(plain, timeout=90).stdout
    assert len(re.findall(r"^frame \d+ ", text, re.M)) == 3, text
    lines = place.ok(as_json, timeout=90).stdout.splitlines()
    frames = [m for m in map(json.loads, lines) if m["type"] == "obstacles"]
    assert len(frames) == 3, lines
    return frames


def status_rows(place: Place, name: str) -> dict[str, str]:
    """`ovis status` as the page runs it (block ``name``): each service's table row."""
    (status,) = block(name)
    text = place.ok(status, timeout=60).stdout
    rows = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip("│ ").split("│")]
        if cells and cells[0] in SERVICES:
            rows[cells[0]] = line
    return rows


def test_step_5_live_from_a_folder_watched_and_a_second_up_refused(
    calibrated: Path, tmp_path: Path
) -> None:
    place = _place(calibrated, tmp_path, "frames", "calib.json")
    (up,) = block("up-frames")
    t0 = time.monotonic()
    with live(place, up) as proc:
        frames = watched(place)
        assert all(f["calibration_version"] >= 1 for f in frames), frames
        measured = [o for f in frames for o in [f["robot"], *f["obstacles"]] if o]
        assert measured and all(isinstance(o["x_cm"], float) for o in measured), frames
        rows = status_rows(place, "status")
        assert set(rows) == set(SERVICES), rows
        assert all(re.search(r"│ yes +│ ok +│", row) for row in rows.values()), rows
        (second,) = block("second-up")
        t1 = time.monotonic()
        refused = place.run(second, timeout=60)
        assert time.monotonic() - t1 < START_FAILS_S
        assert refused.returncode == 2 and refused.stdout == ""
        assert_one_line_error(refused, place.endpoint, "--listen")
        summary = ctrl_c(place, up, proc)
    assert_processed_with_the_calibration(summary)
    assert summary["calibration_version"] == 1  # calib.json, stored
    print(f"frames: {summary['frames_processed']} processed, {time.monotonic() - t0:.1f} s")


def test_step_5_live_from_a_video_with_the_web_view(calibrated: Path, tmp_path: Path) -> None:
    place = _place(calibrated, tmp_path, "run.avi", "calib.json")
    place.view = f"127.0.0.1:{free_port()}"
    (up,) = block("up-video")
    t0 = time.monotonic()
    with live(place, up) as proc:
        watched(place)
        with urllib.request.urlopen(f"http://{place.view}/api/state", timeout=10) as r:
            state = json.load(r)["arenas"]["default"]
        with urllib.request.urlopen(f"http://{place.view}/", timeout=10) as r:
            page = r.read().decode()
        summary = ctrl_c(place, up, proc)
    assert "<title>ovis view</title>" in page
    assert state["obstacle_messages"] > 0, state
    assert_processed_with_the_calibration(summary)
    print(f"video: {summary['frames_processed']} processed, {time.monotonic() - t0:.1f} s")


def test_step_5_and_6_live_from_a_network_camera_unplugged_and_back(
    calibrated: Path, tmp_path: Path
) -> None:
    place = _place(calibrated, tmp_path, "calib.json")
    jpegs = [p.read_bytes() for p in photo_paths()]
    (up,) = block("up-stream")
    t0 = time.monotonic()
    with mjpeg_camera(jpegs, free_port()) as camera:
        place.stream = camera.url
        with live(place, up) as proc:
            watched(place)
            camera.stop()  # unplugged
            lost = wait_for(
                lambda: "source lost" in status_rows(place, "status-lost").get("capture", ""),
                30,
                "ovis status to say the capture's source is lost",
            )
            camera.start()  # back: frames flow again by themselves
            wait_for(
                lambda: all(" ok " in row for row in status_rows(place, "status-lost").values()),
                30,
                "ovis status to say every stage is ok again",
            )
            summary = ctrl_c(place, up, proc)
    assert lost
    assert_processed_with_the_calibration(summary)
    assert summary["source_gaps"] >= 1 and not summary["gaps"][0]["ongoing"], summary
    assert camera.url in summary["gaps"][0]["reason"], summary["gaps"]
    print(f"stream: {summary['frames_processed']} processed, gaps {summary['gaps']}, "
          f"{time.monotonic() - t0:.1f} s")  # fmt: skip


# --- step 6: refused at the start ------------------------------------------------------------


@pytest.mark.parametrize("name", ["no-calibration", "wrong-size", "no-camera"])
def test_step_6_a_start_that_cannot_work_is_refused_in_one_line(
    calibrated: Path, tmp_path: Path, name: str
) -> None:
    if name == "no-camera" and list(Path("/dev").glob("video*")):
        pytest.skip("this machine has a camera: camera:0 may open")
    place = _place(calibrated, tmp_path, "frames", "frames-640x480", "calib.json")
    (command,) = block(name)
    t0 = time.monotonic()
    proc = place.run(command, timeout=60)
    took = time.monotonic() - t0
    assert_one_line_error(proc)
    assert proc.returncode == 2 and proc.stdout == "" and took < START_FAILS_S, (took, proc)
    assert not (tmp_path / "ovis-state").exists()  # nothing stored, nothing started
