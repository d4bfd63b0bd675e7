"""The newest frame of an arena as JPEG pictures for the browser: the camera frame with
the detections of the same frame drawn on it, and the binarised frame."""

from __future__ import annotations

import msgspec

from ovis.common.messages import BinaryFrame, BlobList, Frame, MessageError, decode
from ovis.common.view.picture import binary_image, downscale, draw_overlay, to_jpeg
from ovis.common.view.scene import scene_objects
from ovis.services.view.feed import ArenaFeed

__all__ = ["KINDS", "Picture", "make_pictures"]

KINDS = ("camera", "binary")


class Picture(msgspec.Struct, kw_only=True):
    """A JPEG and what it shows (the header the page receives with it)."""

    type: str = "picture"
    arena: str
    kind: str
    seq: int
    stamp_ns: int
    width: int
    height: int
    scale: float
    objects: int = 0
    jpeg: bytes = b""


def _pick(feed: ArenaFeed, kind: str):
    """The newest frame (or binary frame) whose detections have arrived, else the newest;
    with its obstacle message and blobs (copied under the lock)."""
    with feed.lock:
        store = feed.frames if kind == "camera" else feed.binaries
        if not store:
            return None
        seqs = list(store)
        seq = next((s for s in reversed(seqs) if s in feed.obstacles), seqs[-1])
        return (
            seq,
            store[seq],
            feed.obstacles.get(seq),
            feed.blobs.get(seq),
            feed.calibration,
        )


def make_pictures(
    feed: ArenaFeed, kinds: set[str], max_side: int, quality: int, last: dict[str, int]
) -> list[Picture]:
    """Pictures of each of ``kinds`` whose newest usable frame is not ``last[kind]``
    (updated); a frame that fails validation is counted by the feed and skipped."""
    out = []
    for kind in kinds:
        picked = _pick(feed, kind)
        if picked is None or picked[0] == last.get(kind):
            continue
        seq, payload, obstacles, blobs_payload, calib = picked
        last[kind] = seq
        try:
            msg = decode(payload, Frame if kind == "camera" else BinaryFrame)
        except MessageError as exc:
            feed.refuse("frame" if kind == "camera" else "binary", exc)
            continue
        if kind == "binary":
            small, scale = downscale(binary_image(msg), max_side)
            n = 0
        else:
            small, scale = downscale(msg.image(), max_side)
            objects = scene_objects(obstacles) if obstacles else []
            blobs = []
            if blobs_payload is not None:
                try:
                    blobs = decode(blobs_payload, BlobList).blobs
                except MessageError as exc:
                    feed.refuse("blobs", exc)
            small = draw_overlay(
                small,
                scale,
                objects=objects,
                blobs=blobs,
                points=calib.points if calib is not None else (),
                camera=calib.camera if calib is not None else None,
            )
            n = len(objects)
        out.append(
            Picture(
                arena=feed.arena,
                kind=kind,
                seq=seq,
                stamp_ns=msg.stamp_ns,
                width=small.shape[1],
                height=small.shape[0],
                scale=scale,
                objects=n,
                jpeg=to_jpeg(small, quality),
            )
        )
    return out
