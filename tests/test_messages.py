"""The message codec: round trips, the wire format seen by a plain msgpack library,
validation with exact error text, images, key expressions and the JSON Schema.

Every case runs against ovis's msgspec codec *and* the independent ``msgpack`` package:
what ovis encodes must read as a tagged map of field names, and what a plain msgpack
encoder writes from such a map must decode to the same message.
"""

from __future__ import annotations

import copy
import json
import math
import subprocess
import sys
from typing import Any

import msgpack
import msgspec
import numpy as np
import pytest
import skimage.data
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ovis.common.calibration.file import Calibration, GenerationRecord, PointResidual
from ovis.common.config import CalibrationRanges, GAConfig, load_config
from ovis.common.messages import (
    ENCODING,
    MAX_IMAGE_SIDE,
    BinaryFrame,
    BlobList,
    BlobMeasure,
    BlobPatch,
    CalibrateReply,
    CalibrateRequest,
    CalibrationUpdate,
    FloorMaps,
    Frame,
    MessageError,
    ObstacleFrame,
    PlaneMap,
    RobotCommand,
    RobotDrive,
    ServiceStatus,
    SourceGap,
    SourceState,
    StreamHealth,
    Topics,
    TruthFrame,
    WorldFrame,
    WorldObject,
    decode,
    encode,
    message_schema,
)
from ovis.common.sim.arena import SimObject
from ovis.common.world.detection import DetectedObject, PlannerEntry

MESSAGE_TYPES = [
    Frame,
    BinaryFrame,
    BlobList,
    ObstacleFrame,
    TruthFrame,
    CalibrateRequest,
    CalibrateReply,
    CalibrationUpdate,
    ServiceStatus,
    StreamHealth,
    WorldFrame,
    SourceState,
    RobotCommand,
    RobotDrive,
]


# --- builders -------------------------------------------------------------------------
def _tag(cls: type) -> str:
    return msgspec.inspect.type_info(cls).tag


def _detected(id: int, kind: str = "obstacle", **kw: Any) -> DetectedObject:
    fields: dict[str, Any] = dict(
        id=id,
        kind=kind,
        row=120.5,
        col=340.25,
        area_px=812.0,
        perimeter_px=101.3,
        compactness=1.004,
        x_cm=-12.75,
        y_cm=88.125,
        z_cm=5.0,
        radius_cm=4.884,
        area_cm2=74.94,
    )
    fields.update(kw)
    return DetectedObject(**fields)


def _obstacle_frame(**kw: Any) -> ObstacleFrame:
    obstacles = [_detected(2), _detected(3, x_cm=96.862, y_cm=132.382, radius_cm=5.272)]
    fields: dict[str, Any] = dict(
        seq=41,
        stamp_ns=1_712_000_000_123_456_789,
        published_ns=1_712_000_000_140_000_000,
        frame_age_ms=16.543,
        calibration_version=3,
        robot=_detected(
            1,
            "robot",
            x_cm=98.241,
            y_cm=30.626,
            heading_deg=-12.5,
            elongation=1.8,
            vx_cm_s=3.0,
            heading_resolved=True,
        ),
        obstacles=obstacles,
        planner=[
            PlannerEntry(obstacle_id=2, distance_cm=71.9, angle_deg=-101.5),
            PlannerEntry(obstacle_id=3, distance_cm=101.9, angle_deg=35.25),
        ],
        arena="lab-2",
    )
    fields.update(kw)
    return ObstacleFrame(**fields)


def _patch(**kw: Any) -> BlobPatch:
    diff = np.arange(-6, 6, dtype=np.int16).reshape(3, 4) * 40  # signed: shadows are < 0
    fields: dict[str, Any] = dict(
        top=4,
        left=17,
        rows=3,
        cols=4,
        diff=diff.astype("<i2").tobytes(),
        filled_area_px=310.0,
        filled_row=10.75,
        filled_col=20.0,
    )
    fields.update(kw)
    return BlobPatch(**fields)


def _blob(**kw: Any) -> BlobMeasure:
    fields: dict[str, Any] = dict(
        row=10.5,
        col=20.25,
        area_px=300.0,
        perimeter_px=62.0,
        compactness=1.02,
        mu_rr=24.0,
        mu_cc=23.5,
        mu_rc=-0.75,
    )
    fields.update(kw)
    return BlobMeasure(**fields)


def _calibration() -> Calibration:
    """Built like tests/test_calibration_file.py does, plus points and a GA history."""
    cfg = load_config()
    return Calibration(
        version=7,
        created="2024-05-01T12:00:00+00:00",
        dipe_px=0.5,
        dipe_mm=0.132,
        dipe_max_px=0.8,
        dipe_max_mm=0.2,
        camera=cfg.camera,
        image=cfg.image,
        pose=cfg.pose,
        points=[
            PointResidual(
                name="P1",
                x_cm=0.0,
                y_cm=0.0,
                z_cm=0.0,
                detected_row=10.0,
                detected_col=12.0,
                predicted_row=10.2,
                predicted_col=11.9,
                dipe_px=0.22,
                dipe_mm=0.05,
            )
        ],
        ga=GAConfig(),
        ranges=CalibrationRanges(),
        history=[GenerationRecord(0, 3.5, None, 3.5, 0.4), GenerationRecord(1, 2.5, 4.0, 2.5, 0.6)],
        evaluations=200,
        elapsed_s=1.25,
        source_image="frame-0041.png",
    )


def _gray() -> np.ndarray:
    return skimage.data.camera()[::8, ::8]  # (64, 64) uint8, a real photograph


def _bgr() -> np.ndarray:
    return skimage.data.astronaut()[::8, ::4, ::-1]  # (64, 128, 3), non-square


def _mask() -> np.ndarray:
    image = skimage.data.coins()[:37, :53]  # 37 x 53 = 1961 bits: the last byte is padded
    return (image > 128).astype(np.uint8)


