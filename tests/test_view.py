"""`ovis up --view` in a real browser (the distribution's Chromium, driven by Playwright):
the page shows the simulated robot where the simulator put it, counts update, a killed
stage turns red, recalibration works with the operator token and only with it; and
garbage on the WebSocket, 20 clients at once and a view of an arena where no stage
runs leave the view serving with a clear state on the page.

One running system (router, five stages, two views) is shared by the whole module.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import signal
import subprocess
import threading
import time
import urllib.request
from pathlib import Path

import pytest
from pipeline_helpers import Recorder
from zenoh_helpers import client, free_port, ovis_cmd, pids_with, spawn, stop, wait_for

CHROMIUM = Path("/usr/bin/chromium")
ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--disable-quic",
]
TOKEN = "view-test-operator-token"
DOCS_IMAGE = Path(__file__).resolve().parents[1] / "docs" / "images" / "view.png"

if not CHROMIUM.exists():
    reason = f"no Chromium at {CHROMIUM}: install it with `apt-get install chromium`"
    if os.environ.get("CI") == "true":
        pytest.fail(f"{reason} (CI must run the browser tests)", pytrace=False)
    pytest.skip(reason, allow_module_level=True)

sync_playwright = pytest.importorskip("playwright.sync_api").sync_playwright
ws_client = pytest.importorskip("websockets.sync.client")


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
        with open(self.err, "wb") as fh:
            self.up = subprocess.Popen(
                ovis_cmd(
                    "up",
                    "--view",
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
                ),
                tmp / "lonely.log",
            )
            wait_for(lambda: _answers(s.url) and _answers(s.lonely_url), 30, "both views")
            with sync_playwright() as p:
                s.browser = p.chromium.launch(executable_path=str(CHROMIUM), args=ARGS)
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


def _answers(url: str) -> bool:
    try:
        get_json(url + "api/state")
        return True
    except OSError:
        return False


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
        DOCS_IMAGE.parent.mkdir(parents=True, exist_ok=True)
        # written here: given a path, Playwright writes it on a thread of its event loop's
        # executor, a thread that then stays for the module
        DOCS_IMAGE.write_bytes(page.screenshot(full_page=True))
    assert DOCS_IMAGE.stat().st_size > 20000


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


def _messages(ws, until, timeout: float = 10.0) -> list[dict]:
    """Text messages from a raw WebSocket until ``until(message)``."""
    got = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        data = ws.recv(timeout=max(0.1, deadline - time.monotonic()))
        if isinstance(data, str):
            got.append(json.loads(data))
            if until(got[-1]):
                return got
    raise AssertionError(f"no matching message in {timeout} s: {got[-5:]}")


def test_recalibration_needs_the_right_token_on_the_server(system) -> None:
    ws_url = system.url.replace("http", "ws") + "ws"
    with ws_client.connect(ws_url) as ws:
        ws.send(json.dumps({"type": "recalibrate", "token": "wrong-token-123"}))
        msgs = _messages(ws, lambda m: m["type"] == "recalibration")
        assert msgs[-1]["state"] == "refused" and "wrong operator token" in msgs[-1]["message"]
    with page_of(system, system.lonely_url) as page:
        page.wait_for_selector("#stages tr", timeout=10000)
        assert page.locator("#recalibrate").count() == 0  # no token: no button
    with ws_client.connect(system.lonely_url.replace("http", "ws") + "ws") as ws:
        ws.send(json.dumps({"type": "recalibrate", "token": TOKEN}))
        msgs = _messages(ws, lambda m: m["type"] == "recalibration")
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


def test_garbage_and_20_clients_leave_the_view_serving(system) -> None:
    ws_url = system.url.replace("http", "ws") + "ws"
    with ws_client.connect(ws_url) as ws:
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
            msgs = _messages(ws, lambda m: m["type"] == "error")
            assert msgs[-1]["message"] and not msgs[-1].get("fatal")
    # 20 clients at once: each gets its hello, health and pictures.
    results: list[int] = []
    lock = threading.Lock()

    def one() -> None:
        with ws_client.connect(ws_url) as ws:
            pictures = 0
            deadline = time.monotonic() + 8
            while time.monotonic() < deadline and pictures < 5:
                if isinstance(ws.recv(timeout=5), bytes):
                    pictures += 1
            with lock:
                results.append(pictures)

    threads = [threading.Thread(target=one) for _ in range(20)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert results == [5] * 20, results
    # Beyond --max-clients (3 on the read-only view): told so, clearly.
    lonely_ws = system.lonely_url.replace("http", "ws") + "ws"
    with contextlib.ExitStack() as stack:
        for _ in range(3):
            stack.enter_context(ws_client.connect(lonely_ws)).recv(timeout=5)
        with ws_client.connect(lonely_ws) as extra:
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
