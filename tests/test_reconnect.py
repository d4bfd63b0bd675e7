"""Sources that go away and come back: a real video file removed and put back, read by the
source object and by the capture service (a real process on a real router)."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from zenoh_helpers import client, free_port, ovis_cmd, spawn, stop, wait_for

from ovis.common.capture.sources import SourceError, StreamSource, open_source
from ovis.common.config import config_from_dict, load_config
from ovis.common.messages import Frame, Topics, decode


def write_video(path: Path, frames: int = 12) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (160, 120))
    assert writer.isOpened()
    for i in range(frames):
        writer.write(np.full((120, 160, 3), 20 * i % 255, np.uint8))
    writer.release()


def test_video_source_reconnects_when_the_file_comes_back(tmp_path: Path) -> None:
    video, away = tmp_path / "cam.avi", tmp_path / "away.avi"
    write_video(video)
    src = open_source(str(video), load_config(), loop=False)
    assert [src.read()[0].shape for _ in range(12)] == [(120, 160, 3)] * 12
    video.rename(away)  # "unplugged"
    with pytest.raises(SourceError, match=r"delivered no frame .* reconnecting"):
        src.read()
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


def test_capture_service_resumes_after_the_video_comes_back(tmp_path: Path) -> None:
    video, away = tmp_path / "cam.avi", tmp_path / "away.avi"
    write_video(video, frames=8)
    cfg = tmp_path / "cfg.toml"
    cfg.write_text(f'[service]\nsource = "{video}"\nloop = false\nfps = 20.0\n')
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = spawn(ovis_cmd("router", "--listen", endpoint), tmp_path / "router.log")
    capture = spawn(
        ovis_cmd("run", "capture", "--connect", endpoint, "--config", str(cfg)),
        tmp_path / "capture.log",
    )
    seen: list[tuple[float, int]] = []
    lock = threading.Lock()

    def on_frame(sample) -> None:
        f = decode(sample.payload.to_bytes(), Frame)
        with lock:
            seen.append((time.monotonic(), f.seq))

    try:
        with client(endpoint) as session:
            session.declare_subscriber(Topics("default").frames, on_frame)
            wait_for(lambda: len(seen) >= 5, 30, "frames from the video")
            video.rename(away)  # unplugged: the reader hits the end, cannot reopen
            time.sleep(4.0)
            with lock:
                gone_at, before = time.monotonic(), len(seen)
            time.sleep(2.5)
            with lock:
                assert len(seen) == before  # nothing while it is away
            away.rename(video)  # plugged back
            wait_for(lambda: len(seen) >= before + 5, 30, "frames after the video is back")
            with lock:
                after = [s for t, s in seen if t > gone_at]
            assert after == sorted(after) and after[0] > max(s for t, s in seen if t <= gone_at)
            assert capture.poll() is None
    finally:
        stop([capture, router])
    log = (tmp_path / "capture.log").read_text()
    assert "Traceback" not in log and "reconnecting" in log and "existing video file" in log
