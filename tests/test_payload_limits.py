"""ovis.common.pipeline.limits: how large each message may be for a camera, and a
frame's payload against its own header (what the calibrator keeps unread)."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest

from ovis.common.config import PinholeParams
from ovis.common.messages import Frame, FrameHeader, decode, encode
from ovis.common.pipeline.limits import (
    HEADER_BYTES,
    MAX_PAYLOAD_BYTES,
    SMALL_BYTES,
    PayloadLimits,
    frame_payload_problem,
    oversized,
)

POSE = {"rvec": [0.0, 0.0, 0.0], "tvec_cm": [0.0, 0.0, 100.0]}
CAMERA = PinholeParams(rows=480, cols=640, fx=500.0, fy=500.0, cx=320.0, cy=240.0, **POSE)


def _frame(rows: int = 480, cols: int = 640, channels: int = 1) -> bytes:
    shape = (rows, cols) if channels == 1 else (rows, cols, 3)
    image = np.full(shape, 7, np.uint8)
    return encode(Frame.from_image(image, seq=3, stamp_ns=1, source="camera:0", stream="ab"))


def test_a_grey_and_a_colour_frame_fit_a_30_mb_one_does_not() -> None:
    limits = PayloadLimits.of(CAMERA)
    assert limits.frame == 3 * 640 * 480 + HEADER_BYTES
    assert len(_frame()) <= limits.frame and len(_frame(channels=3)) <= limits.frame
    assert oversized(len(_frame(channels=3)), "frame", "frame", CAMERA) is None
    problem = oversized(30 << 20, "frame", "frame", CAMERA)
    assert problem == (
        f"refused a {30 << 20}-byte frame message unread: a frame is at most "
        f"{limits.frame} bytes with the 640x480 camera"
    )
    assert oversized(SMALL_BYTES + 1, "small", "truth", CAMERA) is not None
    assert oversized(SMALL_BYTES, "small", "truth", CAMERA) is None


def test_no_camera_known_means_the_hard_cap() -> None:
    limits = PayloadLimits.of(None)
    assert limits == (MAX_PAYLOAD_BYTES, MAX_PAYLOAD_BYTES, MAX_PAYLOAD_BYTES, SMALL_BYTES)
    huge = PinholeParams(rows=20000, cols=20000, fx=1.0, fy=1.0, cx=0.0, cy=0.0, **POSE)
    assert max(PayloadLimits.of(huge)) == MAX_PAYLOAD_BYTES
    assert "camera" not in oversized(MAX_PAYLOAD_BYTES + 1, "frame", "frame", None)


@pytest.mark.parametrize("channels", [1, 3])
def test_a_genuine_frame_is_kept(channels: int) -> None:
    payload = _frame(channels=channels)
    header = decode(payload, FrameHeader)
    assert header.channels == channels
    assert frame_payload_problem(header, len(payload), CAMERA) is None


def test_a_frame_with_more_or_fewer_bytes_than_its_header_says_is_not_kept() -> None:
    payload = _frame()
    header = decode(payload, FrameHeader)
    assert frame_payload_problem(header, 30 << 20, CAMERA) == (
        f"frame 3 declares 640x480x1 = 307200 bytes of image, its message holds {30 << 20}"
    )
    assert "holds 1000" in frame_payload_problem(header, 1000, CAMERA)


def test_a_frame_of_another_size_than_the_camera_is_not_kept() -> None:
    payload = _frame(rows=48, cols=64)
    header = decode(payload, FrameHeader)
    problem = frame_payload_problem(header, len(payload), CAMERA)
    assert problem == "frame 3 is 64x48, the camera is configured for 640x480"


def test_limits_are_worked_out_once_per_camera_size() -> None:
    """Every message is checked against its camera's limits: the same size (another pose,
    a recalibration) gives the same limits without working them out again; another size
    its own."""
    moved = msgspec.structs.replace(CAMERA, tvec_cm=(5.0, 0.0, 150.0))
    assert PayloadLimits.of(moved) is PayloadLimits.of(CAMERA)
    wider = msgspec.structs.replace(CAMERA, cols=1280, rows=960)
    assert PayloadLimits.of(wider).frame == 3 * 1280 * 960 + HEADER_BYTES
