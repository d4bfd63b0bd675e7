"""`ovis up --world physical --cameras 2x2`: four cameras over one physical world, each
calibrated on the floor marks it sees, fused into one world scored against the truth
(real processes, real Zenoh on loopback). Apart from test_up_physical.py, whose live
checks run alone: nothing here is timed, so it runs beside other files."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest
from physical_helpers import needs_physical
from zenoh_helpers import free_port, ovis_cmd

# long: a minute of start-up and rendering, started early so the run ends with both
# workers busy
pytestmark = pytest.mark.long


@needs_physical
def test_up_physical_cameras_2x2_fuses_one_physical_world(tmp_path: Path) -> None:
    cfg = tmp_path / "fast.toml"
    cfg.write_text(
        'preset = "physical"\n[physical]\nshadows = false\n[fusion]\nwait_ms = 250.0\n'
        f"[service]\nstate_dir = '{tmp_path / 'state'}'\n"
    )
    env = dict(os.environ, OVIS_CACHE=str(tmp_path / "cache"))
    args = ["up", "--world", "physical", "--cameras", "2x2", "--duration", "6", "--json",
            "--seed", "53", "--fps", "2", "--listen", f"tcp/127.0.0.1:{free_port()}",
            "--config", str(cfg)]  # fmt: skip
    proc = subprocess.run(ovis_cmd(*args), capture_output=True, text=True, env=env,
                          timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert "calibrated on the floor marks it sees" in proc.stderr
    assert all(c["captured"] >= 5 and c["processed"] >= 5 for c in summary["cameras"].values())
    world = summary["world"]
    assert world["frames"] >= 5 and world["scored"] >= 5
    assert world["height_error_cm"]["max"] >= world["height_error_cm"]["mean"] >= 0
    assert world["heights"]