def sample_messages() -> dict[str, Any]:
    mask = _mask()
    starting = ServiceStatus(service="capture", pid=1, host="h", started_ns=0, state="starting")
    return {
        "frame-gray": Frame.from_image(_gray(), seq=0, stamp_ns=1, source="camera:0"),
        "frame-bgr": Frame.from_image(_bgr(), seq=2**63, stamp_ns=2**64 - 1),
        "binary": BinaryFrame(
            seq=5,
            stamp_ns=6,
            rows=mask.shape[0],
            cols=mask.shape[1],
            bits=np.packbits(mask).tobytes(),
            threshold=128,
            calibration_version=2,
        ),
        "blobs": BlobList(
            seq=9,
            stamp_ns=10,
            rows=480,
            cols=640,
            calibration_version=1,
            blobs=[_blob(), _blob(row=479.0, col=0.0, mu_rc=1e9)],
        ),
        "blobs-empty": BlobList(seq=0, stamp_ns=0, rows=1, cols=1, calibration_version=0, blobs=[]),
        "binary-gray": BinaryFrame(
            seq=7,
            stamp_ns=8,
            rows=mask.shape[0],
            cols=mask.shape[1],
            bits=np.packbits(mask).tobytes(),
            threshold=131,
            calibration_version=2,
            gray=(mask * 200).astype(np.uint8).tobytes(),
        ),
        "blobs-patches": BlobList(
            seq=11,
            stamp_ns=12,
            rows=480,
            cols=640,
            calibration_version=1,
            blobs=[_blob()],
            patches=[_patch()],
        ),
        "obstacles-measured": _obstacle_frame(
            obstacles=[
                _detected(
                    2,
                    z_cm=12.25,
                    z_source="one camera",
                    z_sigma_cm=0.07,
                    covariance_cm2=[0.01, 0.0, 0.002, 0.0, 0.01, 0.001, 0.002, 0.001, 0.0049],
                    shape="box",
                ),
                _detected(3, z_source="configured", z_unmeasured="not measurable", shape="prism5"),
            ]
        ),
        "obstacles": _obstacle_frame(),
        "obstacles-no-robot": _obstacle_frame(robot=None, obstacles=[], planner=[]),
        "truth": TruthFrame(
            seq=3,
            objects=[
                SimObject(
                    id=1,
                    kind="robot",
                    x_cm=98.0,
                    y_cm=30.5,
                    z_cm=12.0,
                    radius_cm=9.0,
                    heading_deg=45.0,
                    shape="rect",
                    length_cm=20.0,
                    width_cm=12.7,
                ),
                SimObject(
                    id=2,
                    kind="obstacle",
                    x_cm=28.7,
                    y_cm=26.3,
                    z_cm=5.0,
                    radius_cm=4.884,
                    heading_deg=0.0,
                    shape="disk",
                    length_cm=9.768,
                    width_cm=9.768,
                ),
            ],
        ),
        "calibrate": CalibrateRequest(),
        "calibrate-full": CalibrateRequest(frame_seq=41, seed=7, population=100, generations=90),
        "calibrate-reply": CalibrateReply(
            ok=True,
            version=8,
            frame_seq=41,
            dipe_px=0.41,
            dipe_mm=0.11,
            dipe_max_px=0.9,
            elapsed_s=12.5,
            parameters={"Z0_cm": 137.2, "lam_mm": 4.1, "k1": -1e-3},
            saved_to="/var/lib/ovis/calib-v8.json",
        ),
        "calibrate-reply-error": CalibrateReply(ok=False, error="no frame yet"),
        "calibration": CalibrationUpdate(calibration=_calibration()),
        "status": ServiceStatus(
            service="pose",
            pid=4242,
            host="arena-pc",
            started_ns=1_712_000_000_000_000_000,
            state="ok",
            frames_in=100,
            frames_out=99,
            fps=29.97,
            dropped=1,
            errors={"bad_blobs": 2},
            last_error="refused a 3-byte blobs message: …",
            calibration_version=3,
            last_frame_age_s=0.033,
            rss_mb=87.5,
        ),
        "status-starting": starting,
        "health-stalled": StreamHealth(
            state="stalled",
            published_ns=1_700_000_000_000_000_000,
            last_seq=41,
            seconds_since_frame=2.5,
            last_frame_age_ms=3.2,
            frames_dropped=1,
            calibration_version=2,
        ),
        "health-waiting": StreamHealth(state="waiting", published_ns=1),
        "health-source-lost": StreamHealth(
            state="source lost",
            published_ns=1_700_000_000_000_000_000,
            last_seq=41,
            seconds_since_frame=1.2,
            reason="stream http://cam/stream delivered no frame for 1 s or closed",
        ),
        "status-source-lost": msgspec.structs.replace(
            starting,
            state="source lost",
            reason="cannot open camera 0",
            source_gaps=2,
            source_gap_s=7.25,
            gaps=[
                SourceGap(start_ns=10, seconds=3.0, reason="camera 0 delivered no frame"),
                SourceGap(start_ns=90, seconds=4.25, reason="cannot open camera 0", ongoing=True),
            ],
        ),
        "source-lost": SourceState(
            state="source lost",
            published_ns=1_700_000_000_000_000_000,
            reason="ended: folder photos (14 images): all images sent (loop is off)",
            lost_ns=1_699_999_999_000_000_000,
            ended=True,
            gaps=1,
        ),
        "source-ok": SourceState(state="ok", published_ns=5, gaps=3),
        "world": WorldFrame(
            seq=3,
            stamp_ns=1_700_000_000_000_000_000,
            published_ns=1_700_000_000_004_000_000,
            arena="lab",
            objects=[
                WorldObject(
                    id=1,
                    kind="robot",
                    x_cm=50.0,
                    y_cm=40.0,
                    z_cm=5.0,
                    radius_cm=9.0,
                    sigma_cm=0.05,
                    cameras=["cam00", "cam10"],
                    marker_id=0,
                    heading_deg=-30.0,
                ),
                WorldObject(
                    id=1000,
                    kind="obstacle",
                    x_cm=120.0,
                    y_cm=60.0,
                    z_cm=7.0,
                    radius_cm=5.0,
                    sigma_cm=0.07,
                    cameras=["cam10"],
                ),
            ],
            cameras=["cam00", "cam10"],
            missing=["cam11"],
            late_frames={"cam00": 0, "cam10": 2, "cam11": 0},
        ),
        "robot_command": RobotCommand(
            robot_id=1,
            seq=9,
            stream="c0ffee",
            stamp_ns=1_700_000_000_000_000_000,
            published_ns=1_700_000_000_002_000_000,
            v_cm_s=12.5,
            omega_deg_s=-30.0,
            planner="fuzzy",
            goal_cm=(135.0, 60.0),
            critical_id=4,
            distance_cm=18.2,
            angle_deg=-25.0,
            deviation_deg=40.0,
        ),
        "robot_command_stop": RobotCommand(
            robot_id=2,
            seq=10,
            stream="c0ffee",
            stamp_ns=1_700_000_000_000_000_000,
            published_ns=1_700_000_000_002_000_000,
            v_cm_s=0.0,
            omega_deg_s=0.0,
            stop="stream health stalled",
        ),
        "robot_drive": RobotDrive(
            robot_id=1,
            stamp_ns=1_700_000_000_000_000_000,
            t_s=3.2,
            x_cm=60.0,
            y_cm=58.5,
            heading_deg=170.0,
            v_cm_s=19.0,
            omega_deg_s=4.0,
            goal_cm=(15.0, 60.0),
            collisions=0,
            min_clearance_cm=6.5,
            commands=31,
            refused=1,
        ),
    }


