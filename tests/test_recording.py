"""The recording logic without a bus: session files (write, read, cut, damaged,
recover), lossless frames, Foxglove views and their schemas, pacing, frame selection,
restamping, and handing a recording's calibration to a fresh pipeline."""

from __future__ import annotations

import functools
import json
import os
from pathlib import Path

import cv2
import msgspec
import numpy as np
import pytest
from mcap.reader import make_reader

from ovis.common.calibration.file import calibration_from_config
from ovis.common.calibration.store import CalibrationStore
from ovis.common.capture.sources import SimSource
from ovis.common.config import load_config
from ovis.common.messages import (
    CalibrationUpdate,
    Frame,
    MessageError,
    ObstacleFrame,
    TruthFrame,
    decode,
    encode,
)
from ovis.common.recording.calibration import adopt_recorded_calibration
from ovis.common.recording.foxglove import compressed_image, scene_update
from ovis.common.recording.frames import pack_frame, unpack_frame
from ovis.common.recording.pacing import FrameGate, Pacer, Restamp, parse_speed
from ovis.common.recording.schemas import bus_type, json_schema
from ovis.common.recording.session import RecordingError, SessionReader, SessionWriter, recover
from ovis.common.sim.arena import Arena
from ovis.common.world.detection import Detector

CFG = load_config()
SHARED = Path(
    os.environ.get(
        "OVIS_SHARED_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"
    )
)
REAL = sorted((SHARED / "chessboard-9x6").glob("*.jpg"))


@pytest.fixture(scope="module")
def sim_frames() -> list[bytes]:
    source = SimSource(CFG, 0, prerender=6)
    return [
        encode(Frame.from_image(source.read()[0], seq=i, stamp_ns=10**18 + i * 33_333_333))
        for i in range(6)
    ]


@functools.cache
def _obstacles(seq: int = 7) -> ObstacleFrame:
    image, _ = Arena(CFG, 1).render()
    det = Detector(CFG.camera, CFG.image, CFG.pose).detect(image, stamp_s=1.0)
    return ObstacleFrame(
        seq=seq,
        stamp_ns=1_500_000_000,
        published_ns=1_600_000_000,
        frame_age_ms=100.0,
        calibration_version=1,
        robot=next(o for o in det.objects if o.kind == "robot"),
        obstacles=[o for o in det.objects if o.kind == "obstacle"],
        planner=det.planner,
    )


# --- frames -----------------------------------------------------------------------
def test_packed_frames_rebuild_bit_exact_and_are_smaller(sim_frames) -> None:
    for payload in sim_frames:
        packed = pack_frame(payload)
        assert packed is not None and len(packed) < 0.8 * len(payload)
        assert unpack_frame(packed) == payload


@pytest.mark.skipif(not REAL, reason=f"real photos not found under {SHARED}")
def test_packed_real_colour_photos_rebuild_bit_exact() -> None:
    for path in REAL[:4]:
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        payload = encode(Frame.from_image(image, seq=3, stamp_ns=5, source=path.name))
        packed = pack_frame(payload)
        assert packed is not None and unpack_frame(packed) == payload
        assert decode(unpack_frame(packed), Frame).image().shape == (512, 640, 3)


def test_a_payload_that_does_not_re_encode_is_not_packed(sim_frames) -> None:
    raw = msgspec.msgpack.decode(sim_frames[0])
    raw["extra"] = 1  # a newer sender's field: kept only by recording it as it came
    assert pack_frame(msgspec.msgpack.encode(raw)) is None
    assert pack_frame(b"\x00garbage") is None


