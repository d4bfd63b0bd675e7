"""`ovis up --source ros2:/topic`: frames from a ROS 2 camera node through rmw_zenoh. The
camera node is written here from the same layout (tests/rmw_zenoh_design.py): its node
and publisher tokens, its data key, its attachments; it publishes the real photos as
``sensor_msgs/msg/CompressedImage`` and as ``sensor_msgs/msg/Image`` (CDR from rosbags),
through a router standing for rmw_zenohd."""

from __future__ import annotations

import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
import zenoh
from cli_helpers import assert_one_line_error
from pipeline_helpers import run_up
from real_photos import photo_calibration, photo_paths
from rosbags.typesys import Stores, get_typestore
from zenoh_helpers import free_port, ovis_cmd, spawn, stop, wait_for

from ovis.common.config import ZenohConfig
from ovis.common.ros2 import wire
from ovis.services.bus import zenoh_config

# alone: frames at a camera node's rate, counted over seconds
pytestmark = pytest.mark.alone

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
RATE_HZ = 10.0


@pytest.fixture(scope="module")
def calib(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The photos' calibration, made as docs/real-camera.md says."""
    return photo_calibration(tmp_path_factory.mktemp("lens"))[1]


@pytest.fixture
def router(tmp_path: Path) -> Iterator[str]:
    """A Zenoh router standing for rmw_zenohd, on a free port."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = spawn(ovis_cmd("router", "--listen", endpoint), tmp_path / "rmw_zenohd.log")
    wait_for(lambda: "listening on" in (tmp_path / "rmw_zenohd.log").read_text(), 20, "router")
    yield endpoint
    stop([proc])


def _message(type_name: str, image: np.ndarray, stamp_ns: int) -> bytes:
    T = TYPESTORE.types
    header = T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9),
        frame_id="camera",
    )
    if type_name == "sensor_msgs/msg/CompressedImage":
        jpeg = cv2.imencode(".jpg", image)[1].ravel()
        msg = T[type_name](header=header, format="jpeg", data=jpeg)
    else:
        rows, cols = image.shape
        msg = T[type_name](header=header, height=rows, width=cols, encoding="mono8",
                           is_bigendian=0, step=cols, data=image.ravel())  # fmt: skip
    return bytes(TYPESTORE.serialize_cdr(msg, type_name))


class CameraNode:
    """A ROS 2 camera node as rmw_zenoh lays it out, publishing the photos in a loop at
    :data:`RATE_HZ`, each stamped with its place in the schedule."""

    def __init__(self, endpoint: str, topic: str, type_name: str) -> None:
        self.session = zenoh.open(zenoh_config(ZenohConfig(mode="peer", connect=[endpoint])))
        zid = str(self.session.info.zid())
        type_hash = TYPESTORE.hash_rihs01(type_name)
        node = wire.node_token(0, zid, 0, "/", "camera")
        qos = wire.QoS(reliability=wire.BEST_EFFORT, depth=5)
        pub = wire.entity_token("MP", 0, zid, 0, 1, "/", "camera", topic, type_name,
                                type_hash, qos)  # fmt: skip
        self.tokens = [self.session.liveliness().declare_token(t) for t in (node, pub)]
        self.key = wire.topic_key(0, topic, type_name, type_hash)
        self.gid = wire.entity_gid(pub)
        self.images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in photo_paths()]
        self.type_name = type_name
        self.done = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        start = time.time_ns()
        n = 0
        while not self.done.wait(max(0.0, (start + n * 1e9 / RATE_HZ - time.time_ns()) / 1e9)):
            stamp = start + round(n * 1e9 / RATE_HZ)  # the schedule: a capture clock
            payload = _message(self.type_name, self.images[n % len(self.images)], stamp)
            attachment = wire.encode_attachment(n + 1, stamp, self.gid)
            self.session.put(self.key, payload, attachment=attachment)
            n += 1

    def close(self) -> None:
        self.done.set()
        self.thread.join()
        for token in self.tokens:
            token.undeclare()
        self.session.close()


def _config(tmp: Path, endpoint: str) -> str:
    cfg = tmp / "ros2.toml"
    cfg.write_text(f'[ros2]\nconnect = ["{endpoint}"]\n')
    return str(cfg)


@pytest.mark.parametrize("type_name", ["sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/Image"])
def test_frames_from_a_ros2_camera_are_processed(
    calib: Path, router: str, tmp_path: Path, type_name: str
) -> None:
    topic = "/camera/image/compressed" if "Compressed" in type_name else "/camera/image_raw"
    camera = CameraNode(router, topic, type_name)
    try:
        code, summary, err, _ = run_up(
            tmp_path, "--source", f"ros2:{topic}", "--calibration", str(calib),
            "--config", _config(tmp_path, router), "--duration", "6",
        )  # fmt: skip
    finally:
        camera.close()
    assert code == 0 and summary is not None, err
    assert summary["frames_processed"] >= 10 and summary["calibration_version"] == 1, summary
    assert summary["exit_code"] == 0 and summary["reason"] == "", summary


def test_no_ros2_publisher_is_exit_2_saying_what_the_graph_holds(
    calib: Path, router: str, tmp_path: Path
) -> None:
    camera = CameraNode(router, "/other/image", "sensor_msgs/msg/CompressedImage")
    try:
        t0 = time.monotonic()
        code, summary, err, took = run_up(
            tmp_path, "--source", "ros2:/camera/image/compressed", "--calibration", str(calib),
            "--config", _config(tmp_path, router), "--duration", "6", timeout=60,
        )  # fmt: skip
    finally:
        camera.close()
    line = assert_one_line_error(subprocess.CompletedProcess([], code, "", err), code=2)
    assert summary is None and took < 10, (took, time.monotonic() - t0)
    assert "ROS 2 topic /camera/image/compressed" in line and "no image for 3 s" in line, line
    assert "no ROS 2 node publishes it (publishers on domain 0: /other/image)" in line, line


def test_no_ros2_router_is_exit_2_naming_it(calib: Path, tmp_path: Path) -> None:
    nowhere = f"tcp/127.0.0.1:{free_port()}"
    code, _, err, took = run_up(
        tmp_path, "--source", "ros2:/camera/image/compressed", "--calibration", str(calib),
        "--config", _config(tmp_path, nowhere), "--duration", "6", timeout=60,
    )  # fmt: skip
    line = assert_one_line_error(subprocess.CompletedProcess([], code, "", err), code=2)
    assert f"cannot reach the ROS 2 router at {nowhere}" in line and took < 10, (line, took)
