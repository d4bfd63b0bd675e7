"""``ovis cameras simulate``: the simulated grid fused and scored from the command line."""

from __future__ import annotations

import json
import subprocess

from zenoh_helpers import ovis_cmd


def test_cameras_simulate_json_gives_the_issue_summary_fields() -> None:
    done = subprocess.run(
        ovis_cmd("cameras", "simulate", "--frames", "90", "--seed", "5", "--kill", "cam10",
                 "--json"),
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    out = json.loads(done.stdout)
    assert "fused 90/90 frames" in done.stderr  # progress, on stderr with --json
    assert set(out["cameras"]) == {"cam00", "cam10", "cam01", "cam11"}
    assert out["cameras"]["cam10"] == {"captured": 45, "processed": 45, "dropped": 0}
    assert out["cameras"]["cam00"]["processed"] == 90
    world = out["world"]
    assert world["frames"] == 90
    assert world["duplicates"] == 0 and world["identity_swaps"] == 0
    assert world["missed"] == 0 and world["phantoms"] == 0
    assert world["handover_jump_cm"] <= 1.0
    assert 0 < world["world_error_cm"]["mean"] <= 0.5
    assert world["world_error_cm"]["max"] >= world["world_error_cm"]["mean"]
    assert 0 < world["fuse_ms"]["p50"] <= world["fuse_ms"]["p99"]


def test_cameras_simulate_refuses_bad_input_in_one_line() -> None:
    for args, says in (
        (["--grid", "3by2"], "--grid '3by2': give columns x rows"),
        (["--kill", "cam99"], "no camera 'cam99' in a 2x2 grid"),
    ):
        done = subprocess.run(
            ovis_cmd("cameras", "simulate", "--frames", "2", *args),
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert done.returncode == 2
        last = done.stderr.strip().splitlines()[-1]
        assert last.startswith("error: ") and says in last
        assert "Traceback" not in done.stderr
