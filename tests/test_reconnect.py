"""Sources that go away and come back: a real video file removed and put back, read by the
source object and by the capture service (a real process on a real router), which says
it lost it and plays it again once it is back; and a video that ends with looping off,
lost for good, as the capture service and the stream's health say."""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import zenoh
from zenoh_helpers import alive, client, free_port, ovis_cmd, spawn, stop, wait_for

from ovis.common.capture.sources import SourceEndedError, SourceError, StreamSource, open_source
from ovis.common.config import config_from_dict, load_config
from ovis.common.messages import (
    Frame,
    ServiceStatus,
    SourceState,
    StreamHealth,
    Topics,
    decode,
)
from ovis.services.cli.watching import query_statuses


def write_video(path: Path, frames: int = 12) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (160, 120))
    assert writer.isOpened()
    for i in range(frames):
        writer.write(np.full((120, 160, 3), 20 * i % 255, np.uint8))
    writer.release()


def capture_config(tmp_path: Path, video: Path) -> Path:
    """The video (8 frames) written, and a capture's config that plays it once at 4 fps."""
    write_video(video, frames=8)
    cfg = tmp_path / "cfg.toml"
    cfg.write_text(f'[service]\nsource = "{video}"\nloop = false\nfps = 4.0\n')
    return cfg


def frame_seqs(session: zenoh.Session) -> list[int]:
    """The sequence numbers of the frames published from now on, as they come."""
    seen: list[int] = []
    session.declare_subscriber(
        Topics("default").frames, lambda s: seen.append(decode(s.payload.to_bytes(), Frame).seq)
    )
    return seen


def test_video_source_reconnects_when_the_file_comes_back(tmp_path: Path) -> None:
    video, away = tmp_path / "cam.avi", tmp_path / "away.avi"
    write_video(video)
    src = open_source(str(video), load_config(), loop=False)
    assert [src.read()[0].shape for _ in range(12)] == [(120, 160, 3)] * 12
    video.rename(away)  # "unplugged"
    with pytest.raises(SourceError, match=r"delivered no frame .* reconnecting") as gone:
        src.read()
    assert not isinstance(gone.value, SourceEndedError)  # not ended: gone, maybe back
    with pytest.raises(SourceError, match="cannot open video"):
        src.read()
    away.rename(video)  # back
    assert src.read()[0].shape == (120, 160, 3)
    src.close()


def test_missing_sources_say_what_to_check() -> None:
    with pytest.raises(SourceError, match="existing video file"):
        open_source("/nonexistent/cam.avi", load_config())
    with pytest.raises(SourceError, match="check that it is connected"):
        open_source("camera:97", load_config())
    with pytest.raises(SourceError, match="check the URL"):
        StreamSource("rtsp://127.0.0.1:9/none")


def test_camera_settings_are_validated() -> None:
    cfg = config_from_dict({"service": {"camera_width": 1280, "camera_exposure": 50}})
    from ovis.common.capture.sources import capture_settings

    props = capture_settings(cfg)
    assert props[cv2.CAP_PROP_FRAME_WIDTH] == 1280 and props[cv2.CAP_PROP_EXPOSURE] == 50
    from ovis.common.config import ConfigError

    with pytest.raises(ConfigError, match="camera_width"):
        config_from_dict({"service": {"camera_width": 0}})


