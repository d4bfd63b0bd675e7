"""The physical world end to end, as a user runs it: `ovis simulate --world physical`,
then `ovis calibrate` on its floor marks and `ovis locate`; `ovis up --world physical`
(real processes, real Zenoh on loopback) rendering the world live, calibrating on the
floor marks and scoring against the truth, heights included (`--cameras 2x2` over one
physical world: test_up_physical_grid.py); and what a machine without EGL gets: one
line and exit 2, and a test run that skips with the reason (or, as CI asks, fails)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import msgspec
import numpy as np
import pytest
from cli_helpers import assert_one_line_error, ovis
from physical_helpers import needs_physical
from pipeline_helpers import Recorder, start_up, up_log_dir
from zenoh_helpers import client, free_port, ovis_cmd, wait_for

from ovis.common.camera.projection import project
from ovis.common.config import config_from_dict, load_config, load_points
from ovis.common.physical.scene import random_scene

# alone: frames rendered live at 5 frames/s, all kept, and fits that land within seconds:
# a neighbour's CPU use would falsify both
pytestmark = pytest.mark.alone

#: a library that is not one, where the dynamic loader looks first: EGL fails to load
#: as on a machine without it
NOT_A_LIBRARY = "not a shared library\n"


def _without_egl(tmp_path: Path) -> dict[str, str]:
    """An environment in which EGL cannot be loaded (its library broken)."""
    fake = tmp_path / "no-egl"
    fake.mkdir(exist_ok=True)
    for name in ("libEGL.so.1", "libEGL.so"):
        (fake / name).write_text(NOT_A_LIBRARY)
    return dict(os.environ, LD_LIBRARY_PATH=str(fake))


@needs_physical
def test_simulate_then_calibrate_on_the_floor_marks_then_locate_them(tmp_path: Path) -> None:
    """The documented flow: the data set, `ovis calibrate` with its lens on the marks
    measured in the empty floor, and `ovis locate` puts every mark's pixel within 0.2 cm
    of where the mark is (and floor points elsewhere too)."""
    out = tmp_path / "phys"
    made = ovis("simulate", "--world", "physical", "--out", str(out), "--frames", "3",
                "--seed", "51", "--camera", "overhead", "--json")  # fmt: skip
    info = json.loads(made.stdout)
    assert len(info["frames"]) == 3 and info["marks_measured"] >= 4
    truth = json.loads((out / "truth.json").read_text())
    assert truth["world"] == "physical" and len(truth["frames"]) == 3
    assert [f["t_s"] for f in truth["frames"]] == [k / truth["fps"] for k in range(3)]
    calib = out / "calib.json"
    ovis("calibrate", str(out / "background.png"), "--intrinsics", str(out / "lens.yaml"),
         "--points", str(out / "points.toml"), "--out", str(calib))  # fmt: skip
    marks = truth["marks"]
    points = load_points(out / "points.toml")
    assert {p.name for p in points.points} == {m["name"] for m in marks}
    true_camera = json.loads((out / "true_calibration.json").read_text())["camera"]
    assert points.config is not None
    cam = config_from_dict(points.config).camera
    assert cam == msgspec.convert(true_camera, type(cam))
    x = np.array([m["x_cm"] for m in marks])
    y = np.array([m["y_cm"] for m in marks])
    px = project(x, y, np.zeros_like(x), cam)  # the marks' true pixels (their foot)
    args = [a for r, c in zip(px.row, px.col, strict=True) for a in ("--pixel", f"{r},{c}")]
    found = json.loads(ovis("locate", str(calib), *args, "--json").stdout)
    err = [math.hypot(f["x_cm"] - a, f["y_cm"] - b) for f, a, b in zip(found, x, y, strict=True)]
    assert max(err) < 0.2, err
    ovis("detect", str(out / "frame_0002.png"), "--calibration", str(calib))


def test_without_egl_the_physical_commands_say_so_in_one_line(tmp_path: Path) -> None:
    env = _without_egl(tmp_path)
    for args in (
        ["simulate", "--world", "physical", "--out", str(tmp_path / "x"), "--frames", "1"],
        ["up", "--world", "physical", "--duration", "1",
         "--listen", f"tcp/127.0.0.1:{free_port()}", "--state-dir", str(tmp_path / "st")],
    ):  # fmt: skip
        proc = subprocess.run(ovis_cmd(*args), capture_output=True, text=True, env=env,
                              timeout=120)  # fmt: skip
        assert_one_line_error(proc, "physical world cannot run here", "libegl1", code=2)
    assert not (tmp_path / "x").exists()


def test_a_test_run_without_egl_skips_the_physical_tests_and_ci_fails_them(
    tmp_path: Path,
) -> None:
    """The README's plain run skips them with a one-line reason; with
    OVIS_REQUIRE_PHYSICAL (CI) the same run fails."""
    here = Path(__file__).parent
    (tmp_path / "test_needs_it.py").write_text(
        "from physical_helpers import skip_module_without_physical\n"
        "skip_module_without_physical()\n"
        "from ovis.common.physical.world import PhysicalWorld  # noqa: E402\n\n"
        "def test_it():\n    assert PhysicalWorld\n"
    )
    (tmp_path / "test_others.py").write_text("def test_other():\n    assert True\n")
    env = _without_egl(tmp_path)
    env.pop("OVIS_REQUIRE_PHYSICAL", None)
    env["PYTHONPATH"] = str(here)
    cmd = [sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider", "."]
    plain = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert plain.returncode == 0 and "1 passed, 1 skipped" in plain.stdout, plain.stdout
    skipped = [ln for ln in plain.stdout.splitlines() if ln.startswith("SKIPPED")]
    assert len(skipped) == 1 and "physical world unavailable" in skipped[0], plain.stdout
    ci = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=tmp_path,
                        env=dict(env, OVIS_REQUIRE_PHYSICAL="1"))  # fmt: skip
    assert ci.returncode != 0 and "1 error" in ci.stdout, ci.stdout


@needs_physical
def test_up_physical_calibrates_on_the_marks_and_scores_against_the_physics(
    tmp_path: Path,
) -> None:
    """Frames rendered live (5 frames/s asked): each truth is the physics at its frame's
    instant (index / fps, stamped with it); the calibrator's calibration is made on the
    floor marks; heights measured (the preset's): every frame captured decodes and is
    processed, every obstacle found and nothing spurious, the robot reported as the
    robot; every height measured within 1 cm of the physics and its footprint within
    0.5 cm; the others only while their fits are still to come (their first frames)."""
    proc, endpoint, err = start_up(tmp_path, "--world", "physical", "--duration", "15",
                                   "--seed", "52")  # fmt: skip
    try:
        with client(endpoint) as session:
            rec = Recorder(session)
            wait_for(lambda: len(rec.truth) >= 5, 150, "5 truth frames")
            with rec.lock:
                truths = sorted(rec.truth.values(), key=lambda t: t.seq)
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err.read_text()
    cfg = load_config(preset="physical")
    scene = random_scene(cfg, 52, [cfg.camera])
    solids = {s.id: s for s in scene.solids}
    for truth in truths:
        t = _index_of(truth, truths[0], cfg.service.fps) / cfg.service.fps
        for obj in truth.objects:
            x, y = solids[obj.id].path.at(t, scene.period_s)
            assert math.hypot(obj.x_cm - float(x), obj.y_cm - float(y)) < 1e-6
            assert obj.z_cm == solids[obj.id].height_cm
    summary = json.loads(out)
    assert summary["calibration_version"] >= 1 and summary["frames_refused"] == 0
    # on a loaded 2-core host the renderer may keep only a few frames a second; what it
    # renders, the stages keep up with
    captured = summary["frames_captured"]
    assert captured >= 20 and summary["frames_processed"] >= 0.9 * captured, summary
    assert summary["truth_frames"] >= 20
    n = len(scene.solids)
    assert summary["objects_matched"] >= 0.8 * n * summary["frames_processed"], summary
    assert (summary["objects_missed"], summary["objects_spurious"]) == (0, 0), summary
    assert "measured" in summary["heights"]
    by = summary["by_height"]
    assert set(by) <= {"one camera", "configured (pending)"}, by
    measured = by["one camera"]
    assert measured["position_error_cm_max"] <= 0.5 and measured["height_error_cm_max"] <= 1.0
    assert measured["wrong_kind"] == 0  # the robot told by its fitted size and height
    # a blob waits for its fit only in the first seconds (one fit at a time, beside the
    # frames: a few seconds' work for the scene's solids, longer on a loaded host); the
    # frames after it have every height measured
    assert summary["fits_pending_s"] is None or summary["fits_pending_s"] <= 12.0, summary
    assert summary["latency_after_fits_ms_p50"] is not None
    after = summary["after_fits"]  # once every blob has had its fit
    if summary["fits_pending_s"] is not None:
        assert after["frames"] > 0, summary
        assert (after["objects_missed"], after["objects_spurious"]) == (0, 0), summary
        assert after["position_error_cm_max"] <= 0.5, summary
    assert measured["objects"] >= 0.25 * summary["objects_matched"], by
    calibrator = (Path(up_log_dir(err)) / "calibrator.log").read_text()
    assert "on the floor marks" in calibrator
    assert "segmented against its empty floor" in err.read_text()


def _index_of(truth, first, fps: float) -> int:
    """A truth's frame index from its stamp: whole periods of 1/fps after the first's
    (stamps are the instants shown, frame k at k / fps of the capture clock)."""
    steps = (truth.stamp_ns - first.stamp_ns) * fps / 1e9
    assert abs(steps - round(steps)) < 1e-3, steps
    return round(steps)