SAMPLES = sample_messages()
CASES = sorted(SAMPLES)


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


def _builtins(message: Any) -> Any:
    """The message as plain Python values as msgpack yields them: bytes kept, arrays as lists."""
    return _plain(msgspec.to_builtins(message, builtin_types=(bytes,)))


def test_the_samples_cover_every_message_type() -> None:
    assert {type(m) for m in SAMPLES.values()} == set(MESSAGE_TYPES)


# --- round trips ------------------------------------------------------------------------
@pytest.mark.parametrize("name", CASES)
def test_round_trip_through_msgspec(name: str) -> None:
    message = SAMPLES[name]
    payload = encode(message)
    assert isinstance(payload, bytes)
    assert decode(payload) == message  # as the union of all messages
    assert decode(payload, type(message)) == message  # as its own type
    assert decode(memoryview(payload), type(message)) == message


@pytest.mark.parametrize("name", CASES)
def test_wire_format_is_a_tagged_map_of_field_names(name: str) -> None:
    message = SAMPLES[name]
    payload = encode(message)
    assert payload[0] in range(0x80, 0x90) or payload[0] in (0xDE, 0xDF)  # a msgpack map
    wire = msgpack.unpackb(payload, raw=False)
    assert isinstance(wire, dict)
    assert wire["type"] == _tag(type(message))
    assert set(wire) == {"type", *message.__struct_fields__}
    assert wire == {"type": _tag(type(message)), **_builtins(message)}


@pytest.mark.parametrize("name", CASES)
def test_a_plain_msgpack_encoder_is_understood(name: str) -> None:
    message = SAMPLES[name]
    wire = {"type": _tag(type(message)), **_builtins(message)}
    assert decode(msgpack.packb(wire, use_bin_type=True)) == message


def test_obstacle_map_holds_objects_and_planner_as_maps() -> None:
    wire = msgpack.unpackb(encode(_obstacle_frame()), raw=False)
    assert wire["robot"]["kind"] == "robot" and wire["robot"]["heading_deg"] == -12.5
    assert wire["robot"]["heading_resolved"] is True
    assert wire["obstacles"][0]["heading_resolved"] is False
    assert [o["id"] for o in wire["obstacles"]] == [2, 3]
    assert wire["obstacles"][0]["heading_deg"] is None
    assert wire["planner"][1] == {"obstacle_id": 3, "distance_cm": 101.9, "angle_deg": 35.25}
    assert set(wire["obstacles"][0]) == set(DetectedObject.__struct_fields__)


def test_an_object_from_an_older_sender_has_its_heading_unresolved() -> None:
    """`heading_resolved` is new (at the end, default false): an obstacle map without it
    decodes, and the heading then counts as an axis."""
    wire = msgpack.unpackb(encode(_obstacle_frame()), raw=False)
    for obj in (wire["robot"], *wire["obstacles"]):
        del obj["heading_resolved"]
    old = decode(msgpack.packb(wire, use_bin_type=True), ObstacleFrame)
    assert old.robot is not None and old.robot.heading_resolved is False
    assert old.robot.heading_deg == -12.5


def test_bytes_travel_as_msgpack_bin() -> None:
    frame = SAMPLES["frame-gray"]
    wire = msgpack.unpackb(encode(frame), raw=False)
    assert isinstance(wire["data"], bytes) and wire["data"] == _gray().tobytes()


def test_unknown_fields_from_newer_senders_are_ignored() -> None:
    wire = msgpack.unpackb(encode(_obstacle_frame()), raw=False)
    wire["future_field"] = [1, 2, 3]
    wire["planner"][0]["future_field"] = "x"
    assert decode(msgpack.packb(wire), ObstacleFrame) == _obstacle_frame()


def test_defaults_fill_fields_older_senders_leave_out() -> None:
    wire = {"type": "calibrate-reply", "ok": True}
    assert decode(msgpack.packb(wire)) == CalibrateReply(ok=True)


# --- images ---------------------------------------------------------------------------
def _address(buffer: Any) -> int:
    return np.frombuffer(buffer, dtype=np.uint8).__array_interface__["data"][0]


@pytest.mark.parametrize(
    "image,shape", [(_gray(), (64, 64)), (_bgr(), (64, 128, 3))], ids=["gray", "bgr"]
)
def test_frame_image_is_zero_copy_read_only_with_the_right_shape(
    image: np.ndarray, shape: tuple[int, ...]
) -> None:
    frame = decode(encode(Frame.from_image(image, seq=1, stamp_ns=2)), Frame)
    out = frame.image()
    assert out.shape == shape and out.dtype == np.uint8
    assert np.array_equal(out, image)
    assert not out.flags.writeable
    assert out.__array_interface__["data"][0] == _address(frame.data)  # no copy of data
    with pytest.raises(ValueError, match="read-only"):
        out[0, 0] = 1


