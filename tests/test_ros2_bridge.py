"""`ovis up --ros2` end to end, proven without ROS 2 installed: a plain Zenoh client on
the router lists the keys and liveliness tokens (what `ros2 topic list` and `ros2 node
list` read on an rmw_zenoh system), checks each against the layout of rmw_zenoh's design
document (quoted in tests/rmw_zenoh_design.py with its source), decodes every topic with
rosbags' own CDR reader and compares it with ovis's msgpack topics frame by frame."""

from __future__ import annotations

import math
import threading
from collections import defaultdict
from pathlib import Path

import msgspec
import numpy as np
import rmw_zenoh_design as design
from cli_helpers import ovis
from pipeline_helpers import start_up
from rosbags.typesys import Stores, get_typestore
from zenoh_helpers import alive, client, wait_for

from ovis.common.calibration.file import calibration_from_config
from ovis.common.config import load_config
from ovis.common.messages import ObstacleFrame, decode
from ovis.common.ros2 import wire
from ovis.common.ros2.floor import ros_floor
from ovis.common.view.health import STAGES

TYPES = {
    "/ovis/obstacles": "geometry_msgs/msg/PoseArray",
    "/ovis/markers": "visualization_msgs/msg/MarkerArray",
    "/ovis/camera/camera_info": "sensor_msgs/msg/CameraInfo",
    "/ovis/camera/image/compressed": "sensor_msgs/msg/CompressedImage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
}
ODOM = "nav_msgs/msg/Odometry"
RUN_S = 40
FPS, MARKERS_HZ, IMAGE_HZ = 10, 3.0, 4.0  # rates unlike the defaults: the config's are used