def test_damaged_packed_frames_are_refused(sim_frames) -> None:
    packed = msgspec.msgpack.decode(pack_frame(sim_frames[0]))
    packed["pixels"] = packed["pixels"][: len(packed["pixels"]) // 2]
    with pytest.raises(MessageError, match="pixels"):
        unpack_frame(msgspec.msgpack.encode(packed))
    packed["rows"] = -1
    with pytest.raises(MessageError, match="not a packed frame"):
        unpack_frame(msgspec.msgpack.encode(packed))


# --- session files ------------------------------------------------------------------
def _write(path: Path, frames: list[bytes], **kw) -> list[tuple[str, bytes]]:
    obstacles = encode(_obstacles())
    calib = encode(CalibrationUpdate(calibration=calibration_from_config(CFG)))
    written = []
    w = SessionWriter(path, metadata={"arena": "default"}, **kw)
    w.bus("ovis/default/calibration", calib, 1, 1)
    written.append(("ovis/default/calibration", calib))
    for i, f in enumerate(frames):
        w.frame("ovis/default/frames", f, 10 + i, 10 + i)
        w.bus("ovis/default/obstacles", obstacles, 10 + i, 10 + i)
        written += [("ovis/default/frames", f), ("ovis/default/obstacles", obstacles)]
    w.view("/ovis/default/scene", "foxglove.SceneUpdate", scene_update(_obstacles()), 99, 99)
    w.close()
    return written


@pytest.mark.parametrize("compression", ["lz4", "zstd", "none"])
def test_a_session_reads_back_as_written_and_indexed(tmp_path, sim_frames, compression) -> None:
    path = tmp_path / "s.mcap"
    written = _write(path, sim_frames, compression=compression, chunk_size=400_000)
    reader = SessionReader(path)
    got = [(m.topic, m.payload()) for m in reader.bus_messages()]
    assert got == written and reader.complete and reader.cut is None
    assert reader.metadata["ovis"] == {"arena": "default"}
    # The index the mcap library reads (what Foxglove uses to seek).
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary.statistics.message_count == len(written) + 1
    assert len(summary.chunk_indexes) >= 3
    topics = {c.topic: c for c in summary.channels.values()}
    assert topics["ovis/default/frames"].metadata["ovis.codec"] == "packed-frame"
    assert summary.schemas[topics["/ovis/default/scene"].schema_id].name == "foxglove.SceneUpdate"


def test_a_cut_session_reads_to_its_last_complete_chunk_and_recovers(tmp_path, sim_frames) -> None:
    path = tmp_path / "s.mcap"
    written = _write(path, sim_frames, chunk_size=200_000)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    reader = SessionReader(cut)
    got = [(m.topic, m.payload()) for m in reader.bus_messages()]
    assert reader.cut and "last complete chunk" in reader.cut and not reader.complete
    assert 3 <= len(got) < len(written) and got == written[: len(got)]
    report = recover(cut, tmp_path / "fixed.mcap")
    assert report.was_cut and report.messages == reader.messages_read
    fixed = SessionReader(tmp_path / "fixed.mcap")
    assert [(m.topic, m.payload()) for m in fixed.bus_messages()] == got and fixed.complete


def test_damaged_or_foreign_files_raise_one_clear_error(tmp_path, sim_frames) -> None:
    path = tmp_path / "s.mcap"
    _write(path, sim_frames, chunk_size=200_000)
    data = bytearray(path.read_bytes())
    data[len(data) // 3 : len(data) // 3 + 32] = bytes(32)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(RecordingError, match=r"damaged near byte \d+.*--recover"):
        list(SessionReader(bad))
    (tmp_path / "x.mcap").write_text("not a recording")
    with pytest.raises(RecordingError, match="not an MCAP recording"):
        SessionReader(tmp_path / "x.mcap")
    with pytest.raises(RecordingError, match="does not exist"):
        SessionReader(tmp_path / "missing.mcap")
    with pytest.raises(RecordingError, match="compression"):
        SessionWriter(tmp_path / "y.mcap", compression="gzip")


# --- schemas and Foxglove views -------------------------------------------------------
def test_channel_schemas_validate_the_messages_they_describe() -> None:
    jsonschema = pytest.importorskip("jsonschema")
    name, tp = bus_type("ovis/default/obstacles")
    assert name == "ovis.ObstacleFrame" and tp is ObstacleFrame
    schema = json_schema(tp, name)
    assert "$ref" not in json.dumps(schema)  # self-contained: Foxglove reads one document
    jsonschema.validate(json.loads(msgspec.json.encode(_obstacles())), schema)
    bad = json.loads(msgspec.json.encode(_obstacles()))
    bad["seq"] = -1
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, schema)
    assert bus_type("ovis/default/something")[0] == "ovis.Message"


def test_compressed_image_is_the_frame_as_jpeg(sim_frames) -> None:
    frame = decode(sim_frames[1], Frame)
    view = compressed_image(frame)
    assert view.format == "jpeg" and (view.timestamp.sec, view.timestamp.nsec) == divmod(
        frame.stamp_ns, 10**9
    )
    back = cv2.imdecode(np.frombuffer(view.data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert back.shape == frame.image().shape
    assert np.abs(back.astype(int) - frame.image()).mean() < 3.0  # JPEG quality 90
    as_json = json.loads(msgspec.json.encode(view))
    assert set(as_json) == {"timestamp", "frame_id", "data", "format"}  # data in base64


def test_scene_update_places_the_robot_and_obstacles_in_metres() -> None:
    msg = _obstacles()
    scene = scene_update(msg)
    assert scene.deletions[0].type == 1  # the previous frame's entities go
    ids = [e.id for e in scene.entities]
    assert ids == ["robot-0", *[f"obstacle-{o.id}" for o in msg.obstacles]]
    robot = scene.entities[0].cubes[0]
    assert robot.pose.position.x == pytest.approx(msg.robot.x_cm / 100)
    assert robot.size.x * robot.size.y == pytest.approx(msg.robot.area_cm2 / 1e4)
    for entity, o in zip(scene.entities[1:], msg.obstacles, strict=True):
        cyl = entity.cylinders[0]
        assert (cyl.pose.position.x, cyl.pose.position.y) == pytest.approx(
            (o.x_cm / 100, o.y_cm / 100)
        )
        assert cyl.size.x == pytest.approx(2 * o.radius_cm / 100)
        assert cyl.size.z == pytest.approx(o.z_cm / 100)


# --- pacing, frame selection, restamping --------------------------------------------------
def test_frame_gate() -> None:
    every, none, two = FrameGate("every"), FrameGate("none"), FrameGate(" 2/s ")
    stamps = [int(i * 1e9 / 30) for i in range(90)]  # 3 s at 30 frames/s
    assert sum(map(every.keep, stamps)) == 90 and sum(map(none.keep, stamps)) == 0
    assert sum(map(two.keep, stamps)) == 6
    for bad in ("0/s", "-1/s", "nan/s", "fast", "5"):
        with pytest.raises(ValueError, match="every"):
            FrameGate(bad)


def test_pacer_keeps_the_recorded_pace() -> None:
    now = [100.0]
    waits: list[float] = []

    def wait(s: float) -> bool:
        waits.append(round(s, 6))
        now[0] += s
        return False

    pacer = Pacer(2.0, lambda: now[0], wait)
    for log_ns in (5_000_000_000, 5_500_000_000, 7_000_000_000):
        assert pacer.until(log_ns)
    assert waits == [0.25, 0.75]  # twice as fast: 0.5 s → 0.25 s, then to 1.0 s
    assert Pacer(None, lambda: 0.0, wait).until(10**18)  # max: never waits
    stopped = Pacer(1.0, lambda: 0.0, lambda s: True)
    assert stopped.until(0) and not stopped.until(10**9)
    assert parse_speed("max") is None and parse_speed("0.5") == 0.5
    for bad in ("0", "nan", "fast", "-1"):
        with pytest.raises(ValueError, match="speed"):
            parse_speed(bad)


def test_restamp_keeps_the_first_pass_bit_exact_then_moves_on(sim_frames) -> None:
    r = Restamp()
    assert [r.frame(f) for f in sim_frames] == sim_frames
    truth = encode(TruthFrame(seq=2, objects=[]))
    assert r.truth(truth) == truth
    r.next_pass()
    again = [decode(r.frame(f), Frame) for f in sim_frames]
    assert [f.seq for f in again] == list(range(6, 12))
    first = decode(sim_frames[0], Frame).stamp_ns
    assert again[0].stamp_ns == first + 6 * 33_333_333  # after the pass, one period on
    assert again[0].data == decode(sim_frames[0], Frame).data
    assert decode(r.truth(truth), TruthFrame).seq == 8
    shifted = Restamp(shift_ns=-5)
    assert decode(shifted.frame(sim_frames[0]), Frame).stamp_ns == first - 5


# --- calibration hand-over -----------------------------------------------------------------
def test_a_recordings_calibration_goes_to_an_empty_state_folder(tmp_path, sim_frames) -> None:
    calib = msgspec.structs.replace(calibration_from_config(CFG), version=7, dipe_px=0.25)
    path = tmp_path / "s.mcap"
    w = SessionWriter(path)
    w.bus("ovis/default/calibration", encode(CalibrationUpdate(calibration=calib)), 1, 1)
    w.frame("ovis/default/frames", sim_frames[0], 2, 2)
    w.close()
    note = adopt_recorded_calibration(path, tmp_path / "state")
    assert "recording's calibration v7" in note
    assert CalibrationStore(tmp_path / "state").latest()[0] == calib  # same version, same values
    note = adopt_recorded_calibration(path, tmp_path / "state")
    assert "using calibration v7 of" in note  # a folder with one keeps its own
    empty = tmp_path / "empty.mcap"
    SessionWriter(empty).close()
    assert "holds no calibration" in adopt_recorded_calibration(empty, tmp_path / "other")
