"""MCAP files written by other tools, end to end: `ovis replay` publishes the real photos
of a Foxglove (JSON, protobuf) or ROS 2 (CDR) image channel as ovis frames, pixel for
pixel, at the pace of their log times; `ovis up --source X.mcap` processes them; a file
with no usable channel, or several and no --topic, stops both with exit code 2 and the
channels found. Real router, real processes, real photos."""

from __future__ import annotations

import json
import signal
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from cli_helpers import assert_one_line_error
from foreign_mcap import (
    ForeignMcap,
    no_image_channel,
    raw_fields,
    two_image_channels,
    write_photos,
)
from pipeline_helpers import start_up
from real_photos import photo_bytes_and_pixels, photo_calibration
from zenoh_helpers import client, free_port, ovis_cmd, spawn, stop, wait_for, wait_subscribed

from ovis.common.messages import Frame, decode

PERIOD = 100_000_000  # ns between two photos' log times


@pytest.fixture(scope="module")
def photos() -> list[tuple[bytes, np.ndarray]]:
    return photo_bytes_and_pixels()


@pytest.fixture(scope="module")
def router(tmp_path_factory) -> str:
    log = tmp_path_factory.mktemp("router") / "router.log"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = spawn(ovis_cmd("router", "--listen", endpoint), log)
    try:
        wait_for(lambda: "listening" in log.read_text(), 30, "the router")
        yield endpoint
    finally:
        stop([proc])


class Frames:
    """Every frame published on ``ovis/*/frames``: its key, the frame, when it came."""

    def __init__(self, session: zenoh.Session) -> None:
        self.got: list[tuple[str, Frame, float]] = []
        self.lock = threading.Lock()
        self.sub = session.declare_subscriber("ovis/*/frames", self._keep)

    def _keep(self, sample: zenoh.Sample) -> None:
        frame = decode(sample.payload.to_bytes(), Frame)
        with self.lock:
            self.got.append((str(sample.key_expr), frame, time.monotonic()))

    def all(self) -> list[tuple[str, Frame, float]]:
        with self.lock:
            return list(self.got)