def test_ovis_up_ros2_is_a_ros2_node_with_ovis_numbers(tmp_path: Path) -> None:
    cfg = tmp_path / "ovis.toml"
    cfg.write_text(f"[ros2]\nimage_rate_hz = {IMAGE_HZ}\nmarkers_rate_hz = {MARKERS_HZ}\n")
    proc, endpoint, _ = start_up(tmp_path, "--ros2", "--pin", "none", "--fps", str(FPS),
                                   "--duration", str(RUN_S), "--config", str(cfg))  # fmt: skip
    samples: list[tuple[str, bytes, bytes]] = []
    frames: dict[int, ObstacleFrame] = {}
    lock = threading.Lock()
    try:
        with client(endpoint) as session:
            wait_for(lambda: "ros2" in alive(session), 60, "the ros2 bridge alive")

            def on_ros(sample) -> None:  # every ROS 2 data key of domain 0
                with lock:
                    samples.append((str(sample.key_expr), sample.payload.to_bytes(),
                                    sample.attachment.to_bytes()))  # fmt: skip

            def on_ovis(sample) -> None:
                frame = decode(sample.payload.to_bytes(), ObstacleFrame)
                with lock:
                    frames[frame.stamp_ns] = frame

            subs = [session.declare_subscriber("0/**", on_ros),
                    session.declare_subscriber("ovis/default/obstacles", on_ovis)]  # fmt: skip
            wait_for(lambda: len(frames) >= 60, 90, "60 obstacle frames")
            listed = check_status(endpoint)
            tokens = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/**", timeout=2)
                      if r.ok is not None]  # fmt: skip
            for sub in subs:
                sub.undeclare()
    finally:
        proc.terminate()
        proc.communicate(timeout=60)
    with lock:
        samples, frames = list(samples), dict(frames)
    print("\n".join(["liveliness tokens:", *sorted(tokens), "data keys:",
                     *sorted({k for k, _, _ in samples})]))  # fmt: skip
    print("ovis status:", listed)
    check_graph(tokens, samples)
    check_values(samples, frames)
    check_rates(samples, frames)


def check_status(endpoint: str) -> list[str]:
    """`ovis status` lists the bridge, after the stages, alive and working (as it would
    any service that runs beside them); the services it listed."""
    rows = msgspec.json.decode(ovis("status", "--json", "--connect", endpoint).stdout)
    names = [r["service"] for r in rows]
    assert names == [*STAGES, "ros2"], names
    (bridge,) = (r for r in rows if r["service"] == "ros2")
    assert bridge["alive"] and bridge["status"]["state"] == "ok", bridge
    assert bridge["status"]["frames_in"] > 0 and bridge["status"]["frames_out"] > 0, bridge
    return names


def check_graph(tokens: list[str], samples: list[tuple[str, bytes, bytes]]) -> None:
    """Every token and key as the design document lays them out ({design.SOURCE})."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    nodes = [t for t in tokens if design.NODE_TOKEN.fullmatch(t)]
    assert len(nodes) == 1, (design.NODE_TOKEN_FORMAT, tokens)
    node = wire.parse_token(nodes[0])
    assert (node.domain_id, node.namespace, node.node, node.enclave) == (0, "/ovis", "ovis", "/")
    publishers = {}
    for token in set(tokens) - set(nodes):
        m = design.ENTITY_TOKEN.fullmatch(token)
        assert m, (design.ENTITY_TOKEN_FORMAT, token)
        domain, zid, nid, _eid, kind, enclave, ns, name, topic, dds, hash_, qos = m.groups()
        mine = ("0", node.zid, str(node.node_id), "MP", "%", "%ovis", "ovis")
        assert (domain, zid, nid, kind, enclave, ns, name) == mine
        assert "/" not in topic and topic.startswith("%"), design.MANGLING
        ros_type = wire.ros_type_name(dds)
        assert hash_ == typestore.hash_rihs01(ros_type)
        kept = topic in ("%tf_static", "%ovis%camera%camera_info")
        assert qos == (":1:,1:,:,:,," if kept else "::,10:,:,:,,")
        # the key this publisher puts on: <domain_id>/<fully_qualified_name>/<type_name>/<type_hash>
        publishers[f"{domain}/{topic.replace('%', '/')[1:]}/{dds}/{hash_}"] = (token, ros_type)
    names = {wire.parse_token(t).topic: ty for t, ty in publishers.values()}
    odoms = {n for n, ty in names.items() if ty == ODOM}
    assert {n: t for n, t in names.items() if n not in odoms} == TYPES
    assert odoms and all(n.startswith("/ovis/robots/robot_") and n.endswith("/odom") for n in odoms)
    seen = defaultdict(list)
    for key, _, attachment in samples:
        assert design.DATA_KEY.fullmatch(key), (design.KEY_FORMAT, key)
        assert key in publishers, f"data on {key} with no publisher token"
        seen[key].append(wire.decode_attachment(attachment))
    assert set(seen) == set(publishers)
    for key, attachments in seen.items():
        token, _ = publishers[key]
        assert all(a.gid == wire.entity_gid(token) for a in attachments), design.ATTACHMENT
        numbers = [a.sequence_number for a in attachments]
        assert numbers == list(range(numbers[0], numbers[0] + len(numbers))), key


def check_values(samples: list[tuple[str, bytes, bytes]], frames: dict[int, ObstacleFrame]) -> None:
    """rosbags decodes each message; its numbers are ovis's, frame by frame."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    floor = ros_floor(calibration_from_config(load_config()))
    compared = defaultdict(int)
    image_stamps: set[int] = set()
    for key, cdr, attachment in samples:
        ros_type = wire.parse_topic_key(key).type_name
        msg = typestore.deserialize_cdr(cdr, ros_type)
        source_ns = wire.decode_attachment(attachment).source_timestamp_ns
        if ros_type == "tf2_msgs/msg/TFMessage":
            (tf,) = msg.transforms
            assert (tf.header.frame_id, tf.child_frame_id) == ("ovis_floor", "ovis_camera_optical")
            assert tf.transform.translation.z > 0.5  # the camera looks down from above
            continue
        header = msg.markers[0].header if ros_type.endswith("MarkerArray") else msg.header
        stamp = header.stamp.sec * 10**9 + header.stamp.nanosec
        assert source_ns == stamp, "the source timestamp is the capture time"
        if ros_type == "sensor_msgs/msg/CompressedImage":
            image_stamps.add(stamp)
            assert msg.format.startswith("mono8") and bytes(msg.data[:2]) == b"\xff\xd8"
        if ros_type == "sensor_msgs/msg/CameraInfo":
            assert (msg.width, msg.height) == (640, 480) and msg.k[0] > 0
        frame = frames.get(stamp)
        if frame is None or ros_type in ("sensor_msgs/msg/CompressedImage",
                                         "sensor_msgs/msg/CameraInfo"):  # fmt: skip
            compared[ros_type] += frame is not None
            continue
        compared[ros_type] += 1
        if ros_type == "geometry_msgs/msg/PoseArray":
            assert msg.header.frame_id == "ovis_floor"
            got = np.array([[p.position.x, p.position.y, p.position.z] for p in msg.poses])
            want = np.array([floor.position_m(o.x_cm, o.y_cm, o.z_cm) for o in frame.obstacles])
            assert got.shape == want.shape and np.abs(got - want).max() < 1e-3  # 1 mm
        elif ros_type == "nav_msgs/msg/Odometry":
            robot = frame.robot
            assert robot is not None
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            want = floor.position_m(robot.x_cm, robot.y_cm, robot.z_cm)
            assert np.abs(np.array([p.x, p.y, p.z]) - want).max() < 1e-3  # 1 mm
            if robot.heading_resolved:
                yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y**2 + q.z**2))
                diff = math.degrees(yaw - floor.yaw_rad(robot.heading_deg))
                assert abs((diff + 180) % 360 - 180) < 0.1
        elif ros_type == "visualization_msgs/msg/MarkerArray":
            assert len(msg.markers) >= len(frame.obstacles)
    for ros_type in [*TYPES.values(), ODOM]:
        if ros_type != "tf2_msgs/msg/TFMessage":
            assert compared[ros_type] >= 3, (ros_type, dict(compared))
    assert len(image_stamps) >= 3


def check_rates(samples: list[tuple[str, bytes, bytes]], frames: dict[int, ObstacleFrame]) -> None:
    """PoseArray and Odometry with every obstacle frame; the markers and the image at
    their configured rates, by the frames' capture stamps (as benchmarks/ros2.py
    measures them)."""
    stamps = defaultdict(list)
    for key, _, attachment in samples:
        ros_type = wire.parse_topic_key(key).type_name
        stamps[ros_type].append(wire.decode_attachment(attachment).source_timestamp_ns)
    first, last = min(frames), max(frames)  # the frames both sides saw
    span_s = (last - first) / 1e9
    assert span_s > 4.0, span_s

    def within(ros_type: str) -> list[int]:
        return [t for t in stamps[ros_type] if first <= t <= last]

    poses = within("geometry_msgs/msg/PoseArray")
    assert set(poses) <= set(frames)  # each one an ovis frame's
    assert len(poses) >= 0.9 * len(frames), (len(poses), len(frames))  # drops under load only
    assert len(set(within(ODOM))) >= 0.9 * len(frames)
    for ros_type, hz in (("visualization_msgs/msg/MarkerArray", MARKERS_HZ),
                         ("sensor_msgs/msg/CompressedImage", IMAGE_HZ)):  # fmt: skip
        got, want = len(within(ros_type)), hz * span_s
        print(f"{ros_type}: {got} in {span_s:.1f} s of frames ({want:.1f} at {hz:g} Hz)")
        assert abs(got - want) <= max(2.0, 0.15 * want), (ros_type, got, want)
    assert len(within("visualization_msgs/msg/MarkerArray")) < len(poses) / 2