def test_frame_without_copy_shares_the_image_read_only_and_encodes_the_same() -> None:
    image = np.ascontiguousarray(_bgr())
    copied = Frame.from_image(image, seq=3, stamp_ns=4)
    shared = Frame.from_image(image, seq=3, stamp_ns=4, copy=False)
    assert _address(shared.data) == image.__array_interface__["data"][0]
    assert _address(copied.data) != image.__array_interface__["data"][0]
    assert encode(shared) == encode(copied)
    assert not shared.image().flags.writeable
    with pytest.raises(ValueError, match="read-only"):
        shared.image()[0, 0, 0] = 1
    decoded = decode(encode(shared), Frame)
    assert np.array_equal(decoded.image(), image)


def test_frame_from_image_copies_a_non_contiguous_view_in_row_major_order() -> None:
    view = _bgr()  # strided, reversed channels
    assert not view.flags.c_contiguous
    frame = Frame.from_image(view, seq=0, stamp_ns=0)
    assert (frame.rows, frame.cols, frame.channels) == (64, 128, 3)
    assert frame.data == np.ascontiguousarray(view).tobytes()


@pytest.mark.parametrize(
    "image,needle",
    [
        (
            np.zeros((4, 4), np.float32),
            "expected a uint8 grey (H, W) or BGR (H, W, 3) image, got float32 (4, 4)",
        ),
        (np.zeros((4,), np.uint8), "got uint8 (4,)"),
        (np.zeros((2, 2, 2, 2), np.uint8), "got uint8 (2, 2, 2, 2)"),
    ],
)
def test_frame_from_image_refuses_what_it_cannot_carry(image: np.ndarray, needle: str) -> None:
    with pytest.raises(ValueError) as err:
        Frame.from_image(image, seq=0, stamp_ns=0)
    assert needle in str(err.value)


def test_frame_from_image_refuses_four_channels() -> None:
    with pytest.raises(ValueError):
        Frame.from_image(np.zeros((2, 2, 4), np.uint8), seq=0, stamp_ns=0)


@pytest.mark.parametrize("rows,cols", [(1, 1), (1, 9), (3, 3), (37, 53), (8, 8)])
def test_binary_frame_mask_inverts_packbits(rows: int, cols: int) -> None:
    rng = np.random.default_rng(rows * 100 + cols)
    mask = (rng.random((rows, cols)) > 0.5).astype(np.uint8)
    frame = BinaryFrame(
        seq=0,
        stamp_ns=0,
        rows=rows,
        cols=cols,
        bits=np.packbits(mask).tobytes(),
        threshold=1,
        calibration_version=0,
    )
    out = decode(encode(frame), BinaryFrame).mask()
    assert out.shape == (rows, cols) and out.dtype == np.uint8
    assert np.array_equal(out, mask)


def test_binary_frame_of_a_real_image() -> None:
    assert np.array_equal(decode(encode(SAMPLES["binary"])).mask(), _mask())


# --- refusals, with the exact reason ---------------------------------------------------
def _mutated(message: Any, mutate) -> bytes:
    """The message as a plain map, changed by ``mutate``, packed by plain msgpack."""
    wire = copy.deepcopy(msgpack.unpackb(encode(message), raw=False))
    mutate(wire)
    return msgpack.packb(wire, use_bin_type=True)


def _set(path: str, value: Any):
    """A mutation setting ``a.b[1].c``-style ``path`` to ``value``."""

    def mutate(wire: dict[str, Any]) -> None:
        keys: list[Any] = []
        for part in path.split("."):
            name, _, index = part.partition("[")
            keys.append(name)
            if index:
                keys.append(int(index.rstrip("]")))
        target: Any = wire
        for key in keys[:-1]:
            target = target[key]
        target[keys[-1]] = value

    return mutate


def _drop(field: str):
    return lambda wire: wire.pop(field)


