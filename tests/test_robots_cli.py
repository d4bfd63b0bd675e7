"""`ovis simulate --robots N --obstacles M` and `ovis detect … --json` with marked robots,
as real processes on real files; bad input ends in one line and exit code 2."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from cli_helpers import assert_one_line_error, ovis

from ovis.common.calibration.file import Calibration, save_calibration
from ovis.common.config import load_points

# long: minutes of work, started early so the run ends with both workers busy
pytestmark = pytest.mark.long


@pytest.fixture(scope="module")
def marked(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("marked")
    ovis("simulate", "--out", str(out), "--frames", "20", "--seed", "31",
         "--robots", "3", "--obstacles", "4")  # fmt: skip
    return out


def test_simulate_writes_marked_robots_with_truth(marked: Path) -> None:
    truth = json.loads((marked / "truth.json").read_text())
    assert len(truth["frames"]) == 20
    for frame in truth["frames"]:
        robots = [o for o in frame["objects"] if o["kind"] == "robot"]
        assert [(o["id"], o["marker_id"]) for o in robots] == [(1, 0), (2, 1), (3, 2)]
        for o in robots:
            assert {"x_cm", "y_cm", "heading_deg", "vx_cm_s", "vy_cm_s"} <= set(o)
        assert sum(o["kind"] == "obstacle" for o in frame["objects"]) == 4
    points = load_points(marked / "points.toml")
    assert [p.name for p in points.points][:3] == ["R1", "R2", "R3"]
    assert len(points.config["pose"]["robots"]) == 3


def test_detect_json_lists_robots_with_age(marked: Path) -> None:
    cfg = load_points(marked / "points.toml").config
    from ovis.common.config import config_from_dict

    config = config_from_dict(cfg)
    calib = Calibration(dipe_px=0.0, dipe_mm=0.0, dipe_max_px=0.0, dipe_max_mm=0.0,
                        camera=config.camera, image=config.image, pose=config.pose)  # fmt: skip
    path = marked / "calib.json"
    save_calibration(path, calib)
    frames = sorted(str(p) for p in marked.glob("frame_*.png"))
    result = json.loads(ovis("detect", *frames, "--calibration", str(path), "--fps", "30",
                             "--json").stdout)  # fmt: skip
    truth = json.loads((marked / "truth.json").read_text())["frames"]
    assert len(result) == 20
    for got, true in zip(result, truth, strict=True):
        want = {o["id"]: o for o in true["objects"] if o["kind"] == "robot"}
        assert [r["id"] for r in got["robots"]] == [1, 2, 3]
        for r in got["robots"]:
            o = want[r["id"]]
            assert r["age_s"] == 0.0 and r["marker_id"] == o["marker_id"]
            assert math.hypot(r["x_cm"] - o["x_cm"], r["y_cm"] - o["y_cm"]) < 0.5
        assert sum(o["kind"] == "obstacle" for o in got["objects"]) == 4
    last = result[-1]["robots"][0]
    o = {o["id"]: o for o in truth[-1]["objects"]}[1]
    assert math.hypot(last["vx_cm_s"] - o["vx_cm_s"], last["vy_cm_s"] - o["vy_cm_s"]) < 3.0
    text = ovis("detect", frames[0], "--calibration", str(path)).stdout
    assert "robots" in text and "planner inputs of robot 1" in text


def test_two_robots_on_one_marker_is_a_one_line_error(tmp_path: Path) -> None:
    robots = [
        {"id": i, "name": n, "marker_id": 5, "marker_side_cm": 7.0, "marker_height_cm": 5.0,
         "radius_cm": 9.0}
        for i, n in ((1, "ann"), (2, "bob"))
    ]  # fmt: skip
    from ovis.common.config import dump_toml

    cfg = tmp_path / "c.toml"
    cfg.write_text(dump_toml({"pose": {"robots": robots}}))
    proc = ovis("simulate", "--out", str(tmp_path / "x"), "--config", str(cfg), check=False)
    assert proc.returncode == 2
    assert_one_line_error(proc, "'ann' (id 1)", "'bob' (id 2)", "marker 5")


def test_robots_that_cannot_fit_say_so(tmp_path: Path) -> None:
    proc = ovis("simulate", "--out", str(tmp_path / "x"), "--robots", "40", "--frames", "1",
                check=False)  # fmt: skip
    assert proc.returncode == 2
    assert_one_line_error(proc, "cannot find crossing paths for 40 robots")
