"""A network camera that drops and comes back: the real photos served as MJPEG over HTTP
by a local server (tests/mjpeg_server.py), read by the capture service (a real process,
OpenCV's FFmpeg backend) on a real router, with the pose stage publishing the stream's
health. The server is switched off and on again, then frozen and thawed: the capture's
status and the health say "source lost" with the reason within 2 s, frames flow again,
and each loss is reported with its length."""

from __future__ import annotations

import io
import itertools
import re
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from mjpeg_server import mjpeg_camera
from real_photos import photo_bytes_and_pixels
from rich.console import Console
from zenoh_helpers import alive, client, free_port, ovis_cmd, spawn, stop, wait_for

from ovis.common.analysis.live import LiveScore
from ovis.common.capture.sources import (
    STREAM_OPEN_TIMEOUT_S,
    STREAM_READ_TIMEOUT_S,
    SourceError,
    StreamSource,
    without_password,
)
from ovis.common.messages import Frame, ServiceStatus, SourceState, StreamHealth, Topics, decode
from ovis.services.cli.watching import query_statuses, summary_table

# alone: timeouts kept to a tenth of a second
pytestmark = pytest.mark.alone

#: The requirement: a lost source is said within this many seconds.
SAY_LOST_S = 2.0
#: How long the camera stays off or frozen.
OUTAGE_S = 2.5
TOPICS = Topics("default")


def real_jpegs() -> tuple[list[bytes], list[np.ndarray]]:
    """The shared photos as JPEG files' bytes, and as OpenCV decodes them (grey)."""
    pairs = photo_bytes_and_pixels()
    return [jpeg for jpeg, _ in pairs], [pixels for _, pixels in pairs]


def failure_after(src: StreamSource) -> tuple[float, str]:
    """Seconds until ``src`` fails to read, and why."""
    t = time.monotonic()
    with pytest.raises(SourceError) as failed:
        for _ in range(1000):
            src.read()
    return time.monotonic() - t, str(failed.value)


def test_the_stream_source_reads_mjpeg_over_http_and_gives_up_on_a_stream_that_hangs() -> None:
    jpegs, photos = real_jpegs()
    with mjpeg_camera(jpegs, free_port()) as camera:
        src = StreamSource(camera.url)
        assert src.description == f"stream {camera.url}"
        for photo in photos[:3]:
            image, truth = src.read()
            assert truth is None and image.shape == (512, 640, 3)
            assert np.abs(image[:, :, 0].astype(int) - photo).max() <= 1
        camera.freeze()
        took, why = failure_after(src)
        print(f"a frozen stream fails after {took:.2f} s")
        assert STREAM_READ_TIMEOUT_S - 0.1 < took < STREAM_READ_TIMEOUT_S + 0.5
        assert "delivered no frame for 1 s or closed" in why
        camera.thaw()
        assert src.read()[0].shape == (512, 640, 3)  # reopened on the next read
        camera.stop()
        took, why = failure_after(src)
        assert took < 0.5 and "delivered no frame" in why  # the connection closed
        src.close()


def test_a_stream_that_does_not_answer_is_given_up_after_the_open_timeout() -> None:
    port = free_port()
    with pytest.raises(SourceError, match="check the URL"):  # nothing listens
        StreamSource(f"http://127.0.0.1:{port}/stream")
    with socket.create_server(("127.0.0.1", port)):  # accepts, never answers
        t = time.monotonic()
        with pytest.raises(SourceError, match=f"answers within {STREAM_OPEN_TIMEOUT_S:g} s") as e:
            StreamSource(f"http://user:pw@127.0.0.1:{port}/stream")
        took = time.monotonic() - t
    assert f"stream http://user:***@127.0.0.1:{port}/stream" in str(e.value)
    assert STREAM_OPEN_TIMEOUT_S - 0.1 < took < STREAM_OPEN_TIMEOUT_S + 1.0


def test_a_password_in_a_stream_url_stays_out_of_what_is_shown() -> None:
    assert without_password("rtsp://admin:s3cret@10.0.0.7:554/live") == (
        "rtsp://admin:***@10.0.0.7:554/live"
    )
    assert without_password("http://10.0.0.7/video.mjpg") == "http://10.0.0.7/video.mjpg"
    assert without_password("rtsp://user@cam/x") == "rtsp://user@cam/x"