REFUSALS = [
    ("frame-gray", _set("seq", -1), "Expected `int` >= 0 - at `$.seq`"),
    ("frame-gray", _set("stamp_ns", "now"), "Expected `int`, got `str` - at `$.stamp_ns`"),
    ("frame-gray", _set("rows", 0), "Expected `int` >= 1 - at `$.rows`"),
    ("frame-gray", _set("cols", MAX_IMAGE_SIDE + 1), "Expected `int` <= 16384 - at `$.cols`"),
    ("frame-gray", _set("channels", 4), "Invalid enum value 4 - at `$.channels`"),
    ("frame-gray", _set("dtype", "float32"), "Invalid enum value 'float32' - at `$.dtype`"),
    (
        "frame-gray",
        _set("data", b"\x00" * 4095),
        "data holds 4095 bytes but rows x cols x channels = 64 x 64 x 1 needs 4096",
    ),
    (
        "frame-bgr",
        _set("data", b"\x00" * 8192),
        "data holds 8192 bytes but rows x cols x channels = 64 x 128 x 3 needs 24576",
    ),
    ("frame-gray", _set("data", "not bytes"), "Expected `bytes`, got `str` - at `$.data`"),
    ("binary", _set("bits", b"\x00" * 247), "bits holds 247 bytes, 37 x 53 needs 246"),
    ("binary", _set("bits", b""), "bits holds 0 bytes, 37 x 53 needs 246"),
    ("binary", _set("threshold", 256), "Expected `int` <= 255 - at `$.threshold`"),
    ("binary-gray", _set("gray", b"\x00" * 1960), "gray holds 1960 bytes, 37 x 53 needs 1961"),
    (
        "blobs-patches",
        _set("patches", []),
        "patches must have one entry per blob (0 for 1 blobs)",
    ),
    (
        "blobs-patches",
        _set("patches[0].diff", b"\x00" * 23),
        "diff holds 23 bytes, 3 x 4 int16 needs 24 - at `$.patches[0]`",
    ),
    ("blobs-patches", _set("patches[0].top", -1), "Expected `int` >= 0 - at `$.patches[0].top`"),
    (
        "blobs-patches",
        _set("patches[0].filled_row", math.nan),
        "Expected `float` >= -1000000000.0 - at `$.patches[0].filled_row`",
    ),
    (
        "obstacles-measured",
        _set("obstacles[0].z_source", "guess"),
        "Invalid enum value 'guess' - at `$.obstacles[0].z_source`",
    ),
    (
        "obstacles-measured",
        _set("obstacles[0].covariance_cm2", [0.0] * 8),
        "Expected `array` of length >= 9 - at `$.obstacles[0].covariance_cm2`",
    ),
    (
        "obstacles-measured",
        _set("obstacles[0].z_sigma_cm", -0.1),
        "Expected `float` >= 0.0 - at `$.obstacles[0].z_sigma_cm`",
    ),
    (
        "blobs",
        _set("blobs[1].row", math.nan),
        "Expected `float` >= -1000000000.0 - at `$.blobs[1].row`",
    ),
    (
        "blobs",
        _set("blobs[0].col", math.inf),
        "Expected `float` <= 1000000000.0 - at `$.blobs[0].col`",
    ),
    (
        "blobs",
        _set("blobs[0].mu_rc", -math.inf),
        "Expected `float` >= -1000000000.0 - at `$.blobs[0].mu_rc`",
    ),
    ("blobs", _set("blobs[0].area_px", -1.0), "Expected `float` >= 0.0 - at `$.blobs[0].area_px`"),
    (
        "blobs",
        _set("blobs[1].compactness", math.nan),
        "Expected `float` >= 0.0 - at `$.blobs[1].compactness`",
    ),
    ("blobs", _set("blobs", {}), "Expected `array`, got `object` - at `$.blobs`"),
    ("obstacles", _drop("seq"), "Object missing required field `seq`"),
    ("obstacles", _set("robot.kind", "car"), "Invalid enum value 'car' - at `$.robot.kind`"),
    (
        "obstacles",
        _set("obstacles[1].x_cm", "12"),
        "Expected `float`, got `str` - at `$.obstacles[1].x_cm`",
    ),
    (
        "obstacles",
        _set("planner[0].obstacle_id", 2.5),
        "Expected `int`, got `float` - at `$.planner[0].obstacle_id`",
    ),
    ("obstacles", _set("obstacles", None), "Expected `array`, got `None` - at `$.obstacles`"),
    (
        "truth",
        _set("objects[0].shape", "blob"),
        "Invalid enum value 'blob' - at `$.objects[0].shape`",
    ),
    ("calibrate", _set("population", 1), "Expected `int` >= 2 - at `$.population`"),
    ("calibrate", _set("seed", -3), "Expected `int` >= 0 - at `$.seed`"),
    (
        "calibrate-reply",
        _set("parameters.k1", "x"),
        "Expected `float`, got `str` - at `$.parameters[...]`",
    ),
    (
        "calibration",
        _set("calibration.camera.s_x", -1.0),
        "Expected `float` > 0.0 - at `$.calibration.camera.s_x`",
    ),
    (
        "calibration",
        _set("calibration.dipe_mm", -1.0),
        "dipe_mm must be a finite non-negative number, got -1.0 - at `$.calibration`",
    ),
    ("status", _set("errors", [1]), "Expected `object`, got `array` - at `$.errors`"),
    ("status", _set("started_ns", -1), "Expected `int` >= 0 - at `$.started_ns`"),
    (
        "status-source-lost",
        _set("gaps[1].seconds", -4.0),
        "Expected `float` >= 0.0 - at `$.gaps[1].seconds`",
    ),
    ("source-lost", _set("state", "lost"), "Invalid enum value 'lost' - at `$.state`"),
    ("source-ok", _set("gaps", -1), "Expected `int` >= 0 - at `$.gaps`"),
]


@pytest.mark.parametrize(
    "name,mutate,reason", REFUSALS, ids=[f"{n}:{r[:40]}" for n, _, r in REFUSALS]
)
def test_wrong_schema_is_refused_with_the_exact_reason(name: str, mutate, reason: str) -> None:
    message = SAMPLES[name]
    payload = _mutated(message, mutate)
    for expected in (type(message), None):
        with pytest.raises(MessageError) as err:
            decode(payload) if expected is None else decode(payload, expected)
        assert str(err.value) == f"wrong schema: {reason}"


def test_binary_frame_bits_of_the_right_length_pass() -> None:
    payload = _mutated(SAMPLES["binary"], _set("bits", b"\xff" * 246))
    assert decode(payload, BinaryFrame).mask().all()


@pytest.mark.parametrize("payload", [b"", memoryview(b""), bytearray()])
def test_empty_payload_is_refused(payload: Any) -> None:
    with pytest.raises(MessageError) as err:
        decode(payload)
    assert str(err.value) == "empty payload"


@pytest.mark.parametrize("name", CASES)
def test_a_message_decoded_as_another_type_is_refused(name: str) -> None:
    message = SAMPLES[name]
    payload = encode(message)
    for other in MESSAGE_TYPES:
        if other is type(message):
            continue
        with pytest.raises(MessageError) as err:
            decode(payload, other)
        assert (
            str(err.value) == f"wrong schema: Invalid value '{_tag(type(message))}' - at `$.type`"
        )


@pytest.mark.parametrize(
    "wire,reason",
    [
        ({"type": "nope", "seq": 1}, "wrong schema: Invalid value 'nope' - at `$.type`"),
        ({"seq": 1}, "wrong schema: Object missing required field `type`"),
        ([1, 2, 3], "wrong schema: Expected `object`, got `array`"),
        ("obstacles", "wrong schema: Expected `object`, got `str`"),
        (None, "wrong schema: Expected `object`, got `None`"),
    ],
)
def test_untagged_or_unknown_messages_are_refused(wire: Any, reason: str) -> None:
    with pytest.raises(MessageError) as err:
        decode(msgpack.packb(wire))
    assert str(err.value) == reason


@pytest.mark.parametrize(
    "payload,reason",
    [
        (
            b"\xc1",
            "not MessagePack: MessagePack data is malformed: invalid opcode '\\xc1' (byte 0)",
        ),
        (b"\x82\xa4type", "not MessagePack: Input data was truncated"),
        (
            encode(CalibrateRequest()) + b"\x00",
            f"not MessagePack: MessagePack data is malformed: trailing characters "
            f"(byte {len(encode(CalibrateRequest()))})",
        ),
    ],
)
def test_malformed_msgpack_is_refused(payload: bytes, reason: str) -> None:
    with pytest.raises(MessageError) as err:
        decode(payload)
    assert str(err.value) == reason


