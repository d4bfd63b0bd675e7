"""What the commands compute, without the command line: configuration with options,
image files, export summaries, and the scoring of `ovis up` and `ovis demo` against the
simulator's ground truth."""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import msgspec
import numpy as np
import pytest

from ovis.common.analysis.evaluation import TrackingScore, match_objects
from ovis.common.analysis.live import KEEP, LiveScore
from ovis.common.analysis.tracking import track_simulated
from ovis.common.calibration.file import calibration_from_config
from ovis.common.camera.export import as_pinhole, export_note, export_summary
from ovis.common.camera.pinhole import camera_matrix
from ovis.common.config import (
    ConfigError,
    config_from_dict,
    dump_toml,
    load_config,
    resolve_config,
    router_zenoh,
    with_ga,
    with_options,
)
from ovis.common.messages import ObstacleFrame, ServiceStatus, TruthFrame
from ovis.common.sim.arena import Arena
from ovis.common.vision.frames import ImageError
from ovis.common.vision.imageio import read_image
from ovis.common.world.detection import Detector

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "chessboard-9x6"
CFG = load_config(preset="default")

# --- configuration ------------------------------------------------------------------------


def test_options_are_laid_over_the_file_and_validated(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text('preset = "paper"\n[service]\narena = "lab"\nfps = 12.0\n')
    cfg = with_options(path, connect=["tcp/10.0.0.1:7447"], fps=None, source="sim", cpus=[1])
    assert (cfg.preset, cfg.service.arena, cfg.service.fps) == ("paper", "lab", 12.0)
    assert (cfg.service.source, cfg.service.cpus) == ("sim", [1])
    assert cfg.zenoh.connect == ["tcp/10.0.0.1:7447"]
    assert with_options(None, mode="router").zenoh.mode == "router"
    with pytest.raises(ConfigError, match="command-line options"):
        with_options(None, fps=-1.0)


def test_a_command_takes_the_file_else_the_points_table_else_the_preset(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text('preset = "pinhole"\n')
    table = {"preset": "paper"}
    assert resolve_config(path, "default", table).preset == "pinhole"
    assert resolve_config(None, None, table).preset == "paper"
    assert resolve_config(None, "default", table).preset == "default"
    assert resolve_config(None, None).preset == "default"


def test_ga_overrides_replace_only_what_is_given() -> None:
    cfg = with_ga(CFG, seed=5, pm=None, polish=False)
    assert (cfg.ga.seed, cfg.ga.pm, cfg.ga.polish) == (5, CFG.ga.pm, False)
    assert with_ga(CFG, seed=None) is CFG


def test_router_listens_and_meshes_as_told(tmp_path: Path) -> None:
    default = "tcp/127.0.0.1:7447"
    zc = router_zenoh(CFG, None, listen=None, connect=None, default_endpoint=default)
    assert (zc.listen, zc.connect) == ([default], [])
    path = tmp_path / "r.toml"
    path.write_text('[zenoh]\nconnect = ["tcp/10.0.0.2:7447"]\nlisten = ["tcp/0.0.0.0:7448"]\n')
    cfg = load_config(path)
    zc = router_zenoh(cfg, path, listen=None, connect=None, default_endpoint=default)
    assert (zc.listen, zc.connect) == (["tcp/0.0.0.0:7448"], ["tcp/10.0.0.2:7447"])
    zc = router_zenoh(cfg, path, listen=["tcp/0.0.0.0:9"], connect=None, default_endpoint=default)
    assert zc.listen == ["tcp/0.0.0.0:9"]
    # A client's connect from the defaults is not a router's mesh: only what the file says.
    client = config_from_dict({"zenoh": {"connect": ["tcp/1.2.3.4:7447"]}})
    path.write_text(dump_toml({"zenoh": {"listen": ["tcp/0.0.0.0:7450"]}}))
    zc = router_zenoh(client, path, listen=None, connect=None, default_endpoint=default)
    assert zc.connect == []


# --- image files ----------------------------------------------------------------------------


def test_read_image_reads_real_photos_as_opencv_does() -> None:
    if not DATA.is_dir():
        pytest.skip(f"the chessboard photos are not at {DATA} (../shared beside the clone)")
    for path in sorted(DATA.glob("*.jpg"))[:3]:
        image = read_image(path)
        assert image.dtype == np.uint8 and image.shape[:2] == (512, 640)
        assert np.array_equal(image, cv2.imread(str(path), cv2.IMREAD_UNCHANGED))


def test_read_image_keeps_the_high_byte_of_16_bits(tmp_path: Path) -> None:
    deep = (np.arange(12 * 16, dtype=np.uint16).reshape(12, 16) * 300).astype(np.uint16)
    cv2.imwrite(str(tmp_path / "d.png"), deep)
    assert np.array_equal(read_image(tmp_path / "d.png"), (deep >> 8).astype(np.uint8))


@pytest.mark.parametrize(
    ("make", "needle"),
    [
        (lambda p: p, "does not exist"),
        (lambda p: (p.mkdir(), p)[1], "is a folder"),
        (lambda p: (p.write_bytes(b""), p)[1], "is empty (0 bytes)"),
        (lambda p: (p.write_bytes(b"not a png"), p)[1], "cannot read"),
    ],
)
def test_read_image_says_what_is_wrong(tmp_path: Path, make, needle: str) -> None:
    with pytest.raises(ImageError, match=needle.replace("(", r"\(").replace(")", r"\)")):
        read_image(make(tmp_path / "x.png"))


# --- export -----------------------------------------------------------------------------------


def test_export_summary_and_note() -> None:
    paper = as_pinhole(CFG.camera)
    summary = export_summary("paper", paper, opencv=Path("k.yaml"), ros=None)
    assert summary["exact"] is False and summary["opencv"] == "k.yaml" and summary["ros"] is None
    assert np.allclose(summary["camera_matrix"], camera_matrix(paper.camera))
    assert summary["fit_rms_px"] == paper.rms_px < summary["fit_max_px"] == paper.max_px
    assert "Brown-Conrady fit residual" in export_note(paper, "c.json")
    exact = as_pinhole(load_config(preset="pinhole").camera)
    assert export_note(exact, "c.json") == "from c.json (pinhole model)"
    assert export_summary("pinhole", exact, opencv=None, ros=Path("r"))["fit_max_px"] == 0.0


# --- scoring against ground truth --------------------------------------------------------------


def _truth_run(frames: int, seed: int = 2):
    """A simulated run with the true camera: (detections, truths) per frame."""
    arena = Arena(CFG, seed)
    calib = msgspec.structs.replace(calibration_from_config(CFG), camera=arena.truth_camera)
    detector = Detector(calib.camera, calib.image, calib.pose)
    out = []
    for _ in range(frames):
        arena.step()
        image, truth = arena.render()
        out.append((detector.detect(image).objects, truth.objects))
    return out


def test_tracking_score_adds_up_frames_and_counts_identity_switches() -> None:
    run = _truth_run(3)
    score = TrackingScore()
    for det, truth in run:
        score.add(det, truth)
    per_frame = [match_objects(d, t) for d, t in run]
    true_objects = sum(len(t) for _, t in run)
    assert score.matched == sum(a.truth_index.size for a in per_frame) == true_objects
    assert score.missed == score.spurious == score.wrong_kind == score.id_switches == 0
    assert len(score.position_error_cm) == score.matched
    assert max(score.position_error_cm) < 1.0

    # The same frames with the detections' ids swapped in the last frame: 2 switches.
    det, truth = run[-1]
    swapped = [msgspec.structs.replace(o, id=o.id) for o in det]
    swapped[0], swapped[1] = (
        msgspec.structs.replace(swapped[0], id=det[1].id),
        msgspec.structs.replace(swapped[1], id=det[0].id),
    )
    score.add(swapped, truth)
    assert score.id_switches == 2


def test_tracking_a_simulated_run_finds_every_object() -> None:
    arena = Arena(CFG, 4)
    detector = Detector(arena.truth_camera, CFG.image, CFG.pose)
    run = track_simulated(arena, detector, 4)
    assert run.detect_s.shape == (4,) and (run.detect_s > 0).all()
    assert run.score.missed == run.score.spurious == 0 and run.score.id_switches == 0
    assert run.last_detection is not None and run.last_frame is not None


def _frame(seq: int, objects, stamp_ns: int) -> ObstacleFrame:
    robot = next((o for o in objects if o.kind == "robot"), None)
    return ObstacleFrame(
        seq=seq,
        stamp_ns=stamp_ns,
        published_ns=stamp_ns,
        frame_age_ms=0.0,
        calibration_version=3,
        robot=robot,
        obstacles=[o for o in objects if o.kind == "obstacle"],
        planner=[],
        arena="default",
    )


def test_live_score_matches_frames_to_truth_in_any_order_and_summarises() -> None:
    run = _truth_run(3, seed=5)
    live = LiveScore()
    base = time.time_ns()
    # Frame 0's truth first, frame 1's obstacles first, frame 2's truth never comes.
    live.add_truth(TruthFrame(seq=0, objects=run[0][1]))
    live.add_obstacles(_frame(0, run[0][0], base), base + 2_000_000)
    live.add_obstacles(_frame(1, run[1][0], base), base + 4_000_000)
    live.add_truth(TruthFrame(seq=1, objects=run[1][1]))
    live.add_obstacles(_frame(2, run[2][0], base), base + 6_000_000)
    assert live.score.matched == len(run[0][1]) + len(run[1][1])
    latest, lat = live.recent()
    assert latest is not None and latest.seq == 2 and lat == pytest.approx([2.0, 4.0, 6.0])

    status = ServiceStatus(
        service="capture", pid=1, host="h", started_ns=0, state="ok", frames_out=9, dropped=1
    )
    s = live.summary({"capture": status}, {"capture": 0}, 12.345, {"pose": 1, "label": 0})
    assert (s.frames_captured, s.frames_processed, s.duration_s) == (9, 3, 12.35)
    assert (s.latency_ms_p50, s.latency_ms_max) == pytest.approx((4.0, 6.0))
    assert s.objects_matched == live.score.matched and s.objects_missed == 0
    assert s.position_error_cm_max < 1.0 and s.calibration_version == 3
    assert (s.dropped, s.restarts, s.exit_codes) == ({"capture": 1}, {"pose": 1}, {"capture": 0})


def test_a_live_score_gives_the_frames_after_the_last_fit_apart() -> None:
    """Measured heights: the first frames hold an object waiting for its fit (reported
    roughly, 3 cm off here, one obstacle missing); the summary's ``after_fits`` scores
    only the frames after the last such frame, so the steady state shows apart from the
    start."""
    run = _truth_run(5, seed=5)
    live = LiveScore()
    base = time.time_ns()
    for k, (objects, truth) in enumerate(run):
        stamp = base + k * 200_000_000
        if k < 2:  # one obstacle waits for its fit, 3 cm off; another is not found yet
            first, *rest = [o for o in objects if o.kind == "obstacle"]
            waiting = msgspec.structs.replace(
                first, x_cm=first.x_cm + 3.0, z_source="configured", z_unmeasured="pending"
            )
            objects = [o for o in objects if o.kind == "robot"] + [waiting, *rest[1:]]
        live.add_truth(TruthFrame(seq=k, objects=truth))
        live.add_obstacles(_frame(k, objects, stamp), stamp + 5_000_000)
    s = live.summary({}, {}, 1.0)
    assert s.fits_pending_s == pytest.approx(0.2)
    assert s.objects_missed == 2 and s.position_error_cm_max >= 3.0
    after = s.after_fits
    assert after is not None and after.frames == 3
    assert (after.objects_missed, after.objects_spurious) == (0, 0)
    assert after.objects_matched == sum(len(t) for _, t in run[2:])
    assert after.position_error_cm_max < 1.0
    assert LiveScore().summary({}, {}, 1.0).after_fits is None


def test_a_closed_live_score_counts_no_frame_that_came_after_the_capture_count() -> None:
    """`ovis up` closes its score before it asks the capture for its count: a frame
    processed after that is not counted, so processed never exceeds captured."""
    run = _truth_run(2, seed=5)
    live, base = LiveScore(), time.time_ns()
    live.add_obstacles(_frame(0, run[0][0], base), base + 2_000_000)
    live.close()
    live.add_obstacles(_frame(1, run[1][0], base), base + 4_000_000)
    status = ServiceStatus(service="capture", pid=1, host="h", started_ns=0, state="ok",
                           frames_out=1)  # fmt: skip
    s = live.summary({"capture": status}, {"capture": 0}, 1.0)
    assert (s.frames_captured, s.frames_processed) == (1, 1) and live.latest.seq == 0


def test_live_score_keeps_a_bounded_backlog() -> None:
    live = LiveScore()
    for seq in range(KEEP + 10):
        live.add_truth(TruthFrame(seq=seq, objects=[]))
    assert len(live._truth) == KEEP and next(iter(live._truth)) == 10
    empty = LiveScore().summary({}, {}, 0.0)
    assert (empty.latency_ms_p50, empty.position_error_cm_mean, empty.calibration_version) == (
        None,
        None,
        -1,
    )
