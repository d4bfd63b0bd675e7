"""ovis messages as ROS 2 messages (:mod:`ovis.common.ros2.convert`), read back by an
independent reader: rosbags' CDR deserialiser, on frames the simulator renders and ovis's
detector finds, on a real photo, and on random frames (hypothesis). Positions to 1 mm,
headings to 0.1°, CameraInfo against ``ovis export --ros``, type hashes against the
published values, and the frame REP 103 asks for (right-handed: seen from above, y is
90° counter-clockwise from x) checked through the camera that saw it."""

from __future__ import annotations

import math
import subprocess
import sys
import threading
from pathlib import Path

import cv2
import msgspec
import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from real_photos import photo_paths
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from scipy.spatial.transform import Rotation

from ovis.common.calibration.file import Calibration, save_calibration
from ovis.common.camera.export import as_pinhole
from ovis.common.camera.projection import back_project
from ovis.common.config import OvisConfig, load_config
from ovis.common.fusion.accuracy import position_covariance
from ovis.common.messages import Frame, ObstacleFrame
from ovis.common.ros2.convert import (
    STORE,
    camera_messages,
    image_message,
    message_definition,
    obstacle_messages,
    type_hash,
)
from ovis.common.ros2.floor import NOT_MEASURED, RosFloor, ros_floor
from ovis.common.sim.arena import Arena
from ovis.common.sim.scenes import marked_scene
from ovis.common.world.detection import DetectedObject, Detector
from ovis.common.world.robots import RobotState

READER = get_typestore(Stores.ROS2_JAZZY)
FLOOR = "ovis_floor"
MM = 1e-3  # m
DEG = 0.1  # degrees


def calibration_of(config: OvisConfig, version: int = 1, dipe_px: float = 0.3) -> Calibration:
    """A calibration of ``config``'s camera (its true one: the simulator's)."""
    return Calibration(
        version=version, dipe_px=dipe_px, dipe_mm=None, dipe_max_px=dipe_px, dipe_max_mm=None,
        camera=config.camera, image=config.image, pose=config.pose,
    )  # fmt: skip


def simulated_frames(preset: str, n: int = 3) -> tuple[Calibration, list[ObstacleFrame]]:
    """``n`` frames of a simulated arena with 2 marked robots and 6 obstacles, as the
    pose stage publishes them (ovis's detector on the rendered images)."""
    config = marked_scene(load_config(preset=preset), 2, 6)
    detector = Detector(config.camera, config.image, config.pose)
    frames = []
    for seq, (image, _) in enumerate(Arena(config, seed=3).frames(n)):
        stamp_ns = 1_700_000_000_000_000_000 + seq * 33_333_333
        det = detector.detect(image, stamp_s=stamp_ns / 1e9)
        frames.append(ObstacleFrame(
            seq=seq, stamp_ns=stamp_ns, published_ns=stamp_ns, frame_age_ms=0.0,
            calibration_version=1, robot=next((o for o in det.objects if o.kind == "robot"), None),
            obstacles=[o for o in det.objects if o.kind == "obstacle"], planner=det.planner,
            robots=det.robots,
        ))  # fmt: skip
    return calibration_of(config), frames


def decoded(messages: list, topic: str) -> list:
    return [READER.deserialize_cdr(m.cdr, m.type) for m in messages if m.topic == topic]


def stamp_ns(header) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def yaw_of(q) -> float:
    """Yaw (degrees) of a quaternion about z."""
    assert abs(q.x) < 1e-12 and abs(q.y) < 1e-12
    return math.degrees(2.0 * math.atan2(q.z, q.w))


