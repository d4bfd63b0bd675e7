"""MCAP files written by other tools (common/recording/foreign.py): image channels found,
chosen, and decoded into the pixels of the real photos, bit for bit; what ovis cannot
read is refused with what it reads."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from foreign_mcap import (
    COMPRESSED_IMAGE_JSONSCHEMA,
    FLAVOURS,
    RAW_IMAGE_JSONSCHEMA,
    ForeignMcap,
    no_image_channel,
    png,
    raw_fields,
    two_image_channels,
    write_photos,
)
from real_photos import photo_bytes_and_pixels, photo_paths

from ovis.common.messages import Frame, decode, encode
from ovis.common.recording.foreign import (
    ForeignError,
    ForeignFrames,
    choose_channel,
    compressed_pixels,
    first_image,
    frame_size,
    list_channels,
    raw_pixels,
)
from ovis.common.recording.session import SessionReader, SessionWriter

T0 = 1_700_000_000_000_000_000
PERIOD = 100_000_000  # between two photos' log times


@pytest.fixture(scope="module")
def photos() -> list[tuple[bytes, np.ndarray]]:
    """The first four photos: their JPEG bytes and their pixels as OpenCV decodes them."""
    return photo_bytes_and_pixels(photo_paths()[:4])


@pytest.mark.parametrize("name", list(FLAVOURS))
def test_every_flavour_gives_the_photos_pixels_as_frames(tmp_path: Path, photos, name) -> None:
    path = tmp_path / "other.mcap"
    expected = write_photos(path, photos, name, T0, PERIOD)
    info = choose_channel(path)
    assert info is not None and info.topic == "/camera/image" and info.messages == len(photos)
    frames = ForeignFrames(path, info, "ovis/default/frames", stream="s1")
    out = [(log_ns, key, decode(make(), Frame)) for log_ns, key, make in frames.messages(
        SessionReader(path))]  # fmt: skip
    assert len(out) == len(photos)
    for k, (log_ns, key, frame) in enumerate(out):
        assert key == "ovis/default/frames"
        assert log_ns == frame.stamp_ns == T0 + k * PERIOD  # the log time, paced by
        assert frame.seq == k and frame.stream == "s1"
        assert frame.source == f"{path} /camera/image"
        assert (frame.rows, frame.cols) == (512, 640)
        assert np.array_equal(frame.image(), expected[k])  # bit for bit
    assert np.array_equal(first_image(path, info), expected[0])


def test_the_json_messages_written_are_valid_per_foxgloves_schemas(tmp_path: Path, photos) -> None:
    """The test files are what Foxglove's tools write: each JSON message validates against
    the schema text it is recorded with."""
    path = tmp_path / "json.mcap"
    out = ForeignMcap(path)
    jpeg, pixels = photos[0]
    out.message("/c", "json", "compressed", T0, data=jpeg, format="jpeg")
    out.message("/r", "json", "raw", T0, **raw_fields(pixels, "mono8"))
    out.close()
    schemas = {"/c": COMPRESSED_IMAGE_JSONSCHEMA, "/r": RAW_IMAGE_JSONSCHEMA}
    recs = list(SessionReader(path))
    assert len(recs) == 2
    for rec in recs:
        assert rec.schema is not None and rec.schema.data.decode() == schemas[rec.topic]
        jsonschema.validate(json.loads(rec.data), json.loads(schemas[rec.topic]))


def _refusal(path: Path, topic: str | None = None) -> str:
    """The one line :func:`choose_channel` refuses ``path`` with."""
    with pytest.raises(ForeignError) as err:
        choose_channel(path, topic)
    assert "\n" not in str(err.value)
    return str(err.value)


def test_topic_picks_one_of_several_image_channels(tmp_path: Path, photos) -> None:
    path = tmp_path / "two.mcap"
    two_image_channels(path, photos, T0)
    text = _refusal(path)
    assert "2 image channels: pick one with --topic" in text
    assert "/left (foxglove.CompressedImage, json, 4 messages)" in text
    assert "/right (sensor_msgs/msg/Image, cdr, 4 messages)" in text
    info = choose_channel(path, "/right")
    assert info is not None and info.topic == "/right"
    assert np.array_equal(first_image(path, info), photos[0][1][::-1])
    assert "no channel '/nope'; channels found: /left (" in _refusal(path, "/nope")


def test_no_usable_channel_lists_the_channels_found(tmp_path: Path) -> None:
    path = tmp_path / "none.mcap"
    no_image_channel(path, T0)
    text = _refusal(path)
    assert "holds no image channel ovis reads (foxglove.CompressedImage or " in text
    assert "/rosout (foxglove.Log, json, 1 messages)" in text
    assert "/cam (foxglove.CompressedImage, flatbuffer, 0 messages)" in text
    assert "/raw (no schema, no encoding, 0 messages)" in text
    assert "/rosout (foxglove.Log, json, 1 messages) of " in _refusal(path, "/rosout")
    assert "is not an image channel ovis reads" in _refusal(path, "/rosout")


def test_an_ovis_recording_is_replayed_as_it_is(tmp_path: Path, photos) -> None:
    path = tmp_path / "ovis.mcap"
    writer = SessionWriter(path)
    writer.view("/ovis/default/image", "foxglove.CompressedImage", _view(photos[0][0]), T0, T0)
    writer.bus("ovis/default/health", b"\x80", T0, T0)
    writer.close()
    assert choose_channel(path) is None  # its bus channels go out as recorded
    info = choose_channel(path, "/ovis/default/image")  # its camera view, on request
    assert info is not None
    assert np.array_equal(first_image(path, info), photos[0][1])


def _view(jpeg: bytes) -> object:
    from ovis.common.recording.foxglove import CompressedImage, Time

    return CompressedImage(Time.of_ns(T0), "camera", jpeg, "jpeg")


def test_a_file_cut_short_lists_its_channels_by_reading_it(tmp_path: Path, photos) -> None:
    whole = tmp_path / "whole.mcap"
    out = ForeignMcap(whole, chunk_size=1)  # a chunk per message
    for k, (jpeg, _) in enumerate(photos):
        out.message("/cam", "json", "compressed", T0 + k, data=jpeg, format="jpeg")
    out.close()
    cut = tmp_path / "cut.mcap"
    data = whole.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.8)])
    (info,) = list_channels(cut)
    assert info.topic == "/cam" and 1 <= info.messages < len(photos)
    assert np.array_equal(first_image(cut, info), photos[0][1])


def test_compressed_formats() -> None:
    grey = (np.arange(48 * 64) % 251).astype(np.uint8).reshape(48, 64)
    bgra = np.dstack([grey, 255 - grey, grey // 2, np.full_like(grey, 7)])
    assert np.array_equal(compressed_pixels(png(bgra), "png"), bgra[:, :, :3])
    wide = grey.astype(np.uint16) * 257
    assert np.array_equal(compressed_pixels(png(wide), "png"), grey)  # the high byte
    for fmt in ("webp", "16UC1; compressedDepth png", ""):
        with pytest.raises(ForeignError, match="ovis reads raw mono8, bgr8 or rgb8"):
            compressed_pixels(png(grey), fmt)
    for data in (b"\xff\xd8 not a jpeg", b""):
        with pytest.raises(ForeignError, match="a jpeg image does not decode"):
            compressed_pixels(data, "jpeg")


def test_raw_encodings() -> None:
    bgr = (np.arange(4 * 5 * 3) * 7 % 256).astype(np.uint8).reshape(4, 5, 3)
    rgb = bgr[:, :, ::-1].tobytes()
    assert np.array_equal(raw_pixels(5, 4, "rgb8", 15, rgb), bgr)
    assert np.array_equal(raw_pixels(5, 4, "bgr8", 0, bgr.tobytes()), bgr)  # step 0: packed
    assert np.array_equal(raw_pixels(5, 4, "8UC3", 15, bgr.tobytes()), bgr)
    f = raw_fields(bgr[:, :, 0].copy(), "mono8", pad=3)
    assert f["step"] == 8
    assert np.array_equal(raw_pixels(5, 4, "8UC1", 8, f["data"]), bgr[:, :, 0])
    for enc in ("mono16", "16UC1", "bayer_rggb8", "yuv422", "32FC1", "rgba8"):
        with pytest.raises(ForeignError, match=rf"raw image encoding '{enc}' is not supported: "
                           "ovis reads raw mono8, bgr8 or rgb8"):  # fmt: skip
            raw_pixels(5, 4, enc, 40, bytes(160))
    with pytest.raises(ForeignError, match="holds 59 bytes: it needs rows of at least 15"):
        raw_pixels(5, 4, "rgb8", 15, rgb[:59])
    with pytest.raises(ForeignError, match="rows of at least 15 bytes"):
        raw_pixels(5, 4, "rgb8", 10, rgb)
    with pytest.raises(ForeignError, match="each side must be 1 to"):
        raw_pixels(0, 4, "mono8", 0, b"")


def test_a_damaged_message_is_refused_with_the_reason(tmp_path: Path, photos) -> None:
    path = tmp_path / "bad.mcap"
    out = ForeignMcap(path)
    out.message("/cam", "cdr", "raw", T0, **raw_fields(photos[0][1], "mono16"))
    out.message("/cam", "cdr", "raw", T0 + 1, **raw_fields(photos[1][1], "mono8"))
    out.close()
    info = choose_channel(path)
    assert info is not None
    with pytest.raises(ForeignError, match="raw image encoding 'mono16' is not supported"):
        first_image(path, info)
    made = [make for _, _, make in ForeignFrames(path, info, "k").messages(SessionReader(path))]
    with pytest.raises(ForeignError, match="mono16"):
        made[0]()
    assert np.array_equal(decode(made[1](), Frame).image(), photos[1][1])
    # a message that is not CDR at all
    with pytest.raises(ForeignError, match=r"not a valid sensor_msgs/msg/Image \(cdr\)"):
        ForeignFrames(path, info, "k").decoder(b"\x00\x01garbage")


def test_frame_size_of_any_recording(tmp_path: Path, photos) -> None:
    """The size `ovis up --calibration` checks: a foreign file's first image, an ovis
    recording's first frame (None without frames)."""
    other = tmp_path / "other.mcap"
    write_photos(other, photos, "foxglove protobuf png", T0, PERIOD)
    assert frame_size(other) == (640, 512)
    ours = tmp_path / "ours.mcap"
    writer = SessionWriter(ours)
    writer.frame("ovis/default/frames", encode(Frame.from_image(photos[0][1][:100], seq=0,
                 stamp_ns=T0)), T0, T0)  # fmt: skip
    writer.close()
    assert frame_size(ours) == (640, 100)
    empty = tmp_path / "empty.mcap"
    writer = SessionWriter(empty)
    writer.bus("ovis/default/health", b"\x80", T0, T0)
    writer.close()
    assert frame_size(empty) is None
