"""Frames through Zenoh shared memory on one host (issue 31): the capture writes each
frame once into shared memory, a subscriber on the same host receives it as a shared
buffer, one that cannot map it (shared memory off, as on another host) receives the
same bytes over the network, and ``[zenoh] shared_memory = false`` sends everything
over the network."""

from __future__ import annotations

import threading
from pathlib import Path

import msgspec
import pytest
import zenoh
from zenoh_helpers import alive, client, free_port, ovis_cmd, spawn, stop, wait_for

from ovis.common.config import ConfigError, ZenohConfig, load_config
from ovis.common.messages import Frame, decode
from ovis.services.bus import zenoh_config

FRAMES = 15


class Frames:
    """Every frame a session receives: seq → (came as shared memory, payload bytes)."""

    def __init__(self, session: zenoh.Session) -> None:
        self.got: dict[int, tuple[bool, bytes]] = {}
        self.lock = threading.Lock()
        self.sub = session.declare_subscriber("ovis/default/frames", self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        data = sample.payload.to_bytes()
        with self.lock:
            self.got[decode(data, Frame).seq] = (sample.payload.as_shm() is not None, data)

    def __len__(self) -> int:
        with self.lock:
            return len(self.got)


def _capture(tmp: Path, shared_memory: bool) -> tuple[dict[int, tuple], dict[int, tuple]]:
    """``ovis run capture`` (simulated, behind a router) with ``shared_memory``: what a
    subscriber with shared memory and one without received."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = tmp / "config.toml"
    config.write_text(
        f'preset = "default"\n[service]\nstate_dir = "{tmp / "state"}"\nfps = 20.0\n'
        f'[zenoh]\nconnect = ["{endpoint}"]\nshared_memory = {str(shared_memory).lower()}\n'
    )
    router = spawn(ovis_cmd("router", "--listen", endpoint), tmp / "router.log")
    capture = None
    no_shm = ZenohConfig(connect=[endpoint], shared_memory=False)
    try:
        with client(endpoint) as near, zenoh.open(zenoh_config(no_shm)) as far:
            here, there = Frames(near), Frames(far)
            capture = spawn(ovis_cmd("run", "capture", "--config", str(config)), tmp / "cap.log")
            wait_for(lambda: "capture" in alive(near), 60, "the capture alive")
            wait_for(lambda: len(here) >= FRAMES and len(there) >= FRAMES, 60, "frames")
            here.sub.undeclare()
            there.sub.undeclare()
            return dict(here.got), dict(there.got)
    finally:
        stop([p for p in (capture, router) if p is not None])


def test_frames_go_through_shared_memory_and_the_same_bytes_over_the_network(
    tmp_path: Path,
) -> None:
    here, there = _capture(tmp_path, shared_memory=True)
    assert all(shm for shm, _ in here.values()), "a frame on the same host came as bytes"
    assert not any(shm for shm, _ in there.values()), "shared memory reached a peer without it"
    both = sorted(here.keys() & there.keys())
    assert len(both) >= FRAMES - 2
    for seq in both:
        assert here[seq][1] == there[seq][1], f"frame {seq} differs between the transports"
        frame = decode(here[seq][1], Frame)
        assert frame.image().shape == (frame.rows, frame.cols) and frame.image().any()


def test_shared_memory_off_sends_every_frame_over_the_network(tmp_path: Path) -> None:
    here, there = _capture(tmp_path, shared_memory=False)
    assert len(here) >= FRAMES
    assert not any(shm for shm, _ in here.values()), "shared memory used while switched off"
    for seq in here.keys() & there.keys():
        assert here[seq][1] == there[seq][1]


def test_shared_memory_switch_is_validated(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('preset = "default"\n[zenoh]\nshared_memory = "yes"\n')
    with pytest.raises(ConfigError, match="shared_memory"):
        load_config(bad)
    good = tmp_path / "good.toml"
    good.write_text('preset = "default"\n[zenoh]\nshared_memory = false\n')
    assert load_config(good).zenoh.shared_memory is False
    assert msgspec.json.decode(
        zenoh_config(load_config(good).zenoh).get_json("transport/shared_memory/enabled")
    ) is False  # fmt: skip
