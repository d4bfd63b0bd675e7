"""Issue 28's forged status replies against `ovis up`: a client that knows only Zenoh and
MessagePack answers the status queries in the name of `ovis up`'s own processes (right
pid, host and start time, or another start time, or a new pid each time) with a billion
frames and drops; the summary's totals do not move, and its health says that two
different answers came in their name."""

from __future__ import annotations

import itertools
import json
import subprocess
from pathlib import Path
from typing import Any

import zenoh
from pipeline_helpers import start_up
from test_adversarial import ROOT, Attacker, _pack
from zenoh_helpers import ovis_cmd, wait_for

BILLION = 10**9


def _conflicted(endpoint: str) -> set[str]:
    """The services `ovis status --json` says are answered for by someone else (two
    different answers in their name: "degraded", with that reason)."""
    out = subprocess.run(
        ovis_cmd("status", "--connect", endpoint, "--json"),
        capture_output=True, text=True, timeout=60, check=True,
    ).stdout  # fmt: skip
    rows = [
        r for r in json.loads(out)
        if r["status"] and "two different status answers" in r["status"]["reason"]
    ]  # fmt: skip
    assert all(r["status"]["state"] == "degraded" for r in rows), rows
    return {r["service"] for r in rows}


def test_forged_statuses_do_not_move_ovis_ups_totals(tmp_path: Path) -> None:
    proc, endpoint, err = start_up(tmp_path, "--duration", "15", "--fps", "10", "--pin", "none")
    try:
        attacker = wait_for(lambda: Attacker.connect(endpoint), 30, "ovis up's router")
        try:
            genuine = {
                s: wait_for(
                    lambda s=s: attacker.ask(f"status/{s}", timeout=1.0), 60, f"{s}'s status"
                )[0]
                for s in ("capture", "pose")
            }
            pids = itertools.count(1_000_000)

            def forge(service: str, key: str, query: zenoh.Query) -> None:
                real = genuine[service]
                huge = {"frames_in": BILLION, "frames_out": BILLION, "dropped": BILLION}
                # the right pid last: the reply Zenoh keeps for a key, by default
                for started in (real["started_ns"] + 1, real["started_ns"]):
                    for pid in (next(pids), real["pid"]):
                        forged: dict[str, Any] = {**real, **huge, "started_ns": started, "pid": pid}
                        query.reply(f"{ROOT}/status/{key}", _pack(forged))

            # on the service's own key, and on keys of their own (the name that counts
            # is the one in the message)
            for service in genuine:
                for key in (service, f"{service}-forged"):
                    attacker.session.declare_queryable(
                        f"{ROOT}/status/{key}", lambda q, s=service, k=key: forge(s, k, q)
                    )
            # `ovis status` meanwhile: never the forger's "ok" alone, the conflict said
            wait_for(lambda: _conflicted(endpoint) >= set(genuine), 30, "ovis status saying it")
            out, _ = proc.communicate(timeout=120)
        finally:
            attacker.session.close()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    summary = json.loads(out.decode())
    assert proc.returncode == 0, (summary, err.read_text())
    # 15 s at 10 fps: about 150 frames, never a billion
    assert 0 < summary["frames_captured"] < 1000, summary
    assert all(n < 1000 for n in summary["dropped"].values()), summary["dropped"]
    # and the summary says someone answered in their name: never "ok" over a conflict
    for service in ("capture", "pose"):
        assert "two different status answers in its name" in summary["health"][service], summary