class Watcher:
    """What a client sees: the frames (the first ones' pixels kept), the health and what
    the capture says of its source."""

    def __init__(self, session: zenoh.Session, keep: int = 28) -> None:
        self.frames: list[tuple[float, int]] = []  # (receipt, seq)
        self.images: list[np.ndarray] = []
        self.health: list[tuple[float, StreamHealth]] = []
        self.said: list[SourceState] = []
        self.keep = keep
        self.lock = threading.Lock()
        session.declare_subscriber(TOPICS.frames, self._frame)
        session.declare_subscriber(TOPICS.health, self._health)
        session.declare_subscriber(TOPICS.source, self._said)

    def _frame(self, sample: zenoh.Sample) -> None:
        f = decode(sample.payload.to_bytes(), Frame)
        with self.lock:
            self.frames.append((time.monotonic(), f.seq))
            if len(self.images) < self.keep:
                self.images.append(f.image().copy())

    def _health(self, sample: zenoh.Sample) -> None:
        msg = decode(sample.payload.to_bytes(), StreamHealth)
        with self.lock:
            self.health.append((time.monotonic(), msg))

    def _said(self, sample: zenoh.Sample) -> None:
        msg = decode(sample.payload.to_bytes(), SourceState)
        with self.lock:
            self.said.append(msg)

    def first_lost(self, after_ns: int) -> tuple[SourceState | None, StreamHealth | None]:
        """The first "source lost" the capture and the health published after ``after_ns``
        (their own publication times: what ovis took, not what a poll took)."""
        with self.lock:
            said = [m for m in self.said if m.published_ns > after_ns]
            health = [h for _, h in self.health if h.published_ns > after_ns]
        return (
            next((m for m in said if m.state == "source lost"), None),
            next((h for h in health if h.state == "source lost"), None),
        )

    def frames_after(self, t: float) -> list[tuple[float, int]]:
        with self.lock:
            return [f for f in self.frames if f[0] > t]

    def health_after(self, t: float, state: str) -> tuple[float, StreamHealth] | None:
        with self.lock:
            return next(((at, h) for at, h in self.health if at > t and h.state == state), None)


def capture_status(session: zenoh.Session) -> ServiceStatus | None:
    return query_statuses(session, TOPICS, timeout=1.0).get("capture")


def lost_within(session: zenoh.Session, watcher: Watcher, t0_ns: int) -> ServiceStatus:
    """Wait for the capture (on its source topic and in its status) and the health to say
    "source lost"; assert that the capture and the health published it within SAY_LOST_S
    of ``t0_ns`` (wall clock, when the camera failed); the capture's status."""
    said, health = wait_for(
        lambda: all(watcher.first_lost(t0_ns)) and watcher.first_lost(t0_ns),
        10,
        "the capture and the health to say source lost",
    )
    status = wait_for(
        lambda: (st := capture_status(session)) and st.state == "source lost" and st,
        10,
        "the capture's status to say source lost",
    )
    said_s, health_s = (said.published_ns - t0_ns) / 1e9, (health.published_ns - t0_ns) / 1e9
    print(f"source lost: said by the capture after {said_s:.2f} s, the health {health_s:.2f} s")
    assert said_s < SAY_LOST_S and health_s < SAY_LOST_S
    assert said.reason == status.gaps[-1].reason and said.lost_ns is not None
    # the reason it was lost, or (after an attempt to reopen) why it cannot be reopened
    assert health.reason in (status.gaps[-1].reason, status.reason)
    assert status.reason.startswith(("stream http://", "cannot open stream http://"))
    return status


def back_within(
    session: zenoh.Session, watcher: Watcher, t_off: float, t_on: float, gaps: int
) -> ServiceStatus:
    """Wait for frames after ``t_on`` and the status to count ``gaps`` losses, the last
    one closed and as long as the time without frames."""
    first = wait_for(lambda: watcher.frames_after(t_on), 15, "frames after the camera is back")
    back_at = first[0][0]
    st = wait_for(
        lambda: (s := capture_status(session)) and s.state == "ok" and s.source_gaps == gaps and s,
        10,
        "the capture's status to be ok again",
    )
    gap = st.gaps[-1]
    without = back_at - t_off  # the client's view: last chance of a frame → next frame
    print(
        f"back {back_at - t_on:.2f} s after the camera; gap {gap.seconds:.2f} s, "
        f"outage {t_on - t_off:.2f} s, no frames for {without:.2f} s"
    )
    assert not gap.ongoing and len(st.gaps) == gaps
    assert t_on - t_off - 0.2 <= gap.seconds <= without + 0.2
    assert st.source_gap_s == round(sum(g.seconds for g in st.gaps), 3)
    return st