def angle_diff(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def check_frame(frame: ObstacleFrame, floor: RosFloor) -> None:
    """Every message of ``frame``, decoded, against the frame itself."""
    messages = obstacle_messages(frame, FLOOR, floor)
    ys = floor.y_sign
    for m in messages:
        assert m.cdr[:4] == b"\x00\x01\x00\x00"  # CDR little-endian encapsulation
        assert m.stamp_ns == frame.stamp_ns
    (poses,) = decoded(messages, "obstacles")
    assert poses.header.frame_id == FLOOR and stamp_ns(poses.header) == frame.stamp_ns
    assert len(poses.poses) == len(frame.obstacles)
    for o, p in zip(frame.obstacles, poses.poses, strict=True):
        assert p.position.x == pytest.approx(o.x_cm / 100, abs=MM)
        assert p.position.y == pytest.approx(ys * o.y_cm / 100, abs=MM)
        assert p.position.z == pytest.approx(o.z_cm / 100, abs=MM)
        if o.heading_deg is not None:
            assert angle_diff(yaw_of(p.orientation), ys * o.heading_deg) < DEG
    (markers,) = decoded(messages, "markers")
    kinds = [(m.ns, m.type) for m in markers.markers]
    assert markers.markers[0].action == 3  # DELETEALL: markers of gone objects vanish
    assert kinds.count(("obstacles", 3)) == len(frame.obstacles)  # cylinders
    cylinders = [m for m in markers.markers if m.ns == "obstacles"]
    for o, c in zip(frame.obstacles, cylinders, strict=True):
        assert c.id == o.id and c.scale.x == pytest.approx(2 * o.radius_cm / 100, abs=MM)
        assert c.pose.position.x == pytest.approx(o.x_cm / 100, abs=MM)
        assert c.pose.position.y == pytest.approx(ys * o.y_cm / 100, abs=MM)
    texts = {m.text for m in markers.markers if m.type == 9}
    assert {str(o.id) for o in frame.obstacles} <= texts
    robots = frame.robots
    arrows = [m for m in markers.markers if m.ns == "robots"]
    assert [a.id for a in arrows] == [r.id for r in robots] and all(a.type == 0 for a in arrows)
    for r in robots:
        (odom,) = decoded(messages, f"robots/robot_{r.id}/odom")
        assert odom.header.frame_id == FLOOR and stamp_ns(odom.header) == frame.stamp_ns
        pose = odom.pose.pose
        assert pose.position.x == pytest.approx(r.x_cm / 100, abs=MM)
        assert pose.position.y == pytest.approx(ys * r.y_cm / 100, abs=MM)
        assert angle_diff(yaw_of(pose.orientation), ys * r.heading_deg) < DEG
        # the twist is in the robot's frame: turned back to the floor, ovis's velocity
        yaw = math.radians(ys * r.heading_deg)
        v = odom.twist.twist.linear
        world = (
            math.cos(yaw) * v.x - math.sin(yaw) * v.y,
            math.sin(yaw) * v.x + math.cos(yaw) * v.y,
        )
        if r.velocity_measured:
            assert world[0] == pytest.approx(r.vx_cm_s / 100, abs=MM)
            assert world[1] == pytest.approx(ys * r.vy_cm_s / 100, abs=MM)
            assert math.degrees(odom.twist.twist.angular.z) == pytest.approx(
                ys * r.yaw_rate_deg_s, abs=DEG
            )
        else:
            assert (v.x, v.y, odom.twist.twist.angular.z) == (0.0, 0.0, 0.0)
    assert len(messages) == 2 + len(robots)


@pytest.mark.parametrize("preset", ["default", "pinhole"])
def test_simulated_frames_decode_to_what_ovis_found(preset: str) -> None:
    calib, frames = simulated_frames(preset)
    floor = ros_floor(calib)
    assert floor.mirrored == (preset == "default")  # the paper model images a mirror world
    assert all(f.robots and f.obstacles for f in frames)
    assert any(r.velocity_measured for f in frames for r in f.robots)
    for frame in frames:
        check_frame(frame, floor)


@pytest.mark.parametrize("preset", ["default", "pinhole"])
def test_ros_frame_is_right_handed_and_tf_with_camera_info_project_as_ovis_does(
    preset: str,
) -> None:
    """The camera that saw the floor, as /tf_static and CameraInfo give it to ROS,
    projects ROS points where ovis's camera projects the ovis points (so RViz overlays
    match the image), with a proper rotation and positive focal lengths; and through it
    ROS's +y is 90° counter-clockwise from +x seen from above: right-handed, z up."""
    calib = calibration_of(load_config(preset=preset))
    floor = ros_floor(calib)
    info_msg, tf_msg = camera_messages(calib, FLOOR, 42)
    assert (info_msg.topic, tf_msg.topic) == ("camera/camera_info", "/tf_static")
    info = READER.deserialize_cdr(info_msg.cdr, info_msg.type)
    (tf,) = READER.deserialize_cdr(tf_msg.cdr, tf_msg.type).transforms
    assert tf.header.frame_id == FLOOR and tf.child_frame_id == info.header.frame_id
    assert stamp_ns(tf.header) == stamp_ns(info.header) == 42
    K = info.k.reshape(3, 3)
    assert K[0, 0] > 0 and K[1, 1] > 0
    t, q = tf.transform.translation, tf.transform.rotation
    R_floor_cam = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    assert np.linalg.det(R_floor_cam) == pytest.approx(1.0)
    assert t.z > 0.3  # the camera hangs above the floor
    # ROS points → camera → pixels (OpenCV's projection with the message's numbers)
    cam = calib.camera
    rng = np.random.default_rng(1)
    rows, cols = rng.uniform(0, cam.rows - 1, 300), rng.uniform(0, cam.cols - 1, 300)
    seen = back_project(rows, cols, cam, 7.0)
    ros = np.array([floor.position_m(x, y, 7.0) for x, y in zip(seen.x_cm, seen.y_cm, strict=True)])
    R = R_floor_cam.T
    tvec = -R @ np.array([t.x, t.y, t.z])
    px = cv2.projectPoints(ros, cv2.Rodrigues(R)[0], tvec, K, info.d)[0].reshape(-1, 2)
    ok = seen.valid & (((R @ ros.T).T + tvec)[:, 2] > 0)
    assert ok.sum() > 250
    fit = as_pinhole(cam).max_px + 0.01
    np.testing.assert_allclose(px[ok, 0], cols[ok], atol=fit)
    np.testing.assert_allclose(px[ok, 1], rows[ok], atol=fit)
    # right-handed: seen from above (the camera's view, screen up = −row), x → y is CCW
    c = np.array(floor.position_m(150.0, 0.0, 0.0))
    axes = np.vstack([c, c + np.array([0.1, 0.0, 0.0]), c + np.array([0.0, 0.1, 0.0])])
    (o, ex, ey) = cv2.projectPoints(axes, cv2.Rodrigues(R)[0], tvec, K, info.d)[0].reshape(3, 2)
    (ax, ay), (bx, by) = (ex - o) * [1, -1], (ey - o) * [1, -1]  # (right, up) on the screen
    assert ax * by - ay * bx > 0


def test_camera_info_has_the_numbers_of_ovis_export_ros(tmp_path: Path) -> None:
    """The same numbers as the file ``ovis export --ros`` writes (for the paper model's
    mirrored floor, fy and p1 with the camera's y turned: the module docstring)."""
    for preset in ("pinhole", "default"):
        calib = calibration_of(load_config(preset=preset))
        save_calibration(tmp_path / "c.json", calib)
        out = tmp_path / f"{preset}.yaml"
        proc = subprocess.run(
            [sys.executable, "-m", "ovis.services.cli", "export", str(tmp_path / "c.json"),
             "--ros", str(out)],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        exported = yaml.safe_load(out.read_text())
        info_msg = camera_messages(calib, FLOOR, 0)[0]
        info = READER.deserialize_cdr(info_msg.cdr, info_msg.type)
        turn = -1.0 if ros_floor(calib).mirrored else 1.0
        K = np.array(exported["camera_matrix"]["data"]).reshape(3, 3)
        K[:, 1] *= turn
        P = np.array(exported["projection_matrix"]["data"]).reshape(3, 4)
        P[:, 1] *= turn
        D = np.array(exported["distortion_coefficients"]["data"])
        D[2] *= turn
        np.testing.assert_array_equal(info.k, K.ravel())
        np.testing.assert_array_equal(info.p, P.ravel())
        np.testing.assert_array_equal(info.d, D)
        np.testing.assert_array_equal(info.r, exported["rectification_matrix"]["data"])
        assert (info.width, info.height) == (exported["image_width"], exported["image_height"])
        assert info.distortion_model == exported["distortion_model"] == "plumb_bob"


def test_odometry_covariance_is_ovis_accuracy_model() -> None:
    calib, frames = simulated_frames("pinhole", 1)
    floor = ros_floor(calib)
    frame = frames[0]
    r = frame.robots[0]
    (odom,) = decoded(obstacle_messages(frame, FLOOR, floor), f"robots/robot_{r.id}/odom")
    cov = odom.pose.covariance.reshape(6, 6)
    expected = position_covariance(r.x_cm, r.y_cm, r.z_cm, calib.camera, calib.dipe_px)[0] / 1e4
    # the accuracy map's grid node (2 cm away at most) against the point itself
    np.testing.assert_allclose(cov[:2, :2], expected, rtol=0.05, atol=1e-3 * expected[0, 0])
    assert 0 < cov[0, 0] < 1e-4  # sub-cm
    side_m = calib.pose.robots[0].marker_side_cm / 100
    sigma = math.sqrt(np.trace(cov[:2, :2]) / 2)
    assert cov[5, 5] == pytest.approx((sigma / (side_m * math.sqrt(2))) ** 2)
    assert cov[2, 2] == cov[3, 3] == cov[4, 4] == NOT_MEASURED
    assert (odom.twist.covariance.reshape(6, 6).diagonal() == NOT_MEASURED).all()
    # without a calibration (version 0) nothing is claimed
    uncalibrated = ros_floor(msgspec.structs.replace(calib, version=0))
    (odom,) = decoded(obstacle_messages(frame, FLOOR, uncalibrated), f"robots/robot_{r.id}/odom")
    assert (odom.pose.covariance.reshape(6, 6).diagonal() == NOT_MEASURED).all()


def test_image_decodes_to_the_frame_pixels() -> None:
    """A real photo (grey) and a simulated colour frame: the JPEG in the message decodes
    to the frame's pixels within JPEG's error, stamped with the capture time."""
    grey = cv2.imread(str(photo_paths()[0]), cv2.IMREAD_GRAYSCALE)
    colour = cv2.cvtColor(next(Arena(load_config(), 0).frames(1))[0], cv2.COLOR_GRAY2BGR)
    for image in (grey, colour):
        frame = Frame.from_image(image, seq=7, stamp_ns=123_456_789_012)
        m = image_message(frame, quality=95)
        assert (m.topic, m.stamp_ns) == ("camera/image/compressed", frame.stamp_ns)
        msg = READER.deserialize_cdr(m.cdr, m.type)
        assert stamp_ns(msg.header) == frame.stamp_ns
        enc = "mono8" if image.ndim == 2 else "bgr8"
        assert msg.format == f"{enc}; jpeg compressed {enc}"
        back = cv2.imdecode(msg.data, cv2.IMREAD_UNCHANGED)
        assert back.shape == image.shape
        assert np.abs(back.astype(int) - image).mean() < 2.0


#: Published RIHS01 hashes of standard types (ROS 2 Jazzy's generated type descriptions,
#: e.g. rmw_zenoh's design document keys ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66…``,
#: and the sensor_msgs hashes listed by independent rmw_zenoh clients).
PUBLISHED = {
    "std_msgs/msg/String":
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "sensor_msgs/msg/Image":
        "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47",
    "sensor_msgs/msg/CameraInfo":
        "RIHS01_b3dfd68ff46c9d56c80fd3bd4ed22c7a4ddce8c8348f2f59c299e73118e7e275",
    "geometry_msgs/msg/PoseArray":
        "RIHS01_af0cc36d190e104d546d168d6b39df04fa4b4ccecf59cb4c9ed328d3d5004aa0",
}  # fmt: skip
OURS = [
    "geometry_msgs/msg/PoseArray",
    "visualization_msgs/msg/MarkerArray",
    "nav_msgs/msg/Odometry",
    "sensor_msgs/msg/CameraInfo",
    "tf2_msgs/msg/TFMessage",
    "sensor_msgs/msg/CompressedImage",
]


def test_type_hashes_are_the_published_ones_and_stable_across_distros() -> None:
    assert STORE == Stores.ROS2_JAZZY
    for name, value in PUBLISHED.items():
        assert type_hash(name) == value
    kilted = get_typestore(Stores.ROS2_KILTED)
    for name in OURS:
        h = type_hash(name)
        assert h.startswith("RIHS01_") and len(h) == 7 + 64 and int(h[7:], 16) >= 0
        assert kilted.hash_rihs01(name) == h


def test_message_definitions_rebuild_the_same_types() -> None:
    """Each ros2msg text (what the MCAP schema carries) parsed on its own, the way a bag
    reader does, gives a type with the same hash: the text holds every dependency."""
    for name in OURS:
        text = message_definition(name)
        assert text.count("MSG: ") >= 1 and "=" * 80 in text
        store = get_typestore(Stores.EMPTY)
        types = {}
        main, *deps = text.split("=" * 80 + "\n")
        types.update(get_types_from_msg(main, name))
        for dep in deps:
            head, _, body = dep.partition("\n")
            pkg, typ = head.removeprefix("MSG: ").split("/")
            types.update(get_types_from_msg(body, f"{pkg}/msg/{typ}"))
        store.register(types)
        assert store.hash_rihs01(name) == type_hash(name)


ids = st.integers(0, 10_000)
cm = st.floats(-500.0, 500.0, allow_nan=False)
deg = st.floats(-179.99, 180.0, allow_nan=False)


@st.composite
def obstacle_frames(draw) -> ObstacleFrame:
    obstacles = [
        DetectedObject(i, "obstacle", 1.0, 1.0, 10.0, 10.0, 0.8, draw(cm), draw(cm),
                       draw(st.floats(0, 50)), draw(st.floats(0.5, 40)), 10.0,
                       draw(st.none() | deg))
        for i in draw(st.lists(ids, max_size=12, unique=True))
    ]  # fmt: skip
    robots = [
        RobotState(id=i, name=f"r{i}", marker_id=i, x_cm=draw(cm), y_cm=draw(cm),
                   z_cm=draw(st.floats(0, 30)), heading_deg=draw(deg), vx_cm_s=draw(cm),
                   vy_cm_s=draw(cm), yaw_rate_deg_s=draw(deg), age_s=0.0, radius_cm=9.0,
                   velocity_measured=draw(st.booleans()))
        for i in draw(st.lists(ids, max_size=4, unique=True))
    ]  # fmt: skip
    stamp = draw(st.integers(0, 2**31 * 10**9 - 1))  # ROS 2 Time: int32 seconds
    return ObstacleFrame(
        seq=1, stamp_ns=stamp, published_ns=stamp, frame_age_ms=0.0, calibration_version=1,
        robot=None, obstacles=obstacles, planner=[], robots=robots,
    )  # fmt: skip


def test_a_stamp_ros_time_cannot_hold_is_refused_with_the_reason() -> None:
    _, (frame, *_) = simulated_frames("pinhole", 1)
    late = msgspec.structs.replace(frame, stamp_ns=2**31 * 10**9)
    with pytest.raises(ValueError, match="ROS 2 time holds int32 seconds"):
        obstacle_messages(late, FLOOR)


@settings(max_examples=60, deadline=None)
@given(obstacle_frames(), st.booleans())
def test_random_frames_decode_to_their_values(frame: ObstacleFrame, mirrored: bool) -> None:
    check_frame(frame, RosFloor(mirrored))


def test_a_frame_converts_the_same_whatever_came_before_and_on_any_thread() -> None:
    """The message objects are kept between frames and rewritten (a frame's cost is then
    what changes): a frame gives the same bytes after a larger and a smaller frame, and
    threads converting at once do not mix their frames."""
    calib, frames = simulated_frames("default", 3)
    floor = ros_floor(calib)
    few = msgspec.structs.replace(
        frames[1], obstacles=frames[1].obstacles[:1], robots=[], robot=None
    )
    first = [m.cdr for m in obstacle_messages(frames[0], FLOOR, floor)]
    obstacle_messages(frames[2], FLOOR, floor)
    assert len(obstacle_messages(few, FLOOR, floor)) == 2  # poses and markers, no odometry
    assert [m.cdr for m in obstacle_messages(frames[0], FLOOR, floor)] == first
    check_frame(few, floor)
    expected = {f.seq: [m.cdr for m in obstacle_messages(f, FLOOR, floor)] for f in frames}
    mismatches: list[int] = []

    def convert(frame: ObstacleFrame) -> None:
        for _ in range(200):
            if [m.cdr for m in obstacle_messages(frame, FLOOR, floor)] != expected[frame.seq]:
                mismatches.append(frame.seq)

    threads = [threading.Thread(target=convert, args=(f,)) for f in frames]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert mismatches == []


def test_markers_can_be_left_out_of_a_frame() -> None:
    """Between two frames of a lower marker rate: the same messages without markers."""
    calib, (frame, *_) = simulated_frames("pinhole", 1)
    floor = ros_floor(calib)
    full = obstacle_messages(frame, FLOOR, floor)
    lean = obstacle_messages(frame, FLOOR, floor, markers=False)
    assert [m.topic for m in full if m.topic != "markers"] == [m.topic for m in lean]
    assert [m.cdr for m in full if m.topic != "markers"] == [m.cdr for m in lean]
    assert "markers" in {m.topic for m in full}


def test_mirrored_floor_covariance_is_the_model_turned_and_off_grid_is_computed() -> None:
    """The paper model's floor (y mirrored): the covariance terms are the accuracy
    model's with the off-diagonal turned (F·C·F, F = diag(1, −1)), in m²; a point off
    the model's grid gets the model's own value, not a neighbour's."""
    calib = calibration_of(load_config(preset="default"), dipe_px=0.4)
    floor = ros_floor(calib)
    assert floor.mirrored and floor.accuracy is not None
    seen = back_project(np.array([100.0, 300.0]), np.array([120.0, 500.0]), calib.camera, 5.0)
    points = [(float(x), float(y), 5.0) for x, y in zip(seen.x_cm, seen.y_cm, strict=True)]
    points.append((5000.0, -4000.0, 5.0))  # far outside the image: off the grid
    terms = floor.planar_terms(points)
    for (x, y, z), got in zip(points, terms, strict=True):
        model = floor.accuracy(x, y, z)[0]
        if not np.isfinite(model).all():
            assert got is None
            continue
        assert got is not None
        turned = np.diag([1.0, -1.0]) @ model @ np.diag([1.0, -1.0]) / 1e4
        np.testing.assert_allclose([got[0], got[1], got[2]], turned[[0, 0, 1], [0, 1, 1]])
        np.testing.assert_allclose(floor.planar_covariance(x, y, z), turned)
    assert abs(terms[0][1]) > 0  # an off-diagonal that the turn changes


def test_the_floor_of_the_same_calibration_is_kept() -> None:
    """A caller may ask for the floor with every frame: the same calibration (the same
    object or an equal one) gives the same floor, with its accuracy grids built once;
    another calibration gets its own."""
    calib = calibration_of(load_config(preset="pinhole"))
    floor = ros_floor(calib)
    assert ros_floor(calib) is floor
    assert ros_floor(msgspec.structs.replace(calib)) is floor
    other = ros_floor(msgspec.structs.replace(calib, dipe_px=0.9))
    assert other is not floor and other.accuracy is not floor.accuracy