def test_a_video_that_ends_with_loop_off_is_lost_for_good_and_says_so(tmp_path: Path) -> None:
    """The capture (a real process) sends the video's frames once, then says "source
    lost" with the reason "ended: …" in its status, on its source topic and, through the
    pose stage, in the stream's health; it does not start the video again."""
    video = tmp_path / "cam.avi"
    cfg = capture_config(tmp_path, video)
    # no calibrator here: the pose stage runs on the simulator's settings (a real source's
    # stages listen only once a calibrator hands them a calibration); what it is checked
    # for is how it passes the capture's word on into the stream's health
    pose_cfg = tmp_path / "pose.toml"
    pose_cfg.write_text("[service]\nfps = 4.0\n")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = spawn(ovis_cmd("router", "--listen", endpoint), tmp_path / "router.log")
    procs = []
    topics = Topics("default")
    said: list[SourceState] = []
    health: list[StreamHealth] = []
    try:
        with client(endpoint) as session:
            seen = frame_seqs(session)
            session.declare_subscriber(
                topics.source, lambda s: said.append(decode(s.payload.to_bytes(), SourceState))
            )
            session.declare_subscriber(
                topics.health, lambda s: health.append(decode(s.payload.to_bytes(), StreamHealth))
            )
            for stage in ("pose", "capture"):  # the capture last: its frames are all seen
                procs.append(
                    spawn(
                        ovis_cmd(
                            "run",
                            stage,
                            "--connect",
                            endpoint,
                            "--config",
                            str(cfg if stage == "capture" else pose_cfg),
                        ),
                        tmp_path / f"{stage}.log",
                    )
                )
                wait_for(lambda stage=stage: stage in alive(session), 30, f"{stage} alive")

            def ended() -> ServiceStatus | None:
                st = query_statuses(session, topics).get("capture")
                return st if st is not None and st.state == "source lost" else None

            st = wait_for(ended, 30, "the capture to say its video ended")
            assert st.reason == f"ended: video {video}: all frames sent (loop is off)"
            assert (st.frames_out, st.source_gaps, st.gaps[0].ongoing) == (8, 1, True)
            wait_for(lambda: any(h.state == "source lost" for h in health), 5, "the health")
            time.sleep(2.0)
            assert seen and seen == list(range(seen[0], 8))  # once, not replayed
            assert said and all(m.ended and m.reason == st.reason for m in said)
            assert [h.reason for h in health if h.state == "source lost"][-1] == st.reason
            assert "capture" in alive(session) and all(p.poll() is None for p in procs)
    finally:
        stop([*procs, router])
    log = (tmp_path / "capture.log").read_text()
    assert "Traceback" not in log and "source lost: ended: video" in log


def test_the_capture_resumes_when_a_video_that_went_away_comes_back(tmp_path: Path) -> None:
    """A video (looping off) moved away while the capture (a real process) plays it: once
    its open file is read out, the capture says "source lost" (the file gone) and sends
    nothing; moved back, it plays it again, sequence numbers going on, and counts the
    loss as over. (A looping video moved away is not lost at all: OpenCV keeps reading
    the file it has open.)"""
    video, away = tmp_path / "cam.avi", tmp_path / "away.avi"
    cfg = capture_config(tmp_path, video)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = spawn(ovis_cmd("router", "--listen", endpoint), tmp_path / "router.log")
    procs = []
    topics = Topics("default")
    try:
        with client(endpoint) as session:
            seen = frame_seqs(session)
            procs.append(
                spawn(
                    ovis_cmd("run", "capture", "--connect", endpoint, "--config", str(cfg)),
                    tmp_path / "capture.log",
                )
            )
            wait_for(lambda: seen, 30, "the video's first frame")
            video.rename(away)  # unplugged while it plays

            def status(state: str, reason: str) -> ServiceStatus | None:
                st = query_statuses(session, topics).get("capture")
                return st if st and st.state == state and reason in st.reason else None

            # lost, and an attempt to open it again has failed: it is really away
            wait_for(lambda: status("source lost", "existing video file"), 30, "a failed reopen")
            away_seen = list(seen)
            st = status("source lost", "")
            assert st is not None and st.source_gaps == 1 and st.gaps[-1].ongoing
            assert (
                st.gaps[-1].reason == f"video {video} delivered no frame (file gone?); reconnecting"
            )
            assert away_seen == list(range(away_seen[0], 8))  # what the open file still held
            away.rename(video)  # plugged back
            wait_for(lambda: len(seen) >= len(away_seen) + 8, 30, "the video played again")
            assert seen[len(away_seen) :] == list(range(8, 16))  # the numbers go on
            st = wait_for(
                lambda: status("source lost", "ended: "), 30, "the video to end, loop off"
            )
            assert st.source_gaps == 2 and not st.gaps[0].ongoing and st.gaps[1].ongoing
            assert st.gaps[0].reason.endswith("(file gone?); reconnecting")
            assert procs[0].poll() is None
    finally:
        stop([*procs, router])
    log = (tmp_path / "capture.log").read_text()
    assert "Traceback" not in log and "source back after" in log
