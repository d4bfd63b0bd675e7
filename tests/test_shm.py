"""Frames through Zenoh shared memory on one host (issue 31): the capture writes each
frame once into shared memory, a subscriber on the same host receives it as a shared
buffer, one that cannot map it (shared memory off, as on another host) receives the
same bytes over the network, and ``[zenoh] shared_memory = false`` sends everything
over the network. Zenoh itself may move a large payload through shared memory (its
transport optimisation): the capture's status (``shm_written``) proves that ovis's own
writer put the frames there; a full pool sends the message as bytes, counted
(``shm_fallbacks``) in the status that ``ovis status`` shows."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import msgspec
import pytest
import zenoh
from zenoh_helpers import alive, client, free_port, ovis_cmd, spawn, stop, wait_for

from ovis.common.config import ConfigError, ZenohConfig, load_config
from ovis.common.messages import Frame, ServiceStatus, decode
from ovis.services.bus import zenoh_config
from ovis.services.cli.watching import ServiceReport, format_shm, status_table
from ovis.services.service import Service
from ovis.services.shm import SHM_MIN_BYTES, ShmWriter

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


class Received(NamedTuple):
    """What a subscriber with shared memory (``here``) and one without (``there``)
    received, and the capture's status once they had :data:`FRAMES` frames and again
    some frames later."""

    here: dict[int, tuple[bool, bytes]]
    there: dict[int, tuple[bool, bytes]]
    before: ServiceStatus
    after: ServiceStatus


def _capture_status(session: zenoh.Session) -> ServiceStatus | None:
    for reply in session.get("ovis/default/status/capture", timeout=3.0):
        if reply.ok is not None:
            return decode(reply.ok.payload.to_bytes(), ServiceStatus)
    return None


def _capture(tmp: Path, shared_memory: bool) -> Received:
    """``ovis run capture`` (simulated, behind a router) with ``shared_memory``: what a
    subscriber with shared memory and one without received, and its status."""
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
            before = wait_for(lambda: _capture_status(near), 10, "the capture's status")
            after = wait_for(
                lambda: (
                    (st := _capture_status(near)) and st.frames_out >= before.frames_out + 5 and st
                ),
                30,
                "the capture's status five frames later",
            )
            return Received(dict(here.got), dict(there.got), before, after)
    finally:
        stop([p for p in (capture, router) if p is not None])


def test_frames_go_through_shared_memory_and_the_same_bytes_over_the_network(
    tmp_path: Path,
) -> None:
    here, there, before, after = _capture(tmp_path, shared_memory=True)
    assert all(shm for shm, _ in here.values()), "a frame on the same host came as bytes"
    # ovis's writer put them there (Zenoh alone would too, unseen by the status): every
    # frame sent went into its pool or, the pool full, as bytes, counted either way
    for st in (before, after):
        assert st.shm_pool_bytes > 0 and st.shm_written > 0
        assert st.frames_out <= st.shm_written + st.shm_fallbacks <= st.frames_out + 1
    assert after.shm_written + after.shm_fallbacks - before.shm_written - before.shm_fallbacks >= 5
    assert after.shm_written > before.shm_written
    assert not any(shm for shm, _ in there.values()), "shared memory reached a peer without it"
    both = sorted(here.keys() & there.keys())
    assert len(both) >= FRAMES - 2
    for seq in both:
        assert here[seq][1] == there[seq][1], f"frame {seq} differs between the transports"
        frame = decode(here[seq][1], Frame)
        assert frame.image().shape == (frame.rows, frame.cols) and frame.image().any()


def test_shared_memory_off_sends_every_frame_over_the_network(tmp_path: Path) -> None:
    here, there, _, after = _capture(tmp_path, shared_memory=False)
    assert len(here) >= FRAMES
    assert not any(shm for shm, _ in here.values()), "shared memory used while switched off"
    assert after.frames_out >= FRAMES
    assert (after.shm_pool_bytes, after.shm_written, after.shm_fallbacks) == (0, 0, 0)
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


def test_a_full_pool_sends_bytes_counted_in_the_status_and_ovis_status(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A subscriber that keeps every message it received holds the pool's buffers: the
    writer then sends the next ones as plain bytes (they still arrive, the same), counts
    them, says so in its log and in its status; freed buffers are used again."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    peer = ZenohConfig(mode="peer", connect=[], listen=[endpoint])
    config = load_config(None)
    config = msgspec.structs.replace(config, zenoh=peer)
    message = bytes(range(256)) * (SHM_MIN_BYTES // 256 + 1)  # large enough to go in
    held: list[zenoh.ZBytes] = []
    lock, ready = threading.Lock(), threading.Event()

    def keep(sample: zenoh.Sample) -> None:
        with lock:
            ready.set()
            if len(sample.payload.to_bytes()) > len(message):  # not the probes
                held.append(sample.payload)

    with zenoh.open(zenoh_config(peer)) as session, client(endpoint) as near:
        service = Service("capture", config, session)
        service.shm = ShmWriter(4 * len(message), service.log)  # room for a few only
        sub = near.declare_subscriber("ovis/default/test", keep)
        publish = service.publisher("ovis/default/test", drop=False)
        wait_for(lambda: publish(b"probe") or ready.is_set(), 10, "the subscriber")
        with caplog.at_level(logging.WARNING, logger="ovis.capture"):
            for _ in range(8):
                publish(message)
            wait_for(lambda: len(held) >= 8, 10, "every message")
        status = service.status()
        with lock:
            shared = [p.as_shm() is not None for p in held]
            assert all(msgspec.msgpack.decode(p.to_bytes()) == message for p in held)
        assert 1 <= status.shm_written < 8 and status.shm_fallbacks >= 1
        assert (status.shm_written, status.shm_fallbacks) == (
            shared.count(True),
            shared.count(False),
        )
        assert status.shm_pool_bytes == 4 * len(message)
        assert "shared-memory pool of" in caplog.text and "shm_fallbacks #1" in caplog.text
        assert status.state != "degraded" and not status.errors  # every message went
        row = format_shm(status)
        assert row == f"{status.shm_written}, [yellow]{status.shm_fallbacks} pool full[/]"
        table = status_table([ServiceReport("capture", True, status)], service.topics)
        assert [c.header for c in table.columns][-1] == "shm"
        with lock:
            held.clear()  # the subscriber lets go: the pool has room again
        publish(message)
        wait_for(lambda: held, 10, "the message after the pool was freed")
        assert held[0].as_shm() is not None
        assert service.status().shm_written == status.shm_written + 1
        sub.undeclare()


def test_publishers_declared_from_several_threads_share_one_pool(tmp_path: Path) -> None:
    """The capture declares its frame publisher while its source thread declares
    another: both write into the one pool that the status counts (two pools made at
    once left the frames' writes out of the status: 0 written of 173 frames)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    peer = ZenohConfig(mode="peer", connect=[], listen=[endpoint])
    config = msgspec.structs.replace(load_config(None), zenoh=peer)
    message = bytes(SHM_MIN_BYTES)
    threads = 8
    for _ in range(5):  # the race needs the threads to meet in the pool's creation
        with zenoh.open(zenoh_config(peer)) as session:
            service = Service("capture", config, session)
            start = threading.Barrier(threads)
            publishers: list[Callable[[object], None]] = []

            def declare(
                n: int,
                service: Service = service,
                start: threading.Barrier = start,
                out: list[Callable[[object], None]] = publishers,
            ) -> None:
                start.wait()
                out.append(service.publisher(f"ovis/default/test/{n}", drop=False))

            workers = [threading.Thread(target=declare, args=(n,)) for n in range(threads)]
            for worker in workers:
                worker.start()
            for worker in workers:
                worker.join()
            for publish in publishers:
                publish(message)
            assert service.status().shm_written == threads
