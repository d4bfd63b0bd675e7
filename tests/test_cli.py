"""The `ovis` command line, run as a real process: outputs, files and one-line errors."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, ovis

from ovis.common.calibration.file import load_calibration
from ovis.common.config import load_points
from ovis.services.bus import interruptible

TABLE_1_T1 = [
    "--robot",
    "98.241,30.626",
    "--goal",
    "65,105",
    "--obstacle",
    "28.715,26.300,4.884",
    "--obstacle",
    "96.862,132.382,5.272",
]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sim")
    ovis("simulate", "--out", str(out), "--frames", "3", "--seed", "4")
    return out


@pytest.fixture(scope="module")
def calibration(dataset: Path) -> Path:
    out = dataset / "calib.json"
    ovis(
        "calibrate",
        str(dataset / "frame_0000.png"),
        "--points",
        str(dataset / "points.toml"),
        "--out",
        str(out),
        "--plot",
        str(dataset / "conv.png"),
        "--quiet",
    )
    return out


def test_plan_reproduces_table_1_json() -> None:
    rows = json.loads(ovis("plan", *TABLE_1_T1, "--json").stdout)
    assert [r["distance_cm"] for r in rows] == pytest.approx([64.776, 96.493], abs=0.002)
    assert set(rows[0]) == {"distance_cm", "angle_deg"}


def test_simulate_writes_frames_truth_and_points(dataset: Path) -> None:
    assert sorted(p.name for p in dataset.glob("frame_*.png")) == [
        "frame_0000.png",
        "frame_0001.png",
        "frame_0002.png",
    ]
    truth = json.loads((dataset / "truth.json").read_text())
    assert {"camera", "frames"} <= set(truth)
    obj = truth["frames"][0]["objects"][0]
    assert {"id", "kind", "x_cm", "y_cm", "radius_cm"} <= set(obj)
    pts = load_points(dataset / "points.toml")
    assert [p.name for p in pts.points] == ["R", "O1", "O2", "O3"]
    assert pts.config is not None and pts.config["camera"]["cols"] == 640


def test_calibrate_out_of_the_box(calibration: Path, dataset: Path) -> None:
    calib = load_calibration(calibration)
    raw = json.loads(calibration.read_text())
    assert raw["dipe_px"] == calib.dipe_px and "dipe_mm" in raw
    assert calib.dipe_mm < 0.735214
    assert len(calib.points) == 4 and len(calib.history) == 91
    assert (dataset / "conv.png").stat().st_size > 10_000


def test_detect_json_and_overlay(calibration: Path, dataset: Path) -> None:
    overlay = dataset / "overlay.png"
    out = json.loads(
        ovis(
            "detect",
            str(dataset / "frame_0002.png"),
            "--calibration",
            str(calibration),
            "--goal",
            "65,115",
            "--json",
            "--overlay",
            str(overlay),
        ).stdout
    )
    truth = json.loads((dataset / "truth.json").read_text())["frames"][2]["objects"]
    objs = out["objects"]
    assert len(objs) == len(truth) == 4
    keys = {
        "id",
        "kind",
        "row",
        "col",
        "area_px",
        "perimeter_px",
        "compactness",
        "x_cm",
        "y_cm",
        "radius_cm",
    }
    assert all(keys <= set(o) for o in objs)
    assert sorted(o["kind"] for o in objs) == ["obstacle"] * 3 + ["robot"]
    for t in truth:
        err = min(np.hypot(o["x_cm"] - t["x_cm"], o["y_cm"] - t["y_cm"]) for o in objs)
        assert err < 1.0
    assert len(out["planner"]) == 3
    assert {"obstacle_id", "distance_cm", "angle_deg"} == set(out["planner"][0])
    # The planner entries agree with `ovis plan` on the detected positions.
    robot = next(o for o in objs if o["kind"] == "robot")
    obstacles = {o["id"]: o for o in objs if o["kind"] == "obstacle"}
    args = ["--robot", f"{robot['x_cm']},{robot['y_cm']}", "--goal", "65,115"]
    for e in out["planner"]:
        o = obstacles[e["obstacle_id"]]
        args += ["--obstacle", f"{o['x_cm']},{o['y_cm']},{o['radius_cm']}"]
    planned = json.loads(ovis("plan", *args, "--json").stdout)
    assert [p["distance_cm"] for p in planned] == pytest.approx(
        [e["distance_cm"] for e in out["planner"]], abs=1e-9
    )
    assert overlay.stat().st_size > 10_000


def test_config_show_roundtrip(tmp_path: Path) -> None:
    text = ovis("config", "show", "--preset", "paper").stdout
    assert "theta_deg = 70.0" in text and "[paper]" in text
    cfg = tmp_path / "c.toml"
    cfg.write_text(text)
    again = ovis("config", "show", "--config", str(cfg)).stdout
    assert "s_x = 0.134" in again


def test_help_explains() -> None:
    for cmd in ("simulate", "calibrate", "detect", "plan", "demo"):
        out = ovis(cmd, "--help").stdout
        assert "Usage: " in out and len(out) > 400


def test_bad_inputs_give_one_line_errors(tmp_path: Path, dataset: Path, calibration: Path) -> None:
    frame = str(dataset / "frame_0000.png")
    points = str(dataset / "points.toml")
    not_image = tmp_path / "x.png"
    not_image.write_text("hello")
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    bad_points = tmp_path / "p.toml"
    bad_points.write_text('[[points]]\nname = "R"\nx_cm = 1\n')
    bad_config = tmp_path / "c.toml"
    bad_config.write_text("[ga]\npc = 1.5\n")
    nan_config = tmp_path / "n.toml"
    nan_config.write_text("[camera]\nlam_mm = nan\n")
    out = str(tmp_path / "c.json")
    assert_one_line_error(
        ovis("calibrate", str(not_image), "--points", points, "--out", out, check=False),
        "cannot read",
    )
    assert_one_line_error(
        ovis("calibrate", str(empty), "--points", points, "--out", out, check=False), "empty"
    )
    assert_one_line_error(
        ovis("calibrate", frame, "--points", str(bad_points), "--out", out, check=False),
        "points file",
        "y_cm",
    )
    assert_one_line_error(
        ovis(
            "calibrate",
            frame,
            "--points",
            points,
            "--config",
            str(bad_config),
            "--out",
            out,
            check=False,
        ),
        "$.ga.pc",
        "<= 1.0",
    )
    assert_one_line_error(
        ovis(
            "calibrate", frame, "--points", points, "-c", str(nan_config), "--out", out, check=False
        ),
        "$.camera.lam_mm",
    )
    # A frame of bare floor can never show four objects: infeasible, exit 3.
    import cv2

    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((480, 640), 60, np.uint8))
    proc = ovis(
        "calibrate", str(blank), "--points", points, "--out", out, "--generations", "3", check=False
    )
    assert_one_line_error(proc, "infeasible", "exactly 4 objects")
    assert proc.returncode == 3
    assert not Path(out).exists()
    assert_one_line_error(
        ovis("detect", frame, "--calibration", str(tmp_path / "none.json"), check=False),
        "does not exist",
    )
    broken = tmp_path / "broken.json"
    broken.write_text(calibration.read_text().replace('"dipe_px"', '"dipe_pix"'))
    assert_one_line_error(
        ovis("detect", frame, "--calibration", str(broken), check=False), "invalid"
    )
    assert_one_line_error(
        ovis("detect", frame, "--calibration", str(calibration), "--goal", "1,nan", check=False),
        "--goal",
    )
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((100, 100), np.uint8))
    assert_one_line_error(
        ovis("detect", str(small), "--calibration", str(calibration), check=False), "640x480"
    )


def test_a_result_that_comes_after_stop_won_is_discarded_not_leaked() -> None:
    """A client stopped while its session was still opening: the call returns None at
    once, and the session that opens afterwards is handed to ``discard`` (closed)."""
    stop, release, discarded = threading.Event(), threading.Event(), []

    def slow_open() -> str:
        release.wait(10)
        return "session"

    stop.set()
    assert interruptible(stop, slow_open, discard=discarded.append) is None
    release.set()
    deadline = time.monotonic() + 5
    while not discarded and time.monotonic() < deadline:
        time.sleep(0.01)
    assert discarded == ["session"]
    # in time, the result is the caller's and nothing is discarded
    assert interruptible(threading.Event(), lambda: "kept", discard=discarded.append) == "kept"
    assert discarded == ["session"]