def test_an_mjpeg_camera_that_drops_is_said_lost_in_2_s_and_reconnects(tmp_path: Path) -> None:
    jpegs, photos = real_jpegs()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    port = free_port()
    procs = [spawn(ovis_cmd("router", "--listen", endpoint), tmp_path / "router.log")]
    with mjpeg_camera(jpegs, port) as camera:
        try:
            for stage, extra in (("capture", ["--source", camera.url]), ("pose", [])):
                args = ovis_cmd("run", stage, "--connect", endpoint, *extra)
                procs.append(spawn(args, tmp_path / f"{stage}.log"))
            with client(endpoint) as session:
                watcher = Watcher(session)
                wait_for(lambda: alive(session) >= {"capture", "pose"}, 30, "capture and pose")
                wait_for(lambda: len(watcher.images) >= watcher.keep, 30, "frames of the stream")

                # the photos, pixel for pixel (FFmpeg's JPEG decoder vs OpenCV's: ±1 level)
                shown = []
                for image in watcher.images:
                    assert image.shape == (512, 640, 3)
                    assert (image == image[:, :, :1]).all()  # grey photos: 3 equal channels
                    diffs = [np.abs(image[:, :, 0].astype(int) - p).max() for p in photos]
                    shown.append(int(np.argmin(diffs)))
                    assert min(diffs) <= 1 and sorted(diffs)[1] > 20
                steps = {(b - a) % len(photos) for a, b in itertools.pairwise(shown)}
                assert steps == {1}, shown  # each photo in turn, none skipped
                assert len(set(shown)) == len(photos)

                # switched off: the connection closes, nothing answers
                t_off, t_off_ns = time.monotonic(), time.time_ns()
                camera.stop()
                status = lost_within(session, watcher, t_off_ns)
                assert status.gaps[-1].reason.startswith(f"stream {camera.url} delivered no frame")
                assert status.source_gaps == 1 and status.gaps[-1].ongoing
                time.sleep(max(0.0, t_off + OUTAGE_S - time.monotonic()))
                t_on = time.monotonic()
                camera.start()
                back_within(session, watcher, t_off, t_on, gaps=1)
                wait_for(
                    lambda: watcher.health_after(time.monotonic() - 0.5, "waiting"),
                    5,
                    "the health to stop saying source lost",  # (no label stage: no frames)
                )

                # frozen: the connection stays open, no frame comes
                t_freeze, t_freeze_ns = time.monotonic(), time.time_ns()
                camera.freeze()
                status = lost_within(session, watcher, t_freeze_ns)
                assert "delivered no frame for 1 s" in status.gaps[-1].reason
                time.sleep(max(0.0, t_freeze + OUTAGE_S - time.monotonic()))
                t_thaw = time.monotonic()
                camera.thaw()
                status = back_within(session, watcher, t_freeze, t_thaw, gaps=2)

            # the summary of a run with this capture's status
            summary = LiveScore().summary({"capture": status}, {}, 30.0)
            assert (summary.source_gaps, summary.gaps) == (2, status.gaps)
            console = Console(file=io.StringIO(), width=200)
            console.print(summary_table(summary))
            text = console.file.getvalue()
            assert f"2 times, {status.source_gap_s:.1f} s in total" in text
            assert f"{status.gaps[0].seconds:.1f} s: stream {camera.url} delivered" in text
        finally:
            stop(procs[1:])
            stop(procs[:1])
    log = (tmp_path / "capture.log").read_text()
    assert "Traceback" not in log and "source back after" in log
    first, second = log.split("source back after", 1)
    waits = re.findall(r"next attempt in ([\d.]+) s", first)
    assert len(waits) >= 2 and waits == ["0.5", "1", "2", "4"][: len(waits)]  # doubling
    assert re.findall(r"next attempt in ([\d.]+) s", second)[0] == "0.5"  # reset by frames
    assert "Traceback" not in (tmp_path / "pose.log").read_text()