def test_deeply_nested_arrays_are_refused() -> None:
    with pytest.raises(MessageError) as err:
        decode(b"\x91" * 100_000)  # [[[[…]]]]: refused at the first level
    assert str(err.value) == "wrong schema: Expected `object`, got `array`"


@pytest.mark.parametrize(
    "payload",
    [
        b"\x81\xa4type\xa2\x80\x80",  # the tag
        msgpack.packb(
            {"type": "status", "service": "x", "pid": 1, "host": "h", "started_ns": 0, "state": ""}
        ).replace(b"\xa1x", b"\xa1\x80"),  # a str field
    ],
    ids=["tag", "field"],
)
def test_invalid_utf8_is_refused_as_message_error(payload: bytes) -> None:
    with pytest.raises(MessageError):
        decode(payload)


@pytest.mark.parametrize(
    "payload",
    [
        b"\x82\xa4type\xa9calibrate\xa1x" + b"\x91" * 1000 + b"\xc0",
        b"\x81\xa1a" * 1000 + b"\xc0",
    ],
    ids=["unknown-field", "maps"],
)
def test_deep_nesting_is_refused_as_message_error(payload: bytes) -> None:
    with pytest.raises(MessageError):
        decode(payload)


# --- property tests -----------------------------------------------------------------------
INT64 = st.integers(-(2**63), 2**63 - 1)
UINT = st.integers(0, 2**64 - 1)
REAL = st.floats(allow_nan=False)  # ±inf round-trips; NaN never equals itself
TEXT = st.text(max_size=20)
FINITE = st.floats(-1e9, 1e9)
NON_NEG = st.floats(0.0, 1e12)

ID = st.integers(0, 2**63 - 1)
COORD = st.floats(-1e12, 1e12)
SIZE = st.floats(0.0, 1e12)
detected_objects = st.builds(
    DetectedObject,
    id=ID,
    kind=st.sampled_from(["robot", "obstacle"]),
    row=COORD,
    col=COORD,
    area_px=SIZE,
    perimeter_px=SIZE,
    compactness=SIZE,
    x_cm=COORD,
    y_cm=COORD,
    z_cm=COORD,
    radius_cm=SIZE,
    area_cm2=SIZE,
    heading_deg=st.none() | COORD,
    elongation=SIZE,
    vx_cm_s=COORD,
    vy_cm_s=COORD,
    heading_resolved=st.booleans(),
)
planner_entries = st.builds(
    PlannerEntry,
    obstacle_id=ID,
    distance_cm=COORD,
    angle_deg=st.floats(-180.0, 180.0, exclude_min=True),
)
obstacle_frames = st.builds(
    ObstacleFrame,
    seq=UINT,
    stamp_ns=UINT,
    published_ns=UINT,
    frame_age_ms=FINITE,
    calibration_version=st.integers(0, 2**63 - 1),
    robot=st.none() | detected_objects,
    obstacles=st.lists(detected_objects, max_size=6),
    planner=st.lists(planner_entries, max_size=6),
    arena=TEXT,
)
blob_measures = st.builds(
    BlobMeasure,
    row=FINITE,
    col=FINITE,
    area_px=NON_NEG,
    perimeter_px=NON_NEG,
    compactness=NON_NEG,
    mu_rr=NON_NEG,
    mu_cc=NON_NEG,
    mu_rc=FINITE,
)
blob_lists = st.builds(
    BlobList,
    seq=UINT,
    stamp_ns=UINT,
    rows=st.integers(1, MAX_IMAGE_SIDE),
    cols=st.integers(1, MAX_IMAGE_SIDE),
    calibration_version=UINT,
    blobs=st.lists(blob_measures, max_size=8),
)


@settings(max_examples=150, deadline=None)
@given(message=obstacle_frames | blob_lists)
def test_random_valid_messages_round_trip_exactly(message: Any) -> None:
    payload = encode(message)
    assert decode(payload, type(message)) == message
    assert decode(payload) == message
    wire = msgpack.unpackb(payload, raw=False)
    assert wire == {"type": _tag(type(message)), **_builtins(message)}
    assert decode(msgpack.packb(wire, use_bin_type=True)) == message


def _assert_decodes_or_refuses(payload: bytes) -> None:
    for expected in (None, ObstacleFrame, Frame, CalibrateRequest):
        try:
            out = decode(payload) if expected is None else decode(payload, expected)
        except MessageError as exc:
            assert str(exc)  # a reason, always
        else:
            assert isinstance(out, tuple(MESSAGE_TYPES))


@settings(max_examples=400, deadline=None)
@given(payload=st.binary(max_size=200))
def test_random_bytes_never_raise_anything_but_message_error(payload: bytes) -> None:
    _assert_decodes_or_refuses(payload)


_scalars = (
    st.none()
    | st.booleans()
    | INT64
    | st.floats()
    | TEXT
    | st.binary(max_size=8)
    | st.sampled_from([_tag(c) for c in MESSAGE_TYPES])
)
_keys = (
    st.sampled_from(
        ["type", "seq", "rows", "cols", "data", "bits", "robot", "obstacles", "planner", "blobs"]
    )
    | TEXT
)
_msgpack_values = st.recursive(
    _scalars,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(_keys, inner, max_size=6),
    max_leaves=30,
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    value=st.fixed_dictionaries(
        {"type": st.sampled_from([_tag(c) for c in MESSAGE_TYPES])},
        optional={
            k: _msgpack_values for k in ["seq", "rows", "cols", "data", "obstacles", "blobs"]
        },
    )
    | _msgpack_values
)
def test_random_msgpack_structures_never_raise_anything_but_message_error(value: Any) -> None:
    _assert_decodes_or_refuses(msgpack.packb(value, use_bin_type=True))


