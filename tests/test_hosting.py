"""One stage process serving several cameras (issue 38), without a router: each
camera's configuration taken from ``[[cameras]]``, which cameras a process serves, the
one loop that serves every camera's inbox in turn (a camera stuck in its handler is
left to it while the others go on; a camera whose stage fails says so alone), and the
CPU time of a run's processes read from /proc."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import msgspec
import pytest
import zenoh
from zenoh_helpers import free_port, wait_for

from ovis.common.calibration.file import calibration_from_config, save_calibration
from ovis.common.config import ConfigError, ZenohConfig, config_from_dict, load_config
from ovis.common.messages import Topics
from ovis.common.pipeline.hosting import camera_config, served_cameras
from ovis.services.bus import zenoh_config
from ovis.services.cpu import CpuWindow, process_cpu_s
from ovis.services.host import SharedLoop, serve_cameras
from ovis.services.service import Service


def _arena(tmp: Path, **service: object) -> dict:
    """The default configuration with cameras north (inline model) and south (from a
    calibration file, its camera 300 cm along X), state under ``tmp``."""
    data = msgspec.to_builtins(load_config())
    south = msgspec.structs.replace(load_config().camera, X0_cm=load_config().camera.X0_cm + 300)
    calib = msgspec.structs.replace(calibration_from_config(load_config()), camera=south, version=3)
    save_calibration(tmp / "south.json", calib)
    data["cameras"] = [
        {"name": "north", "source": "sim", "camera": data["camera"]},
        {
            "name": "south",
            "source": "camera:4",
            "calibration": str(tmp / "south.json"),
            "background": str(tmp / "south-floor.png"),
        },
    ]
    data["service"].update(state_dir=str(tmp / "state"), **service)
    return data


def test_a_cameras_configuration_is_the_arenas_with_its_name_source_and_model(
    tmp_path: Path,
) -> None:
    arena = config_from_dict(_arena(tmp_path))
    north, south = camera_config(arena, "north"), camera_config(arena, "south")
    assert Topics(north.service.arena, north.service.camera_name).frames == (
        "ovis/default/cam/north/frames"
    )
    assert (north.service.source, south.service.source) == ("sim", "camera:4")
    assert north.camera == arena.camera
    # south's own empty floor; north the arena's
    assert (north.image.background, south.image.background) == (
        arena.image.background,
        str(tmp_path / "south-floor.png"),
    )
    assert south.camera.X0_cm == pytest.approx(arena.camera.X0_cm + 300)  # from its file
    # each camera's calibrations in its own folder; the keys where the arena's are
    assert south.service.state_dir == str(tmp_path / "state" / "cam" / "south")
    assert south.trust.keys_dir == str(tmp_path / "state" / "keys")
    assert (south.cameras, south.service.cameras) == ([], [])  # one camera's chain
    with pytest.raises(ValueError, match="camera 'east' is not in \\[\\[cameras\\]\\]"):
        camera_config(arena, "east")


def test_which_cameras_a_stage_process_serves(tmp_path: Path) -> None:
    assert served_cameras(config_from_dict(_arena(tmp_path))) == ["north", "south"]
    assert served_cameras(config_from_dict(_arena(tmp_path, cameras=["south"]))) == ["south"]
    one = config_from_dict(_arena(tmp_path) | {"cameras": []} | {"service": {"seed": 1}})
    assert served_cameras(one) == []  # one camera: no [[cameras]]
    chain = _arena(tmp_path)
    chain["service"]["camera_name"] = "north"
    assert served_cameras(config_from_dict(chain)) == []  # one camera's chain


@pytest.mark.parametrize(
    ("service", "said"),
    [
        ({"cameras": ["east"]}, "service: cameras east not in [[cameras]] (listed: north, south)"),
        ({"cameras": ["north", "north"]}, "names a camera twice"),
        ({"cameras": ["north"], "camera_name": "north"}, "give one or the other"),
        ({"layout": "per-host"}, "Invalid enum value 'per-host' - at `$.service.layout`"),
    ],
)
def test_bad_camera_settings_are_refused_with_the_reason(
    tmp_path: Path, service: dict, said: str
) -> None:
    with pytest.raises(ConfigError) as err:
        config_from_dict(_arena(tmp_path, **service))
    assert said in str(err.value)


@contextmanager
def _services(tmp: Path, names: tuple[str, ...]) -> Iterator[list[Service]]:
    """A real :class:`Service` per camera on one Zenoh session (a peer, no router)."""
    arena = config_from_dict(_arena(tmp))
    peer = ZenohConfig(mode="peer", connect=[], listen=[f"tcp/127.0.0.1:{free_port()}"])
    arena = msgspec.structs.replace(
        arena,
        zenoh=peer,
        cameras=[msgspec.structs.replace(arena.cameras[0], name=n) for n in names],
    )
    with zenoh.open(zenoh_config(peer)) as session:
        services = [Service("label", camera_config(arena, n), session) for n in names]
        yield services
        for service in services:
            service.stop.set()


def test_one_loop_serves_every_cameras_inputs_in_turn(tmp_path: Path) -> None:
    handled: list[tuple[str, bytes]] = []
    loop = SharedLoop()
    with _services(tmp_path, ("a", "b", "c")) as services:
        inboxes = {s.topics.camera: s.inbox(f"test/{s.topics.camera}", depth=2) for s in services}
        for name in "abc":  # a flood on a (its inbox keeps the newest 2), one input each else
            for k in range(5 if name == "a" else 1):
                inboxes[name].put((f"{name}{k}".encode(), time.time_ns()))

        def handler(service: Service):
            def handle(payload: bytes, _receipt_ns: int) -> None:
                handled.append((service.topics.camera, payload))
                service.sent()

            return handle

        for service in services:
            loop.add(service, inboxes[service.topics.camera], handler(service))
        loop.start()
        wait_for(lambda: len(handled) == 4, 5, "every input handled")
        loop.stop()
        # one input of each camera per pass: the flood on a delays b and c by one input
        assert handled == [("a", b"a3"), ("b", b"b0"), ("c", b"c0"), ("a", b"a4")]
        assert inboxes["a"].dropped == 3  # the older ones, counted in a's status
        assert [s.status().dropped for s in services] == [3, 0, 0]
        assert [s.counters.frames_out for s in services] == [2, 1, 1]


def test_a_camera_stuck_in_its_handler_is_left_to_it_and_the_others_go_on(
    tmp_path: Path,
) -> None:
    release = threading.Event()
    handled: list[str] = []
    loop = SharedLoop(stuck_s=0.3)
    with _services(tmp_path, ("a", "b")) as (a, b):
        boxes = {s.topics.camera: s.inbox(f"test/{s.topics.camera}") for s in (a, b)}

        def handle_a(_payload: bytes, _receipt_ns: int) -> None:
            if not handled:  # the first input of a never comes back, until released
                release.wait()
            handled.append("a")

        loop.add(a, boxes["a"], handle_a)
        loop.add(b, boxes["b"], lambda _p, _r: handled.append("b"))
        loop.start()
        boxes["a"].put((b"", time.time_ns()))
        time.sleep(0.1)
        for _ in range(3):  # b's inputs while a's handler does not come back
            boxes["b"].put((b"", time.time_ns()))
            time.sleep(0.1)
        stuck = wait_for(loop.watch, 2, "the loop to leave the stuck camera")
        assert stuck == "a"
        wait_for(lambda: handled.count("b") >= 1, 2, "b served while a is stuck")
        boxes["b"].put((b"", time.time_ns()))
        wait_for(lambda: handled.count("b") >= 2, 2, "b served again")
        assert "a" not in handled
        assert a.status().errors == {"stuck": 1} and a.state.startswith("stuck")
        assert b.status().errors == {}
        release.set()  # a's handler comes back: a is served again, b as before
        wait_for(lambda: "a" in handled, 2, "a's handler back")
        boxes["a"].put((b"", time.time_ns()))
        boxes["b"].put((b"", time.time_ns()))
        wait_for(lambda: handled.count("a") == 2 and handled.count("b") >= 3, 2, "both")
        loop.stop()


def test_a_camera_whose_stage_fails_says_so_and_the_others_run(tmp_path: Path) -> None:
    started: list[str] = []

    def main(service: Service) -> None:
        if service.topics.camera == "b":
            raise ValueError("no lens for this camera")
        started.append(service.topics.camera)
        service.stop.wait()

    with _services(tmp_path, ("a", "b", "c")) as services:
        host = threading.Thread(target=serve_cameras, args=(services, main))
        host.start()
        wait_for(lambda: sorted(started) == ["a", "c"], 5, "a and c running")
        status = {s.topics.camera: s.status() for s in services}
        assert (status["b"].state, status["b"].reason) == (
            "failing",
            "stage stopped: ValueError: no lens for this camera",
        )
        assert status["b"].errors == {"stage": 1}
        assert [status[n].errors for n in "ac"] == [{}, {}]
        services[0].stop.set()  # as the process's signal does
        host.join(5)
        assert not host.is_alive() and all(s.stop.is_set() for s in services)


_BURN = "import time\nwhile time.process_time() < {s}: pass\nprint(time.process_time())"


def test_the_cpu_window_counts_every_process_through_a_restart() -> None:
    """Two processes of one name (the second replacing the first) and another: what
    /proc says they used in the window is what each said it used itself."""

    def burn(seconds: float) -> subprocess.Popen[str]:
        code = _BURN.format(s=seconds) + "\nimport sys; sys.stdin.read()"
        return subprocess.Popen(
            [sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )

    running: dict[str, subprocess.Popen[str]] = {}
    window = CpuWindow(lambda: {n: p.pid for n, p in running.items() if p.poll() is None})
    running["stage"] = burn(0.0)
    first = running["stage"]
    wait_for(lambda: first.stdout.readline(), 10, "the first process ready")
    before = process_cpu_s(first.pid)
    window.open(frames=0)
    first.stdin.write("x")  # it burns no more; it is killed and replaced
    first.kill()
    first.wait()
    running["stage"] = burn(0.4)
    running["other"] = burn(0.2)
    used = {n: float(p.stdout.readline()) for n, p in running.items()}
    window.read(frames=10)
    for p in running.values():
        p.stdin.close()
        p.wait()
    cpu = window.summary()
    assert cpu.frames == 10 and cpu.window_s > 0.2
    # per frame: the replacement's CPU (the first process used nothing in the window)
    assert before is not None
    assert cpu.by_process_ms["stage"] == pytest.approx(used["stage"] * 100, abs=5.0)
    assert cpu.by_process_ms["other"] == pytest.approx(used["other"] * 100, abs=5.0)
    assert cpu.ms_per_frame == pytest.approx(sum(cpu.by_process_ms.values()), abs=0.01)
    assert cpu.own_ms_per_frame is not None and os.getpid() not in (p.pid for p in running.values())
