"""Frame sources of the capture service: simulated, folder, video, camera."""

from __future__ import annotations

from pathlib import Path

import cv2
import msgspec
import numpy as np
import pytest

from ovis.common.capture.sources import (
    CameraSource,
    FolderSource,
    SimSource,
    SourceEndedError,
    SourceError,
    VideoSource,
    open_source,
)
from ovis.common.config import load_config

CFG = load_config()


def test_sim_source_gives_frames_with_truth_and_replays_prerendered() -> None:
    live = SimSource(CFG, 3)
    a, ta = live.read()
    b, tb = live.read()
    assert a.shape == (480, 640) and ta is not None and ta.index == 0 and tb.index == 1
    replay = SimSource(CFG, 3, prerender=2)
    frames = [replay.read() for _ in range(4)]
    np.testing.assert_array_equal(frames[0][0], a)
    np.testing.assert_array_equal(frames[2][0], a)  # looped
    np.testing.assert_array_equal(frames[3][0], b)


def test_folder_source_sorts_loops_and_stops(tmp_path: Path) -> None:
    for i in (2, 0, 1):
        cv2.imwrite(str(tmp_path / f"f{i}.png"), np.full((8, 9), i * 10, np.uint8))
    (tmp_path / "notes.txt").write_text("not an image")
    src = FolderSource(tmp_path, loop=True)
    values = [int(src.read()[0][0, 0]) for _ in range(4)]
    assert values == [0, 10, 20, 0]
    once = FolderSource(tmp_path, loop=False)
    for _ in range(3):
        once.read()
    with pytest.raises(SourceEndedError, match=r"^ended: folder .* all images sent"):
        once.read()
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(SourceError, match="holds no images"):
        FolderSource(empty)


def test_video_source_reads_and_loops(tmp_path: Path) -> None:
    path = tmp_path / "v.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    if not writer.isOpened():
        pytest.skip("this OpenCV build cannot write MJPG video")
    for i in range(3):
        writer.write(np.full((48, 64, 3), 40 + 80 * i, np.uint8))
    writer.release()
    src = VideoSource(path, loop=True)
    means = [float(src.read()[0].mean()) for _ in range(5)]
    src.close()
    assert means[0] == pytest.approx(40, abs=6) and means[2] == pytest.approx(200, abs=6)
    assert means[3] == pytest.approx(40, abs=6)  # looped
    once = VideoSource(path, loop=False)
    assert [once.read()[0].shape for _ in range(3)] == [(48, 64, 3)] * 3
    with pytest.raises(SourceEndedError, match=r"^ended: video .* all frames sent"):
        once.read()


def test_missing_camera_says_what_to_check() -> None:
    with pytest.raises(SourceError, match="check that it is connected"):
        CameraSource("/dev/video-ovis-missing")
    with pytest.raises(SourceError, match="camera index must be a number"):
        open_source("camera:x", CFG)
    with pytest.raises(SourceError, match="is not 'sim'"):
        open_source("/nonexistent/thing", CFG)


def test_open_source_dispatch(tmp_path: Path) -> None:
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((4, 4), np.uint8))
    assert isinstance(open_source("sim", CFG), SimSource)
    assert isinstance(open_source(str(tmp_path), CFG), FolderSource)
    cfg = msgspec.structs.replace(CFG, service=msgspec.structs.replace(CFG.service, prerender=1))
    assert "replaying 1" in open_source("sim", cfg).description