def _replay(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(ovis_cmd("replay", *args), capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize(
    "flavour",
    [
        "foxglove json jpeg",
        "foxglove protobuf raw mono8",
        "ros2 compressed jpeg",
        "ros2 raw rgb8 padded",
    ],
)
def test_replay_publishes_the_photos_as_frames_at_their_pace(
    tmp_path: Path, photos, router: str, flavour: str
) -> None:
    path = tmp_path / "other.mcap"
    t0 = time.time_ns()
    expected = write_photos(path, photos, flavour, t0, PERIOD)
    with client(router) as session:
        frames = Frames(session)
        wait_subscribed(router, "ovis/default/frames")
        done = _replay(str(path), "--connect", router)
        assert done.returncode == 0, done.stderr
        wait_for(lambda: len(frames.all()) >= len(photos), 10, "every replayed frame")
        time.sleep(0.3)
        got = frames.all()
    assert len(got) == len(photos)
    assert "replayed 14 messages (frames 14) in 1 pass(es) from /camera/image (" in done.stdout
    assert "frames from /camera/image (" in done.stderr and ": 640x512 " in done.stderr
    for k, (key, frame, _) in enumerate(got):
        assert key == "ovis/default/frames"
        assert frame.seq == k and frame.stamp_ns == t0 + k * PERIOD  # the log times
        assert frame.source == f"{path} /camera/image"
        assert (frame.rows, frame.cols) == (512, 640)
        assert np.array_equal(frame.image(), expected[k]), k  # bit for bit
    # at the recorded pace: 13 periods between the first and the last (never sooner)
    assert got[-1][2] - got[0][2] >= 13 * PERIOD / 1e9 * 0.9


def test_topic_picks_a_channel_and_without_it_several_are_refused(
    tmp_path: Path, photos, router: str
) -> None:
    path = tmp_path / "two.mcap"
    two_image_channels(path, photos[:3], time.time_ns())
    line = assert_one_line_error(_replay(str(path), "--connect", router), code=2)
    assert "holds 2 image channels: pick one with --topic NAME: " in line
    assert "/left (foxglove.CompressedImage, json, 3 messages)" in line
    assert "/right (sensor_msgs/msg/Image, cdr, 3 messages)" in line
    with client(router) as session:
        frames = Frames(session)
        wait_subscribed(router, "ovis/lab/frames")
        done = _replay(str(path), "--topic", "/right", "--connect", router, "--arena", "lab")
        assert done.returncode == 0, done.stderr
        wait_for(lambda: len(frames.all()) >= 3, 10, "the /right frames")
        got = frames.all()
    assert [key for key, _, _ in got] == ["ovis/lab/frames"] * 3
    for (_, frame, _), (_, pixels) in zip(got, photos, strict=False):
        assert np.array_equal(frame.image(), pixels[::-1])
    line = assert_one_line_error(
        _replay(str(path), "--topic", "/nope", "--connect", router), code=2
    )
    assert "has no channel '/nope'; channels found: /left (" in line


def test_no_usable_channel_or_encoding_is_exit_2_naming_what_was_found(tmp_path: Path) -> None:
    none = tmp_path / "none.mcap"
    no_image_channel(none, time.time_ns())
    listen = ("--listen", f"tcp/127.0.0.1:{free_port()}", "--no-live")  # never reached
    for cmd in (("replay", str(none)), ("up", "--source", str(none), *listen)):
        line = assert_one_line_error(
            subprocess.run(ovis_cmd(*cmd), capture_output=True, text=True, timeout=60), code=2
        )
        assert "holds no image channel ovis reads" in line
        assert "channels found: /rosout (foxglove.Log, json, 1 messages)" in line
    deep = tmp_path / "depth.mcap"
    out = ForeignMcap(deep)
    out.message("/depth", "cdr", "raw", time.time_ns(), width=4, height=2, encoding="16UC1",
                step=8, data=bytes(16))  # fmt: skip
    out.close()
    line = assert_one_line_error(_replay(str(deep)), code=2)
    assert "raw image encoding '16UC1' is not supported: ovis reads raw mono8, bgr8" in line
    two = tmp_path / "two.mcap"
    two_image_channels(two, [(b"", np.zeros((8, 8), np.uint8))] * 3, time.time_ns())
    line = assert_one_line_error(
        subprocess.run(
            ovis_cmd("up", "--source", str(two), *listen, "--topic", "/left"),
            capture_output=True,
            text=True,
            timeout=60,
        ),
        code=2,
    )
    assert "a jpeg image does not decode (0 bytes)" in line
    line = assert_one_line_error(
        subprocess.run(ovis_cmd("up", *listen, "--topic", "/left"), capture_output=True, text=True),
        code=2,
    )
    assert "source_topic '/left' picks a channel of an MCAP file, but the source is 'sim'" in line


def test_up_processes_the_frames_of_the_channel_topic_picks(tmp_path: Path, photos) -> None:
    path = tmp_path / "two.mcap"
    t0 = time.time_ns()
    both = ForeignMcap(path)  # two image channels: /camera/image is picked with --topic
    for k, (jpeg, pixels) in enumerate(photos):
        both.message("/other", "json", "compressed", t0 + k * PERIOD, data=jpeg, format="jpeg")
        both.message("/camera/image", "protobuf", "raw", t0 + k * PERIOD,
                     **raw_fields(pixels, "mono8"))  # fmt: skip
    both.close()
    size = tmp_path / "size.toml"  # the photos' size (the default camera is 640x480)
    size.write_text('preset = "default"\n[camera]\nrows = 512\ncols = 640\n')
    args = ("--source", str(path), "--topic", "/camera/image", "--config", str(size))
    proc, endpoint, err = start_up(
        tmp_path, *args, "--calibration", str(photo_calibration(tmp_path)[1])
    )
    obstacles: list[bytes] = []
    try:
        with client(endpoint) as session:
            frames = Frames(session)
            session.declare_subscriber(
                "ovis/default/obstacles", lambda s: obstacles.append(s.payload.to_bytes())
            )
            wait_for(lambda: len(frames.all()) >= len(photos) and obstacles, 90,
                     "a pass of the photos through the pipeline")  # fmt: skip
            got = frames.all()
    finally:
        proc.send_signal(signal.SIGTERM)
        stdout, _ = proc.communicate(timeout=60)
    text = err.read_text()
    assert "frames from /camera/image (foxglove.RawImage, protobuf, 14 messages): 640x512" in text
    for _, frame, _ in got:
        assert frame.source == f"{path} /camera/image" and (frame.rows, frame.cols) == (512, 640)
        assert np.array_equal(frame.image(), photos[frame.seq % len(photos)][1])
    summary = json.loads(stdout)
    assert summary["frames_captured"] >= len(photos)
    assert summary["frames_processed"] > 0 and summary["calibration_version"] == 1
