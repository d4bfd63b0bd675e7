"""Issue 28 item 7, played with clients that import only `websockets` (and urllib)
against a real `ovis view` on a router: pages of other origins are refused on `/ws` and
`/api` (and let in by `--allow-origin`); 1000 wrong operator tokens on one socket are
cut short after a few, the client then waits before its next token is even compared,
and the log says so in a line or two; a token worth under 128 bits is refused at
start and `--operator-token auto` makes a strong one; sockets left idle from one
address, and then from several until every seat is taken, never lock the operator out.

Loopback has many addresses (127.0.0.0/8): the clients that play several machines
connect from 127.0.0.2, 127.0.0.3, … and the operator from 127.0.0.1.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import subprocess
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from types import SimpleNamespace

import pytest
from websockets.exceptions import ConnectionClosed, InvalidStatus
from ws_helpers import serving, texts_until, ws_connect
from zenoh_helpers import free_port, ovis_cmd, spawn, stop, wait_for

# long: minutes of work, started early so the run ends with both workers busy
pytestmark = pytest.mark.long

TOKEN = "Qm7vK2xP9dLr4TzW8nHc3sYb6FgJ5uEa"  # 32 random letters and digits
ALLOWED = "http://example.org:8000"


@pytest.fixture(scope="module")
def views(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SimpleNamespace]:
    tmp = tmp_path_factory.mktemp("view-guard")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    operator_port, open_port = free_port(), free_port()
    router = spawn(ovis_cmd("router", "--listen", endpoint), tmp / "router.log")
    env = dict(os.environ, OVIS_OPERATOR_TOKEN=TOKEN)
    with open(tmp / "operator.log", "wb") as log:
        operator = subprocess.Popen(
            ovis_cmd("view", "--connect", endpoint, "--listen", f"127.0.0.1:{operator_port}"),
            stdout=log,
            stderr=subprocess.STDOUT,
            env=env,
        )
    allowing = spawn(
        ovis_cmd(
            "view",
            "--connect",
            endpoint,
            "--listen",
            f"127.0.0.1:{open_port}",
            "--allow-origin",
            ALLOWED,
        ),
        tmp / "allowing.log",
    )
    ns = SimpleNamespace(
        endpoint=endpoint,
        url=f"http://127.0.0.1:{operator_port}/",
        origin=f"http://127.0.0.1:{operator_port}",
        allowing_url=f"http://127.0.0.1:{open_port}/",
        log=tmp / "operator.log",
        tmp=tmp,
    )
    try:
        wait_for(lambda: serving(ns.url) and serving(ns.allowing_url), 30, "both views")
        yield ns
    finally:
        stop([operator, allowing, router])
    for name in ("operator.log", "allowing.log"):
        assert "Traceback" not in (tmp / name).read_text()


def refused_handshake(url: str, origin: str | None) -> str:
    """The HTTP status and body of a refused WebSocket handshake."""
    with pytest.raises(InvalidStatus) as refused, ws_connect(url, origin=origin):
        pass
    response = refused.value.response
    return f"{response.status_code} {response.body.decode()}"


def api_status(url: str, origin: str | None) -> int:
    request = urllib.request.Request(url + "api/state")
    if origin is not None:
        request.add_header("Origin", origin)
    try:
        with urllib.request.urlopen(request, timeout=5) as r:
            return r.status
    except urllib.error.HTTPError as exc:
        return exc.code


def test_other_origins_are_refused_and_an_allowed_one_gets_in(views) -> None:
    refused = refused_handshake(views.url, "http://evil.example")
    assert refused.startswith("403 origin 'http://evil.example' is not allowed"), refused
    assert refused_handshake(views.url, None).startswith("403 no Origin header")
    # a page of another port of the same machine is another origin
    assert refused_handshake(views.url, views.allowing_url.rstrip("/")).startswith("403")
    for own in (views.origin, views.origin.replace("127.0.0.1", "localhost")):
        with ws_connect(views.url, origin=own) as ws:
            assert texts_until(ws, lambda m: m["type"] == "hello")[-1]["operator"] is True
    assert api_status(views.url, "http://evil.example") == 403
    assert api_status(views.url, views.origin) == 200
    assert api_status(views.url, None) == 200  # a program (curl, a script): no Origin
    # --allow-origin lets that origin in, exactly (port 80 is another origin)
    with ws_connect(views.allowing_url, origin=ALLOWED) as ws:
        assert texts_until(ws, lambda m: m["type"] == "hello")[-1]["operator"] is False
    assert refused_handshake(views.allowing_url, "http://example.org").startswith("403")
    assert api_status(views.allowing_url, ALLOWED) == 200


def test_1000_wrong_tokens_are_cut_short_slowed_down_and_barely_logged(views) -> None:
    lines_before = views.log.read_text().count("operator token")
    # one guess at a time, each answer read (as a guesser must, to learn the result)
    answers: list[dict] = []
    with ws_connect(views.url, "127.0.0.2", views.origin) as ws:
        texts_until(ws, lambda m: m["type"] == "hello")
        with contextlib.suppress(ConnectionClosed):
            for i in range(1000):
                ws.send(json.dumps({"type": "recalibrate", "token": f"guess-{i:06d}"}))
                answers += texts_until(ws, lambda m: m["type"] in ("recalibration", "error"))
    refusals = [m for m in answers if m["type"] == "recalibration"]
    assert [m["state"] for m in refusals] == ["refused"] * 5, answers  # then it is closed
    assert [m["message"] for m in refusals[:3]] == ["wrong operator token"] * 3
    assert refusals[3]["message"] == "wrong operator token; wait 1 s to try again"
    assert refusals[4]["message"].startswith("too many wrong operator tokens from 127.0.0.2")
    assert answers[-1]["fatal"], answers[-1]
    assert answers[-1]["message"].startswith("5 operator tokens refused: disconnected")
    # 1000 sent at once, unread: the socket is closed all the same
    t0 = time.monotonic()
    with ws_connect(views.url, "127.0.0.7", views.origin) as ws:
        with contextlib.suppress(ConnectionClosed):
            for i in range(1000):
                ws.send(json.dumps({"type": "recalibrate", "token": f"flood-{i:06d}"}))
        last = texts_until(ws, lambda m: m.get("fatal"), timeout=10)[-1]
        assert last["message"].startswith("5 operator tokens refused: disconnected")
        with pytest.raises(ConnectionClosed):
            ws.recv(timeout=5)
    assert time.monotonic() - t0 < 10
    # the same address must now wait: even the right token is not compared
    with ws_connect(views.url, "127.0.0.2", views.origin) as ws:
        ws.send(json.dumps({"type": "auth", "token": TOKEN}))
        auth = texts_until(ws, lambda m: m["type"] == "auth")[-1]
        assert not auth["ok"] and re.match(
            r"too many wrong operator tokens from 127\.0\.0\.2: wait \d+ s", auth["message"]
        ), auth
    # the operator, elsewhere, is not slowed down
    with ws_connect(views.url, origin=views.origin) as ws:
        ws.send(json.dumps({"type": "auth", "token": TOKEN}))
        assert texts_until(ws, lambda m: m["type"] == "auth")[-1]["ok"] is True

    def logged() -> int:
        return views.log.read_text().count("operator token") - lines_before

    wait_for(logged, 5, "the refused tokens in the view's log")
    assert logged() <= 2, views.log.read_text()[-2000:]


def test_a_weak_token_is_refused_at_start_and_auto_makes_a_strong_one(views) -> None:
    t0 = time.monotonic()
    weak = subprocess.run(
        ovis_cmd(
            "view",
            "--connect",
            views.endpoint,
            "--listen",
            "127.0.0.1:0",
            "--operator-token",
            "0123456789abcdef",
        ),
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert weak.returncode == 2 and time.monotonic() - t0 < 10, weak
    assert "the operator token (16 characters) is worth at most" in weak.stderr, weak.stderr
    assert "128 are needed: use `--operator-token auto`" in weak.stderr
    # `ovis up --view` checks it before it starts anything
    up = subprocess.run(
        ovis_cmd("up", "--view", "--listen", f"tcp/127.0.0.1:{free_port()}", "--no-live"),
        capture_output=True,
        text=True,
        timeout=30,
        env=dict(os.environ, OVIS_OPERATOR_TOKEN="0123456789abcdef"),
    )
    assert up.returncode == 2, up
    assert up.stderr.startswith("error: OVIS_OPERATOR_TOKEN: the operator token (16 char"), up
    log = views.tmp / "auto.log"
    auto = spawn(
        ovis_cmd(
            "view",
            "--connect",
            views.endpoint,
            "--listen",
            f"127.0.0.1:{free_port()}",
            "--operator-token",
            "auto",
        ),
        log,
    )
    try:
        page = wait_for(
            lambda: re.search(r"operator page (http://\S+/)#token=(\S+)", log.read_text()),
            30,
            "the operator page's URL",
        )
        url, token = page[1], page[2]
        assert len(token) >= 32 and re.fullmatch(r"[A-Za-z0-9_-]+", token)
        wait_for(lambda: serving(url), 30, "the view")
        with ws_connect(url, origin=url.rstrip("/")) as ws:
            ws.send(json.dumps({"type": "auth", "token": token}))
            assert texts_until(ws, lambda m: m["type"] == "auth")[-1]["ok"] is True
    finally:
        stop([auto])


def test_idle_sockets_never_lock_the_operator_out(views) -> None:
    def hold(source: str, n: int) -> tuple[contextlib.ExitStack, list[str]]:
        """``n`` idle sockets from ``source`` at once: those seated, and the refusals."""
        stack, refusals, lock = contextlib.ExitStack(), [], threading.Lock()

        def one() -> None:
            opened = ws_connect(views.url, source, views.origin)
            ws = opened.__enter__()
            with lock:
                stack.push(opened.__exit__)
            first = json.loads(ws.recv(timeout=10))
            if first["type"] == "error":
                with lock:
                    refusals.append(first["message"])

        threads = [threading.Thread(target=one) for _ in range(n)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(30)
        return stack, refusals

    with contextlib.ExitStack() as idle:
        stack, refusals = hold("127.0.0.3", 32)
        idle.enter_context(stack)
        assert len(refusals) == 24, refusals
        assert set(refusals) == {
            "too many viewers from 127.0.0.3 (8, the view's --max-clients-per-address): "
            "close another view of ovis there"
        }
        for source in ("127.0.0.4", "127.0.0.5", "127.0.0.6"):  # every seat taken
            stack, refusals = hold(source, 8)
            idle.enter_context(stack)
            assert refusals == [], refusals
        with ws_connect(views.url, origin=views.origin) as viewer:
            msg = json.loads(viewer.recv(timeout=10))
            assert msg["fatal"] and msg["message"].startswith("too many viewers (32,"), msg
        t0 = time.monotonic()
        with ws_connect(views.url, origin=views.origin) as operator:
            operator.send(json.dumps({"type": "auth", "token": TOKEN}))
            got = texts_until(operator, lambda m: m["type"] == "health")
            assert time.monotonic() - t0 < 5
            kinds = [m["type"] for m in got]
            assert (
                "hello" in kinds
                and {"type": "auth", "ok": True} | {"message": "operator (an operator seat)"} in got
            ), got
