"""`ovis record --ros2` end to end: a real `ovis up` on the simulated arena (two marked
robots), recorded by a real `ovis record --ros2`; the file's ROS 2 channels (``cdr``,
``ros2msg`` schemas) are read back with the `mcap` reader and decoded by rosbags from
the definitions the file carries, and compared frame by frame with ovis's own channels
in the same file: counts, stamps, positions to 1 mm, headings to 0.1°."""

from __future__ import annotations

import math
from pathlib import Path

import msgspec
from mcap.reader import make_reader
from pipeline_helpers import Recorder, start_up
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from zenoh_helpers import client, ovis_cmd, spawn, stop, wait_for

from ovis.common.calibration.file import calibration_from_config
from ovis.common.calibration.store import CalibrationStore
from ovis.common.config import dump_toml, load_config
from ovis.common.messages import Frame, ObstacleFrame, decode
from ovis.common.recording.session import SessionReader
from ovis.common.ros2.floor import ros_floor
from ovis.common.sim.scenes import marked_scene

RECORD_S = 8.0


def ros2_channels(path: Path) -> dict[str, list[tuple[str, object]]]:
    """Topic → [(type, decoded message)] of every ``cdr`` channel, decoded with the
    ``ros2msg`` definition stored in the file (rosbags' parser and CDR deserialiser)."""
    out: dict[str, list[tuple[str, object]]] = {}
    stores: dict[str, object] = {}
    with open(path, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            if channel.message_encoding != "cdr":
                continue
            assert schema is not None and schema.encoding == "ros2msg"
            store = stores.get(schema.name)
            if store is None:
                store = stores[schema.name] = get_typestore(Stores.EMPTY)
                store.register(get_types_from_msg(schema.data.decode(), schema.name))
            msg = store.deserialize_cdr(message.data, schema.name)
            out.setdefault(channel.topic, []).append((schema.name, msg))
    return out


def stamp(header) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def test_record_ros2_writes_ros2_channels_matching_ovis_frame_by_frame(tmp_path: Path) -> None:
    config = marked_scene(load_config(), 2, 5)
    config = msgspec.structs.replace(
        config, service=msgspec.structs.replace(config.service, fps=10.0, prerender=40)
    )
    (tmp_path / "live.toml").write_text(dump_toml(config))
    calib = msgspec.structs.replace(calibration_from_config(config), source_image="truth")
    CalibrationStore(tmp_path / "state").save(calib)
    out = tmp_path / "session.mcap"
    up, endpoint, _ = start_up(tmp_path, "--config", str(tmp_path / "live.toml"))
    record = None
    try:
        with client(endpoint) as session:  # the pipeline runs: obstacles come
            seen = Recorder(session)
            wait_for(lambda: seen.count() > 0, 120, "the first obstacles")
        record = spawn(
            ovis_cmd("record", "--connect", endpoint, "--out", str(out), "--ros2",
                     "--duration", str(RECORD_S)),
            tmp_path / "record.log",
        )  # fmt: skip
        assert record.wait(timeout=RECORD_S + 90) == 0, (tmp_path / "record.log").read_text()
    finally:
        stop([p for p in (record, up) if p is not None])
    log = (tmp_path / "record.log").read_text()
    assert f"wrote {out}" in log, log

    ovis = {
        m.stamp_ns: m
        for m in (
            decode(r.data, ObstacleFrame)
            for r in SessionReader(out).bus_messages()
            if r.topic == "ovis/default/obstacles"
        )
    }
    frames = [
        decode(r.payload(), Frame)
        for r in SessionReader(out).bus_messages()
        if r.topic == "ovis/default/frames"
    ]
    ros = ros2_channels(out)
    assert len(ovis) >= RECORD_S * 10 * 0.5, len(ovis)
    # every ROS 2 obstacle message is one of ovis's frames; at most the frames before the
    # recorder got the calibration are missing (the log says how many)
    poses = ros["/ovis/obstacles"]
    assert {t for t, _ in poses} == {"geometry_msgs/msg/PoseArray"}
    assert len(poses) >= len(ovis) - 5 and len(ros["/ovis/markers"]) == len(poses)
    assert "before any calibration" in log or len(poses) == len(ovis)
    floor = ros_floor(calib)
    assert floor.mirrored  # the default preset: the paper model
    for _, msg in poses:
        frame = ovis[stamp(msg.header)]
        assert len(msg.poses) == len(frame.obstacles)
        for o, p in zip(frame.obstacles, msg.poses, strict=True):
            assert abs(p.position.x - o.x_cm / 100) < 1e-3
            assert abs(p.position.y + o.y_cm / 100) < 1e-3
    # one odometry per marked robot and frame it was in, with its heading
    robot_ids = {r.id for f in ovis.values() for r in f.robots}
    assert robot_ids == {1, 2}
    for rid in robot_ids:
        odoms = ros[f"/ovis/robots/{rid}/odom"]
        assert len(odoms) >= sum(1 for f in ovis.values() if any(r.id == rid for r in f.robots)) - 5
        for _, odom in odoms:
            (r,) = [r for r in ovis[stamp(odom.header)].robots if r.id == rid]
            pose = odom.pose.pose
            assert abs(pose.position.x - r.x_cm / 100) < 1e-3
            assert abs(pose.position.y + r.y_cm / 100) < 1e-3
            yaw = math.degrees(2 * math.atan2(pose.orientation.z, pose.orientation.w))
            assert abs((yaw + r.heading_deg + 180) % 360 - 180) < 0.1
    # an image per recorded frame, stamped with its capture time; the camera and its pose
    images = ros["/ovis/camera/image/compressed"]
    assert [stamp(m.header) for _, m in images] == [f.stamp_ns for f in frames]
    assert len(ros["/ovis/camera/camera_info"]) >= 1 and len(ros["/tf_static"]) >= 1
    (_, tf), *_ = ros["/tf_static"]
    assert tf.transforms[0].header.frame_id == "ovis_floor"
    assert tf.transforms[0].transform.translation.z > 0.3
