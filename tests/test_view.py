"""`ovis up --view` in a real browser (the distribution's Chromium, driven by Playwright):
the page shows the simulated robot where the simulator put it, counts update, a killed
stage turns red, recalibration works with the operator token and only with it; and
garbage on the WebSocket, 20 clients at once and a view of an arena where no stage
runs leave the view serving with a clear state on the page.

And an honest page: frames that stop (a capture frozen with SIGSTOP) show "stalled"
with growing seconds and a picture marked stale; a page whose view server stops greys
its health to "unknown"; `ovis replay` of a session of the shared real photos is
labelled "replay of NAME" with the recording's own time and no latency, with its
marked robots labelled on the picture and its calibration's control points only on the
frame it was made on; a real MJPEG camera switched off shows "source lost" with the
capture's reason, and live again when it is back; the map has a grid and a
scale bar.

One running system (router, five stages, two views) is shared by the whole module; the
honest-page tests add a view, a capture and a replay of their own on its router.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import math
import os
import re
import signal
import subprocess
import threading
import time
import urllib.request
import warnings
from datetime import UTC, datetime
from pathlib import Path
from types import SimpleNamespace

import cv2
import msgspec
import pytest
from browser_helpers import chromium_or_skip, launch
from mjpeg_server import mjpeg_camera
from pipeline_helpers import Recorder
from real_photos import photo_calibration, photo_paths
from ws_helpers import serving, texts_until, ws_connect
from zenoh_helpers import client, free_port, ovis_cmd, pids_with, spawn, stop, wait_for

from ovis.common.calibration.file import Calibration
from ovis.common.camera.projection import project
from ovis.common.config import load_config
from ovis.common.messages import (
    CalibrationUpdate,
    Frame,
    ObstacleFrame,
    Topics,
    encode,
)
from ovis.common.recording.session import SessionWriter
from ovis.common.view.grid import map_grid_step
from ovis.common.world.robots import RobotState
from ovis.services.cli.watching import query_statuses

# long: minutes of work, started early so the run ends with both workers busy
pytestmark = pytest.mark.long

TOKEN = "view-test-operator-token"
USER_TIMEOUT_S = 0.35
USER_FRAME_AGE_S = 0.8
DOCS_IMAGE = Path(__file__).resolve().parents[1] / "docs" / "images" / "view.png"

chromium_or_skip()
sync_playwright = pytest.importorskip("playwright.sync_api").sync_playwright
PlaywrightTimeout = pytest.importorskip("playwright.sync_api").TimeoutError


def get_json(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=5) as r:
        return json.loads(r.read())


class System:
    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.url = f"http://127.0.0.1:{free_port()}/"
        self.lonely_url = f"http://127.0.0.1:{free_port()}/"
        env = dict(
            os.environ,
            OVIS_VIEW_LISTEN=self.url.removeprefix("http://").rstrip("/"),
            OVIS_OPERATOR_TOKEN=TOKEN,
        )
        self.err = tmp / "up.err"
        # a user's configuration whose [navigation] limits are not the defaults: the view
        # must judge drives by these
        self.config = tmp / "user.toml"
        self.config.write_text(
            f"[navigation]\ncommand_timeout_s = {USER_TIMEOUT_S}\n"
            f"max_frame_age_s = {USER_FRAME_AGE_S}\n"
        )
        with open(self.err, "wb") as fh:
            self.up = subprocess.Popen(
                ovis_cmd(
                    "up",
                    "--view",
                    "--config",
                    str(self.config),
                    "--listen",
                    self.endpoint,
                    "--fps",
                    "15",
                    "--no-live",
                    "--state-dir",
                    str(tmp / "state"),
                ),
                stdout=fh,
                stderr=subprocess.STDOUT,
                env=env,
            )


@pytest.fixture(scope="module")
def system(tmp_path_factory: pytest.TempPathFactory):
    tmp = tmp_path_factory.mktemp("view")
    s = System(tmp)
    lonely = None
    try:
        with client(s.endpoint) as session:
            s.rec = Recorder(session)
            wait_for(
                lambda: any(m.calibration_version >= 1 for m in s.rec.since(0)),
                60,
                "calibrated obstacle messages",
            )
            s.log_dir = re.search(r"logs in (\S+)", s.err.read_text())[1]
            # A second, read-only view (no token) of an arena where no stage runs, and of
            # the default one; started with a small client limit.
            lonely = spawn(
                ovis_cmd(
                    "view",
                    "--connect",
                    s.endpoint,
                    "--listen",
                    s.lonely_url.removeprefix("http://").rstrip("/"),
                    "--arena",
                    "lonely",
                    "--arena",
                    "default",
                    "--max-clients",
                    "3",
                    "--trust",  # the keys `ovis up` made: it shows only what they signed
                    str(tmp / "state" / "keys"),
                ),
                tmp / "lonely.log",
            )
            wait_for(lambda: serving(s.url) and serving(s.lonely_url), 30, "both views")
            with sync_playwright() as p:
                s.browser = launch(p)
                yield s
                s.browser.close()
    finally:
        if lonely is not None:
            stop([lonely])
        if s.up.poll() is None:
            s.up.send_signal(signal.SIGTERM)
        try:
            s.up.wait(30)
        except subprocess.TimeoutExpired:
            s.up.kill()
    # The view stops cleanly with the stages (the killed one was restarted by `ovis up`).
    assert s.up.returncode == 0, s.err.read_text()[-3000:]
    for log in (
        tmp / "lonely.log",
        Path(s.log_dir) / "view.log" if hasattr(s, "log_dir") else None,
    ):
        if log is not None and log.exists():
            assert "Traceback" not in log.read_text(), log.read_text()


@contextlib.contextmanager
def page_of(system: System, url: str):
    page = system.browser.new_page(viewport={"width": 1280, "height": 1000})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    try:
        page.goto(url)
        yield page
    finally:
        page.close()
    assert errors == [], errors


def test_up_starts_its_view_with_the_configuration_it_runs_with(system) -> None:
    """`ovis up --config` reaches the view too: the user's [navigation] limits judge the
    robots' drives on the page, with `ovis up`'s state folder and router, as a client
    of the router."""
    (pid,) = pids_with(f" --connect {system.endpoint} --arena default --trust ")
    args = Path(f"/proc/{pid}/cmdline").read_bytes().decode().split("\0")
    assert args[args.index("--connect") + 1] == system.endpoint
    cfg = load_config(Path(args[args.index("--config") + 1]))
    assert cfg.zenoh.mode == "client"
    assert cfg.service.state_dir == str(system.tmp / "state")
    assert cfg.trust.keys_dir == args[args.index("--trust") + 1]
    assert (cfg.navigation.command_timeout_s, cfg.navigation.max_frame_age_s) == (
        USER_TIMEOUT_S,
        USER_FRAME_AGE_S,
    )


def test_the_map_shows_the_robot_within_1_cm_of_the_truth(system) -> None:
    with page_of(system, system.url) as page:
        page.wait_for_selector("#map [data-kind=robot]", timeout=15000)
        errors = []
        for _ in range(5):
            seq, x, y = page.evaluate(
                """() => { const r = document.querySelector('#map [data-kind=robot]');
                return [Number(document.getElementById('map').dataset.seq),
                        Number(r.dataset.xCm), Number(r.dataset.yCm)]; }"""
            )
            truth = wait_for(lambda s=seq: system.rec.truth.get(s), 5, f"truth of {seq}")
            robot = next(o for o in truth.objects if o.kind == "robot")
            errors.append(math.hypot(x - robot.x_cm, y - robot.y_cm))
            page.wait_for_timeout(300)
        assert max(errors) < 1.0, errors
        assert page.locator("#map [data-kind=obstacle]").count() == 3
        heading = page.get_attribute("#map [data-kind=robot]", "data-heading-deg")
        assert heading and -180.0 <= float(heading) <= 360.0
        assert page.locator("#map [data-kind=footprint]").count() == 1


def test_counts_pictures_and_health_update(system) -> None:
    with page_of(system, system.url) as page:
        page.wait_for_selector("#picture[data-seq]", timeout=15000)

        def read() -> tuple[int, int, int]:
            return page.evaluate(
                """() => [Number(document.getElementById('count-messages').dataset.value),
                          Number(document.getElementById('count-pictures').dataset.value),
                          Number(document.getElementById('picture').dataset.seq)]"""
            )

        first = read()
        page.wait_for_timeout(1500)
        second = read()
        assert all(b > a for a, b in zip(first, second, strict=True)), (first, second)
        # Pictures come at most max_fps (10) a second.
        assert second[1] - first[1] <= 10 * 1.5 + 2
        assert page.locator("#stages tr[data-alive=true]").count() == 5
        assert "all stages running" in page.inner_text("#notice")
        assert page.get_attribute("#calibration", "data-version") != "0"
        page.check("#show-binary")
        page.wait_for_selector("#picture[data-kind=binary]", timeout=5000)
        page.uncheck("#show-binary")
        page.wait_for_selector("#picture[data-kind=camera]", timeout=5000)
        page.wait_for_timeout(500)
        shot = system.tmp / "view.png"
        # written here: given a path, Playwright writes it on a thread of its event loop's
        # executor, a thread that then stays for the module
        shot.write_bytes(page.screenshot(full_page=True))
        # Robots are labelled on the picture; the calibration's control points are drawn
        # only on the calibration's own frame (when the page happened to show it).
        log = page.evaluate("() => window.ovisView.pictureLog.filter(p => p.kind === 'camera')")
    # A picture waits for its frame's detections; one drawn without them (the frame path
    # more than a second or the kept frames behind, as on a loaded machine at the start)
    # says so and draws nothing, never an arena without its robot.
    drawn = [p for p in log if p["detected"]]
    assert drawn and all(not p["robots"] for p in log if not p["detected"]), log
    assert all(p["robots"] and p["robots"][0]["label"] == "R0" for p in drawn), drawn[-3:]
    assert all(p["robots"][0]["arrow"] for p in drawn)
    assert all((p["points"] > 0) == (p["calibration_frame"] == p["seq"]) for p in log)
    assert {p["calibration_frame"] for p in log} - {None}, "the calibration names its frame"
    assert shot.stat().st_size > 20000
    if os.environ.get("OVIS_UPDATE_DOCS_IMAGES") == "1":
        save_small_png(shot, DOCS_IMAGE)


def save_small_png(shot: Path, out: Path, colours: int = 128) -> None:
    """The screenshot with its colours reduced to a palette (a small file for the docs;
    the octree keeps the few pixels of the status colours)."""
    image = pytest.importorskip("PIL.Image")
    with image.open(shot) as im:
        small = im.convert("RGB").quantize(
            colours, method=image.Quantize.FASTOCTREE, dither=image.Dither.NONE
        )
    out.parent.mkdir(parents=True, exist_ok=True)
    small.save(out, optimize=True)


def test_recalibrate_from_the_page_with_the_token(system) -> None:
    with page_of(system, system.url + f"#token={TOKEN}") as page:
        page.wait_for_selector("#recalibrate", timeout=10000)
        page.wait_for_selector("#calibration[data-version]:not([data-version='0'])")
        before = int(page.get_attribute("#calibration", "data-version"))
        page.fill("#population", "40")
        page.fill("#generations", "20")
        page.fill("#seed", "1")
        # A simulated frame where objects touch is infeasible for any calibration (the
        # calibrator says so); the operator then tries again on a later frame.
        for _attempt in range(3):
            page.click("#recalibrate")
            page.wait_for_selector("#recal-status[data-state=running]", timeout=5000)
            assert "running" in page.inner_text("#recal-status")
            page.wait_for_selector(
                "#recal-status:not([data-state=running]):not([data-state=sent])", timeout=60000
            )
            status = page.inner_text("#recal-status")
            if page.get_attribute("#recal-status", "data-state") == "done":
                break
            assert "sees exactly" in status, status  # infeasible frame: a clear reason
        assert page.get_attribute("#recal-status", "data-state") == "done", status
        version = int(page.get_attribute("#recal-status", "data-version"))
        assert version == before + 1
        assert f"calibration v{version}" in page.inner_text("#recal-status")
        page.wait_for_selector(f"#calibration[data-version='{version}']", timeout=5000)


def test_recalibration_needs_the_right_token_on_the_server(system) -> None:
    with ws_connect(system.url, source="127.0.0.9") as ws:  # its wait is its own
        ws.send(json.dumps({"type": "recalibrate", "token": "wrong-token-123"}))
        msgs = texts_until(ws, lambda m: m["type"] == "recalibration")
        assert msgs[-1]["state"] == "refused" and "wrong operator token" in msgs[-1]["message"]
    with page_of(system, system.lonely_url) as page:
        page.wait_for_selector("#stages tr", timeout=10000)
        assert page.locator("#recalibrate").count() == 0  # no token: no button
    with ws_connect(system.lonely_url) as ws:
        ws.send(json.dumps({"type": "recalibrate", "token": TOKEN}))
        msgs = texts_until(ws, lambda m: m["type"] == "recalibration")
        assert msgs[-1]["state"] == "refused" and "read-only" in msgs[-1]["message"]


def test_a_view_of_an_arena_with_no_stage_says_so(system) -> None:
    with page_of(system, system.lonely_url) as page:
        page.wait_for_selector("#stages tr[data-stage=capture]", timeout=10000)
        assert page.locator("#stages tr[data-alive=false]").count() == 5
        assert "no stage is running" in page.inner_text("#notice")
        assert page.locator("#map [data-kind=robot]").count() == 0
        assert page.is_hidden("#picture")
        assert page.inner_text("#stream") == "no pose service"
        # The selector switches to the arena where ovis runs.
        page.select_option("#arena-select", "default")
        page.wait_for_selector("#map [data-kind=robot]", timeout=15000)
        page.wait_for_selector("#picture[data-seq]", timeout=15000)


def test_garbage_and_20_clients_leave_the_viewserving(system) -> None:
    with ws_connect(system.url) as ws:
        for junk in (
            b"\x00\xff\x13",
            "not json",
            "[1, 2",
            '{"type": "recalibrate", "population": -1}',
            '{"type": "select", "arena": "../../etc"}',
            '{"type": "show", "kind": "everything"}',
            '{"type": "nope"}',
            "x" * 10000,
        ):
            ws.send(junk)
            msgs = texts_until(ws, lambda m: m["type"] == "error")
            assert msgs[-1]["message"] and not msgs[-1].get("fatal")
    # 20 clients at once (from 5 addresses): each gets its hello, health and pictures.
    results: list[int] = []
    lock = threading.Lock()

    def one(source: str) -> None:
        with ws_connect(system.url, source) as ws:
            pictures = 0
            deadline = time.monotonic() + 20  # pictures come slower on a loaded host
            while time.monotonic() < deadline and pictures < 5:
                if isinstance(ws.recv(timeout=5), bytes):
                    pictures += 1
            with lock:
                results.append(pictures)

    threads = [threading.Thread(target=one, args=(f"127.0.0.{2 + i % 5}",)) for i in range(20)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert results == [5] * 20, results
    # Beyond --max-clients (3 on the read-only view): told so, clearly.
    with contextlib.ExitStack() as stack:
        for _ in range(3):
            stack.enter_context(ws_connect(system.lonely_url)).recv(timeout=5)
        with ws_connect(system.lonely_url) as extra:
            msg = json.loads(extra.recv(timeout=5))
            assert msg["type"] == "error" and msg["fatal"] and "too many viewers" in msg["message"]
    state = get_json(system.url + "api/state")
    assert state["arenas"]["default"]["obstacle_messages"] > 0


def test_a_killed_stage_turns_red_within_3_s(system) -> None:
    with page_of(system, system.url) as page:
        page.wait_for_selector("#stages tr[data-stage=label][data-alive=true]", timeout=10000)
        (pid,) = pids_with(f"run label --config {system.log_dir}")
        os.kill(pid, signal.SIGKILL)
        t0 = time.monotonic()
        page.wait_for_selector("#stages tr[data-stage=label][data-alive=false]", timeout=3000)
        assert time.monotonic() - t0 < 3.0
        colour = page.evaluate(
            "() => getComputedStyle(document.querySelector('#stages tr[data-stage=label]'))"
            ".backgroundColor"
        )
        r, g, b = (int(v) for v in re.findall(r"\d+", colour)[:3])
        assert r > 150 and g < 80 and b < 100, colour
        assert "label" in page.inner_text("#notice")
        # `ovis up` restarts it; the page turns green again.
        page.wait_for_selector("#stages tr[data-stage=label][data-alive=true]", timeout=30000)


# --- an honest page ---------------------------------------------------------------------
STALL_ARENA, REPLAY_ARENA, LOST_ARENA = "stall", "replayed", "lost"
#: The capture says a lost source within this many seconds (the issue's bound).
SAY_LOST_S = 2.0
SQUARE_CM = 2.5
#: The replayed frames were captured this long before the replay (the issue saw 264.7 s).
RECORDED_AGO_S = 300.0
FRAME_PERIOD_S = 0.4
#: The calibration was made on this frame of the recording (the first photo, sent last).
CALIBRATION_FRAME = 13
#: Marked robots of the recorded obstacle messages: id, name, floor x, y (cm), heading.
ROBOTS = [(1, "alpha", 6.25, -3.75, 0.0), (2, "", 13.75, -8.75, 90.0)]


@pytest.fixture(scope="module")
def honest(system, tmp_path_factory: pytest.TempPathFactory):
    """A view of three arenas of the system's router: one where a simulated capture runs
    (to be frozen), one for a replay, one whose stream is lost."""
    tmp = tmp_path_factory.mktemp("honest")
    h = SimpleNamespace(tmp=tmp, url=f"http://127.0.0.1:{free_port()}/")
    view = spawn(
        ovis_cmd(
            "view",
            "--connect",
            system.endpoint,
            "--listen",
            h.url.removeprefix("http://").rstrip("/"),
            *("--arena", STALL_ARENA, "--arena", REPLAY_ARENA, "--arena", LOST_ARENA),
        ),
        tmp / "view.log",
    )
    h.capture = spawn(
        ovis_cmd(
            "run",
            "capture",
            *("--connect", system.endpoint, "--arena", STALL_ARENA),
            *("--source", "sim", "--fps", "10"),
        ),
        tmp / "capture.log",
    )
    try:
        wait_for(lambda: serving(h.url), 30, "the honest view")
        yield h
    finally:
        if h.capture.poll() is None:
            os.kill(h.capture.pid, signal.SIGCONT)
        stop([h.capture, view])
    assert "Traceback" not in (tmp / "view.log").read_text()


def watch(page, arena: str) -> None:
    """Show ``arena`` on the page and wait until the view says it shows it."""
    page.wait_for_selector("#stages tr[data-stage=capture]", timeout=15000)
    if page.evaluate("() => window.ovisView.arena") != arena:
        page.select_option("#arena-select", arena)
    page.wait_for_function(f"() => window.ovisView.arena === {arena!r}", timeout=10000)
    page.wait_for_function(
        f"() => window.ovisView.health && window.ovisView.health.arena === {arena!r}",
        timeout=10000,
    )


def since_s(page, selector: str) -> float:
    return float(page.get_attribute(selector, "data-since-s"))


def test_frames_that_stop_show_stalled_with_growing_seconds_and_a_stale_picture(
    system, honest
) -> None:
    with page_of(system, honest.url) as page:
        watch(page, STALL_ARENA)
        page.wait_for_selector("#picture-fresh[data-state=live]", timeout=15000)
        text = page.inner_text("#picture-fresh")
        age = re.search(r"age (-?\d+) ms", text)
        assert age and 0 <= int(age[1]) < 1000, text  # now − the capture stamp
        assert page.get_attribute("#picture-box", "data-stale") == "false"
        assert page.is_hidden("#picture-stale")
        os.kill(honest.capture.pid, signal.SIGSTOP)  # a hung camera: alive, no frames
        t0 = time.monotonic()
        try:
            page.wait_for_selector("#picture-fresh[data-state=stalled]", timeout=6000)
            took = time.monotonic() - t0
            first = since_s(page, "#picture-fresh")
            page.wait_for_timeout(2200)  # no message needed: the page counts on its own
            second = since_s(page, "#picture-fresh")
            text = page.inner_text("#picture-fresh")
            stale = page.inner_text("#picture-stale")
            grey = page.evaluate(
                "() => getComputedStyle(document.getElementById('picture')).filter"
            )
            rows = page.locator("#stages tr[data-stage=capture][data-alive=true]").count()
        finally:
            os.kill(honest.capture.pid, signal.SIGCONT)
        print(f"\nstalled on the page {took:.1f} s after the frames stopped: {text!r}, {stale!r}")
        assert took < 2.0 + 3.0, took  # the 2 s threshold, a health period, the page's tick
        assert 2.0 <= first < 5.0 and 1.5 < second - first < 3.5, (first, second)
        m = re.search(r"stalled · no frame for (\d+(?:\.\d)?) s", text)
        assert m and float(m[1]) == pytest.approx(second, abs=1.1), text
        assert re.fullmatch(r"STALE \d+ s", stale) and int(stale.split()[1]) >= 4, stale
        assert page.get_attribute("#picture-box", "data-stale") == "true"
        assert "grayscale(1)" in grey, grey
        assert rows == 1  # the frozen capture is still alive: only the frames tell
        # Frames again: live, the stale mark gone.
        page.wait_for_selector("#picture-fresh[data-state=live]", timeout=15000)
        assert page.get_attribute("#picture-box", "data-stale") == "false"
        assert page.is_hidden("#picture-stale")


def test_a_page_whose_view_server_stops_greys_its_health_to_unknown(system, tmp_path) -> None:
    url = f"http://127.0.0.1:{free_port()}/"
    args = ovis_cmd(
        "view",
        *("--connect", system.endpoint, "--listen", url.removeprefix("http://").rstrip("/")),
        *("--arena", "default"),
        *("--trust", str(system.tmp / "state" / "keys")),  # the keys `ovis up` made
    )
    server = spawn(args, tmp_path / "view.log")
    try:
        wait_for(lambda: serving(url), 30, "the view")
        with page_of(system, url) as page:
            page.wait_for_selector("#stages tr[data-alive=true]", timeout=15000)
            page.wait_for_selector("#stream[data-state=ok]", timeout=15000)
            page.wait_for_selector("#picture-fresh[data-state=live]", timeout=15000)
            page.wait_for_selector("#picture", state="visible", timeout=15000)  # drawn
            t0 = time.monotonic()
            stop([server])
            page.wait_for_selector("#stream[data-state=unknown]", timeout=3000)
            took = time.monotonic() - t0
            assert page.inner_text("#stream") == "unknown"
            assert page.locator("#stages tr[data-alive=true]").count() == 0
            assert page.locator("#stages tr[data-alive=unknown]").count() == 5
            border = page.evaluate(
                "() => getComputedStyle(document.querySelector('#stages tr td')).borderLeftColor"
            )
            r, g, b = (int(v) for v in re.findall(r"\d+", border)[:3])
            assert abs(r - g) < 30 and abs(g - b) < 30, border  # grey, not green
            assert page.get_attribute("#connection", "data-state") == "closed"
            assert "reconnecting" in page.inner_text("#connection")
            assert "lost the connection" in page.inner_text("#notice")
            assert page.inner_text("#picture-stale") == "DISCONNECTED"
            assert page.get_attribute("#picture-fresh", "data-state") == "unknown"
            assert page.get_attribute("#map", "data-stale") == "true"
            assert page.inner_text("#latency-p50") == "–"
            print(f"\nunknown on the page {took:.2f} s after the view server stopped")
            # The server again: the page reconnects and turns green.
            server = spawn(args, tmp_path / "view2.log")
            page.wait_for_selector("#stream[data-state=ok]", timeout=20000)
            page.wait_for_selector("#stages tr[data-alive=true]", timeout=5000)
            assert page.get_attribute("#connection", "data-state") == "open"
    finally:
        stop([server])


def test_a_lost_source_shows_its_reason_not_green(system, honest, tmp_path) -> None:
    """A real capture of an MJPEG camera serving the shared photos, with the pose stage
    (on the simulator's settings: what it is checked for is how it passes the capture's
    word on): the camera switched off shows "source lost" with the capture's own reason
    within a few seconds; switched on again, the picture is live and the stream no
    longer lost."""
    jpegs = [p.read_bytes() for p in photo_paths()]
    procs = []
    with mjpeg_camera(jpegs, free_port()) as camera:
        try:
            for stage, extra in (("pose", []), ("capture", ["--source", camera.url])):
                args = ("--connect", system.endpoint, "--arena", LOST_ARENA, *extra)
                procs.append(spawn(ovis_cmd("run", stage, *args), tmp_path / f"{stage}.log"))
            with client(system.endpoint) as session, page_of(system, honest.url) as page:
                watch(page, LOST_ARENA)
                page.wait_for_selector("#picture-fresh[data-state=live]", timeout=30000)
                assert page.get_attribute("#stream", "data-state") != "source lost"
                t_off = time.monotonic()
                camera.stop()
                page.wait_for_selector('#stream[data-state="source lost"]', timeout=10000)
                took = time.monotonic() - t_off
                shown, notice = page.evaluate(
                    "() => [document.getElementById('stream-reason').textContent,"
                    " document.getElementById('notice').innerText]"
                )
                shown = shown.removeprefix(": ")
                colour = page.evaluate(
                    "() => getComputedStyle(document.getElementById('stream')).color"
                )
                status = query_statuses(session, Topics(LOST_ARENA)).get("capture")
                print(f"\nsource lost on the page {took:.2f} s after the camera: {shown!r}")
                assert took < SAY_LOST_S + 1.0, took  # the capture's bound, the page's tick
                assert status is not None and status.state == "source lost", status
                # the capture's reason for the loss, or (after an attempt to reopen) why
                # the camera cannot be reopened
                assert shown in (status.gaps[-1].reason, status.reason), (shown, status)
                assert shown.startswith(
                    (f"stream {camera.url} delivered no frame", f"cannot open stream {camera.url}")
                ), shown
                r, g, _ = (int(v) for v in re.findall(r"\d+", colour)[:3])
                assert r > 150 and g < 80, colour
                assert f"SOURCE LOST: {shown}" in notice, notice
                # the camera again: frames, a live picture, the stream no longer lost
                t_on = time.monotonic()
                camera.start()
                page.wait_for_selector('#stream:not([data-state="source lost"])', timeout=15000)
                page.wait_for_selector("#picture-fresh[data-state=live]", timeout=15000)
                print(f"back on the page {time.monotonic() - t_on:.2f} s after the camera")
                assert page.inner_text("#stream-reason") == ""
        finally:
            stop(procs)
    for stage in ("pose", "capture"):
        assert "Traceback" not in (tmp_path / f"{stage}.log").read_text()


def test_the_map_has_a_grid_and_a_scale_bar(system) -> None:
    with page_of(system, system.url) as page:
        page.wait_for_selector("#scale-bar", timeout=15000)
        page.wait_for_selector("#map [data-kind=robot]", timeout=15000)
        step = float(page.get_attribute("#grid-layer", "data-step-cm"))
        health = page.evaluate("() => window.ovisView.health")
        assert step == map_grid_step([tuple(p) for p in health["footprint"]]), step
        assert step in (5.0, 10.0, 20.0, 50.0), step
        lines = page.evaluate(
            """() => [...document.querySelectorAll('#grid-layer line')].map(l =>
              [l.dataset.xCm ?? null, l.dataset.yCm ?? null])"""
        )
        xs = sorted(float(x) for x, _ in lines if x is not None)
        ys = sorted(float(y) for _, y in lines if y is not None)
        assert 3 <= len(xs) <= 14 and 3 <= len(ys) <= 14, (xs, ys)
        for v in xs + ys:
            assert v / step == pytest.approx(round(v / step)), v
        assert all(b - a == pytest.approx(step) for a, b in itertools.pairwise(xs))
        labels = page.evaluate(
            """() => [...document.querySelectorAll('#grid-layer text')].map(t =>
              [t.dataset.xCm ?? t.dataset.yCm, t.textContent])"""
        )
        assert all(float(at) == float(text) for at, text in labels), labels
        assert len(labels) >= len(xs) + len(ys) - 1, labels  # all but one in the corner
        assert page.text_content("#scale-bar text") == f"{step:g} cm"
        # The bar is one step long on the screen, at the map's own cm-to-pixel scale.
        bar, robot = page.evaluate(
            """() => { const m = document.getElementById('map');
              const k = m.getScreenCTM().a;  // screen pixels per cm
              const l = document.querySelector('#scale-bar line.scale');
              const r = document.querySelector('#map [data-kind=robot] circle');
              return [l.getBoundingClientRect().width / k,
                      r.getBoundingClientRect().width / k / 2 - Number(r.getAttribute('r'))]; }"""
        )
        assert bar == pytest.approx(step, rel=0.02), bar
        assert robot == pytest.approx(0.0, abs=0.1 * step)


def _shown_within(page, seq: int, timeout_ms: float) -> bool:
    """Whether the page shows the picture of frame ``seq`` within ``timeout_ms``."""
    try:
        page.wait_for_function(
            f"() => window.ovisView.pictureLog.some(p => p.seq === {seq})", timeout=timeout_ms
        )
    except PlaywrightTimeout:
        return False
    return True


def recorded_session(path: Path, tmp: Path) -> SimpleNamespace:
    """A session as `ovis record` writes one: the shared real photos as frames captured
    RECORDED_AGO_S ago, obstacle messages with marked robots, and the calibration (made
    with `ovis intrinsics` and `ovis calibrate --board` on the first photo, which the
    recording holds as its frame CALIBRATION_FRAME)."""
    photos = photo_paths()
    _, out = photo_calibration(tmp, SQUARE_CM)
    calib = msgspec.json.decode(out.read_bytes(), type=Calibration)
    calib = msgspec.structs.replace(calib, version=1, source_image=f"frame {CALIBRATION_FRAME}")
    t0 = time.time_ns() - int(RECORDED_AGO_S * 1e9)
    still = dict(z_cm=0.0, vx_cm_s=0.0, vy_cm_s=0.0, yaw_rate_deg_s=0.0, age_s=0.0)
    robots = [
        RobotState(id=i, name=n, marker_id=i, x_cm=x, y_cm=y, heading_deg=h, radius_cm=2.0, **still)
        for i, n, x, y, h in ROBOTS
    ]
    logs = []
    writer = SessionWriter(path)
    writer.bus("ovis/rec/calibration", encode(CalibrationUpdate(calibration=calib)), t0, t0)
    for seq in range(len(photos)):
        image = cv2.imread(str(photos[(seq + 1) % len(photos)]), cv2.IMREAD_GRAYSCALE)
        stamp = t0 + int((seq + 1) * FRAME_PERIOD_S * 1e9)
        frame = Frame.from_image(image, seq=seq, stamp_ns=stamp, source=str(photos[0].parent))
        writer.frame("ovis/rec/frames", encode(frame), stamp + 2_000_000, stamp)
        obstacles = ObstacleFrame(
            seq=seq,
            stamp_ns=stamp,
            published_ns=stamp + 20_000_000,
            frame_age_ms=20.0,
            calibration_version=1,
            robot=None,
            obstacles=[],
            planner=[],
            arena="rec",
            robots=robots,
        )
        writer.bus("ovis/rec/obstacles", encode(obstacles), stamp + 21_000_000, stamp)
        logs.append(stamp + 2_000_000)
    writer.close()
    return SimpleNamespace(calibration=calib, start_ns=t0, frame_logs=logs)


def test_a_replay_is_labelled_with_its_recording_and_own_time_not_a_latency(
    system, honest, tmp_path
) -> None:
    session = tmp_path / "arena-tuesday.mcap"
    rec = recorded_session(session, tmp_path)
    with page_of(system, honest.url) as page:
        watch(page, REPLAY_ARENA)
        replay = subprocess.Popen(
            ovis_cmd("replay", str(session), "--connect", system.endpoint, "--arena", REPLAY_ARENA),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
        )
        try:
            page.wait_for_selector("#picture-fresh[data-state=replay]", timeout=20000)
            page.wait_for_selector("#map-fresh[data-state=replay]", timeout=5000)
            page.wait_for_timeout(1000)
            text = page.inner_text("#picture-fresh")
            map_text = page.inner_text("#map-fresh")
            latency = page.inner_text("#latency-p50")
            notice = page.inner_text("#notice")
            out, _ = replay.communicate(timeout=60)
        finally:
            if replay.poll() is None:
                replay.kill()
                replay.wait()
        assert replay.returncode == 0, out
        print(f"\nduring the replay: {text!r}; map {map_text!r}; latency {latency!r}")
        m = re.fullmatch(
            r"replay of arena-tuesday\.mcap · recorded (\S+ \S+) UTC · (\d+\.\d) s into the "
            r"recording",
            text,
        )
        assert m, text
        shown = datetime.fromisoformat(m[1]).replace(tzinfo=UTC).timestamp()
        assert any(abs(shown - log / 1e9) < 0.1 for log in rec.frame_logs), m[1]
        into = float(m[2])
        assert any(abs(into - (log - rec.start_ns) / 1e9) < 0.1 for log in rec.frame_logs), into
        assert map_text.startswith("replay of arena-tuesday.mcap · recorded ")
        assert latency == "– (a replay: not live)", latency  # not 300 000 ms
        assert "REPLAY of arena-tuesday.mcap" in notice
        assert "age" not in text + map_text and "live" not in text + map_text
        # The replay has ended: stalled, still saying what was replayed.
        page.wait_for_selector("#picture-fresh[data-state=stalled]", timeout=8000)
        assert re.match(
            r"stalled · no frame for \d+(\.\d)? s · replay of arena-tuesday\.mcap, last recorded ",
            page.inner_text("#picture-fresh"),
        )
        assert page.get_attribute("#picture-box", "data-stale") == "true"
        # A slow browser gets fewer pictures (a newer one replaces one not yet sent); the
        # newest, the last frame's (the calibration's own), should come.
        last_shown = _shown_within(page, CALIBRATION_FRAME, 10000)
        log = page.evaluate("() => window.ovisView.pictureLog")
        if not last_shown:
            state = get_json(honest.url + "api/state")["arenas"].get(REPLAY_ARENA, {})
            warnings.warn(
                f"the replay's last frame ({CALIBRATION_FRAME}) never reached the page: pictures "
                f"{[p['seq'] for p in log]}, {state.get('obstacle_messages')} obstacle "
                f"messages, health {json.dumps(state.get('health'))[:1500]}; the replay said "
                f"{out.decode(errors='replace')[-500:]!r}",
                stacklevel=1,
            )
        state = page.evaluate("() => window.ovisView.health.summary")
        marks = page.evaluate(
            """() => { const img = document.getElementById('picture');
              const c = document.createElement('canvas');
              c.width = img.naturalWidth; c.height = img.naturalHeight;
              const g = c.getContext('2d'); g.drawImage(img, 0, 0);
              const d = g.getImageData(0, 0, c.width, c.height).data;
              return window.ovisView.pictureLog.at(-1).robots.map(r => {
                let best = -999;  // the greenest pixel of the robot's cross (grey photo: 0)
                for (let y = Math.round(r.y) - 5; y <= Math.round(r.y) + 5; y++)
                  for (let x = Math.round(r.x) - 5; x <= Math.round(r.x) + 5; x++) {
                    const i = 4 * (y * c.width + x);
                    best = Math.max(best, d[i + 1] - Math.max(d[i], d[i + 2]));
                  }
                return [r.label, best]; }); }"""
        )
    assert state["latency_p50_ms"] is None and state["replay"] == "arena-tuesday.mcap"
    # Control points only on the calibration's own frame (the first photo, frame 13).
    seqs = {p["seq"]: p["points"] for p in log}
    assert len(rec.calibration.points) == 54
    if last_shown:
        assert seqs[CALIBRATION_FRAME] == 54, seqs
    others = {s: n for s, n in seqs.items() if s != CALIBRATION_FRAME}
    assert others and set(others.values()) == {0}, seqs
    # Every marked robot labelled (id, name) with its heading arrow where the
    # calibration projects it.
    last = log[-1]
    assert [r["label"] for r in last["robots"]] == ["R1 alpha", "R2"]
    cam = rec.calibration.camera
    for drawn, (_, _, x, y, _) in zip(last["robots"], ROBOTS, strict=True):
        p = project(x, y, 0.0, cam)
        assert drawn["arrow"]
        assert (drawn["x"], drawn["y"]) == pytest.approx((float(p.col), float(p.row)), abs=0.01)
    assert all(green > 40 for _, green in marks), marks