@settings(max_examples=300, deadline=None)
@given(
    name=st.sampled_from(CASES),
    cut=st.integers(0, 10**6),
    flips=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), max_size=4),
)
def test_damaged_valid_payloads_never_raise_anything_but_message_error(
    name: str, cut: int, flips: list[tuple[int, int]]
) -> None:
    payload = bytearray(encode(SAMPLES[name]))
    for at, value in flips:
        payload[at % len(payload)] = value
    _assert_decodes_or_refuses(bytes(payload[: max(1, cut % (len(payload) + 1))]))


# --- key expressions ------------------------------------------------------------------------
def test_topics_of_an_arena() -> None:
    t = Topics("lab-2")
    assert (t.arena, t.root) == ("lab-2", "ovis/lab-2")
    assert t.obstacles == "ovis/lab-2/obstacles"
    assert t.frames == "ovis/lab-2/frames"
    assert t.binary == "ovis/lab-2/binary"
    assert t.blobs == "ovis/lab-2/blobs"
    assert t.truth == "ovis/lab-2/truth"
    assert t.calibration == "ovis/lab-2/calibration"
    assert t.calibrate == "ovis/lab-2/calibrate"
    assert t.status("pose") == "ovis/lab-2/status/pose"
    assert t.alive("pose") == "ovis/lab-2/alive/pose"
    assert t.source == "ovis/lab-2/source"
    assert t.status_all == "ovis/lab-2/status/*"
    assert t.alive_all == "ovis/lab-2/alive/*"


def test_default_arena() -> None:
    t = Topics()
    assert t.arena == "default"
    assert t.obstacles == "ovis/default/obstacles"
    assert t.calibrate == "ovis/default/calibrate"


@pytest.mark.parametrize("arena", ["default", "lab-2", "arena_1.b", "A", "x" * 64])
def test_topics_are_valid_zenoh_key_expressions(arena: str) -> None:
    t = Topics(arena)
    keys = [t.frames, t.binary, t.blobs, t.obstacles, t.truth, t.calibration, t.calibrate]
    for key in [*keys, t.status("pose"), t.alive("pose"), t.status_all, t.alive_all]:
        assert str(zenoh.KeyExpr(key)) == key
    assert zenoh.KeyExpr(t.status_all).intersects(zenoh.KeyExpr(t.status("label")))
    assert zenoh.KeyExpr(t.alive_all).includes(zenoh.KeyExpr(t.alive("capture")))
    assert not zenoh.KeyExpr(t.alive_all).intersects(zenoh.KeyExpr(Topics("other").alive("x")))


@pytest.mark.parametrize(
    "arena",
    ["", "a/b", "*", "**", "a b", "x" * 65, "$x", "a?b", "a#b", "ovis/x", "é", "a*", " default"],
)
def test_bad_arena_names_are_refused(arena: str) -> None:
    with pytest.raises(ValueError) as err:
        Topics(arena)
    assert str(err.value) == (
        f"arena name {arena!r} must be 1-64 letters, digits, '_', '.' or '-' "
        "(it becomes a Zenoh key chunk)"
    )


def test_arena_name_with_a_trailing_newline_is_refused() -> None:
    with pytest.raises(ValueError):
        Topics("default\n")


def test_encoding_is_msgpack() -> None:
    assert ENCODING == "application/msgpack"
    assert str(zenoh.Encoding(ENCODING)) == ENCODING


# --- JSON Schema ----------------------------------------------------------------------------
def test_message_schema_describes_every_message() -> None:
    schema = message_schema()
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    defs = schema["$defs"]
    names = {c.__name__ for c in MESSAGE_TYPES}
    nested = {"BlobMeasure", "DetectedObject", "PlannerEntry", "SimObject", "Calibration"}
    assert names | nested <= set(defs)
    assert [r["$ref"] for r in schema["anyOf"]] == [f"#/$defs/{c.__name__}" for c in MESSAGE_TYPES]
    assert schema["discriminator"]["propertyName"] == "type"
    assert schema["discriminator"]["mapping"] == {
        _tag(c): f"#/$defs/{c.__name__}" for c in MESSAGE_TYPES
    }
    for cls in MESSAGE_TYPES:
        d = defs[cls.__name__]
        assert d["type"] == "object"
        assert d["properties"]["type"] == {"enum": [_tag(cls)]}
        assert set(d["properties"]) == {"type", *cls.__struct_fields__}
        assert "type" in d["required"]
    obstacle = defs["ObstacleFrame"]["properties"]
    assert obstacle["seq"] == {"type": "integer", "minimum": 0}
    assert obstacle["obstacles"]["items"] == {"$ref": "#/$defs/DetectedObject"}
    assert defs["BlobMeasure"]["properties"]["row"] == {
        "type": "number",
        "minimum": -1e9,
        "maximum": 1e9,
    }


def test_ovis_schema_prints_message_schema() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "ovis.services.cli", "schema"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == json.loads(msgspec.json.encode(message_schema()))


@pytest.mark.parametrize(
    "path,value,needle",
    [
        (("planner", 0, "distance_cm"), float("nan"), "at `$.planner[0].distance_cm`"),
        (("obstacles", 0, "x_cm"), float("inf"), "at `$.obstacles[0].x_cm`"),
        (("calibration_version",), -1, "Expected `int` >= 0 - at `$.calibration_version`"),
        (("frame_age_ms",), float("nan"), "at `$.frame_age_ms`"),
    ],
)
def test_obstacle_frame_refuses_non_finite_numbers(path, value, needle) -> None:
    obj = DetectedObject(
        id=1,
        kind="obstacle",
        row=1,
        col=1,
        area_px=1,
        perimeter_px=1,
        compactness=1,
        x_cm=1,
        y_cm=1,
        z_cm=7,
        radius_cm=1,
        area_cm2=3,
    )
    frame = ObstacleFrame(
        seq=1,
        stamp_ns=1,
        published_ns=2,
        frame_age_ms=1.0,
        calibration_version=1,
        robot=None,
        obstacles=[obj],
        planner=[PlannerEntry(obstacle_id=1, distance_cm=3.0, angle_deg=10.0)],
    )
    data = msgspec.to_builtins(frame)
    target = data
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    with pytest.raises(MessageError) as err:
        decode(msgspec.msgpack.encode(data), ObstacleFrame)
    assert needle in str(err.value)


def test_blob_list_carries_the_label_services_floor_maps_and_refuses_ragged_ones() -> None:
    from ovis.common.config import load_config
    from ovis.common.sim.arena import Arena
    from ovis.common.world.detection import (
        Detector,
        binarize_frame,
        find_blobs,
        measure_blobs_and_maps,
    )

    cfg = load_config()
    frame, _ = Arena(cfg, 4).render()
    binary = binarize_frame(frame, cfg.image, cfg.camera)
    planes = (cfg.pose.obstacle_height_cm, cfg.pose.robot_height_cm)
    blobs, (floor, top) = measure_blobs_and_maps(binary, cfg.image, cfg.camera, planes)
    assert blobs.area_px.size >= 2
    maps = FloorMaps(obstacle=PlaneMap.of(floor), robot=PlaneMap.of(top))
    msg = BlobList(
        seq=1,
        stamp_ns=2,
        rows=480,
        cols=640,
        calibration_version=1,
        blobs=BlobList.measures(blobs),
        maps=maps,
    )
    back = decode(encode(msg), BlobList)
    for sent, got in ((floor, back.maps.obstacle.jacobian()), (top, back.maps.robot.jacobian())):
        for a, b in zip(sent, got, strict=True):
            np.testing.assert_array_equal(a, b)
    # The pose from the shipped maps is the pose from its own back-projection.
    with_maps = Detector(cfg.camera, cfg.image, cfg.pose).from_blobs(
        back.to_blobs(), floor=back.maps.obstacle.jacobian(), top=back.maps.robot.jacobian()
    )
    alone = Detector(cfg.camera, cfg.image, cfg.pose).from_blobs(
        find_blobs(frame, cfg.image, cfg.camera, cfg.pose.obstacle_height_cm)
    )
    assert with_maps == alone
    # A map column one short, or a NaN in it, is refused like any malformed message.
    ragged = msgspec.to_builtins(msg)
    ragged["maps"]["robot"]["x_cm"] = ragged["maps"]["robot"]["x_cm"][:-1]
    with pytest.raises(MessageError, match="one entry per blob"):
        decode(msgspec.msgpack.encode(ragged), BlobList)
    bad = msgspec.to_builtins(msg)
    bad["maps"]["obstacle"]["y_cm"][0] = float("nan")
    with pytest.raises(MessageError, match=r"\$\.maps\.obstacle\.y_cm"):
        decode(msgspec.msgpack.encode(bad), BlobList)


def test_an_obstacle_frame_with_robots_still_decodes_with_the_earlier_schema() -> None:
    """A subscriber built on the schema before marked robots (no robots fields) reads
    today's message: the new fields are extra map keys, the old ones unchanged."""
    from ovis.common.messages import ObstacleFrame, message_schema
    from ovis.common.world.robots import RobotState

    class EarlierObstacleFrame(msgspec.Struct, tag_field="type", tag="obstacles", kw_only=True):
        seq: int
        stamp_ns: int
        published_ns: int
        frame_age_ms: float
        calibration_version: int
        robot: dict | None
        obstacles: list[dict]
        planner: list[dict]
        arena: str = "default"

    robot = RobotState(id=3, name="c", marker_id=4, x_cm=1.0, y_cm=2.0, z_cm=5.0,
                       heading_deg=-90.0, vx_cm_s=1.0, vy_cm_s=0.0, yaw_rate_deg_s=0.0,
                       age_s=0.1, radius_cm=9.0)  # fmt: skip
    new = ObstacleFrame(
        seq=5, stamp_ns=7, published_ns=8, frame_age_ms=1.0, calibration_version=2,
        robot=None, obstacles=[], planner=[], robots=[robot],
    )  # fmt: skip
    old = msgspec.msgpack.decode(encode(new), type=EarlierObstacleFrame)
    assert (old.seq, old.calibration_version, old.robot, old.obstacles) == (5, 2, None, [])
    assert decode(encode(new), ObstacleFrame).robots == [robot]
    defs = message_schema()["$defs"]
    assert {"robots", "robot_plans", "unknown_markers"} <= set(defs["ObstacleFrame"]["properties"])
    assert {"heading_deg", "age_s", "vx_cm_s"} <= set(defs["RobotState"]["properties"])


def test_blob_patches_carry_the_signed_difference_and_the_filled_blob() -> None:
    """A patch travels as int16 (shadows are darker than the floor: negative) and comes
    back as the same array; the filled centroids become the blobs' ``filled``."""
    msg = decode(encode(SAMPLES["blobs-patches"]), BlobList)
    (patch,) = msg.blob_patches()
    expected = np.arange(-6, 6, dtype=np.int16).reshape(3, 4) * 40
    np.testing.assert_array_equal(patch.diff, expected)
    assert (patch.top, patch.left) == (4, 17)
    blobs = msg.to_blobs()
    np.testing.assert_array_equal(blobs.filled, [[310.0, 10.75, 20.0]])
    assert SAMPLES["blobs"].to_blobs().filled is None
    gray = decode(encode(SAMPLES["binary-gray"]), BinaryFrame).gray_image()
    np.testing.assert_array_equal(gray, _mask() * 200)


def test_decoders_are_built_at_import_and_once_when_threads_race(monkeypatch) -> None:
    """msgspec works out a class's decoding when a decoder is first built, and two
    threads doing so at once crashed a process (a segmentation fault in `ovis up
    --cameras`' scorer): every message's decoder is built at import, any other once."""
    import threading

    import ovis.common.messages as messages

    assert all(tp in messages._DECODERS for tp in (messages.Message, *messages.Message.__args__))
    built = []
    real = msgspec.msgpack.Decoder
    gate = threading.Barrier(8)

    def counting(tp):
        built.append(tp)
        return real(tp)

    monkeypatch.setattr(msgspec.msgpack, "Decoder", counting)
    expected = list[messages.TruthFrame]  # a type no decoder exists for yet
    monkeypatch.delitem(messages._DECODERS, expected, raising=False)
    payload = msgspec.msgpack.encode([])
    results = []

    def first_use() -> None:
        gate.wait()
        results.append(messages.decode(payload, expected))

    threads = [threading.Thread(target=first_use) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert results == [[]] * 8 and built == [expected]
