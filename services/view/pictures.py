"""The newest frame of an arena as JPEG pictures for the browser: the camera frame with
the detections of the same frame drawn on it (every robot labelled, with its heading;
the calibration's control points only on the calibration's own frame), and the
binarised frame; each with how current it is."""

from __future__ import annotations

import time

import msgspec

from ovis.common.messages import BinaryFrame, BlobList, Frame, MessageError, decode
from ovis.common.view.freshness import Freshness, freshness
from ovis.common.view.pairing import frame_to_draw
from ovis.common.view.picture import (
    binary_image,
    calibration_frame,
    control_points,
    downscale,
    draw_overlay,
    object_marks,
    to_jpeg,
)
from ovis.common.view.scene import scene_objects
from ovis.services.view.feed import KEEP, ArenaFeed

__all__ = ["KINDS", "DrawnRobot", "Picture", "make_pictures"]

KINDS = ("camera", "binary")


class DrawnRobot(msgspec.Struct, kw_only=True):
    """A robot labelled on the picture: its label and where (picture pixels), and
    whether its heading arrow is drawn."""

    label: str
    x: float
    y: float
    arrow: bool


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
    fresh: Freshness | None = None
    robots: list[DrawnRobot] = []
    #: control points drawn: only on the calibration's own frame
    points: int = 0
    calibration_frame: int | None = None
    calibration_version: int = 0
    #: the camera frame's detections are drawn (False: they had not come when waiting
    #: no longer helped, :func:`~ovis.common.view.pairing.frame_to_draw`)
    detected: bool = True


def _pick(feed: ArenaFeed, kind: str):
    """The newest frame (or binary frame) whose detections have arrived; for the camera,
    none while they may still come (:func:`frame_to_draw`), for the binarised frame
    (nothing drawn on it) the newest; with its obstacle message and blobs (copied under
    the lock)."""
    with feed.lock:
        store = feed.frames if kind == "camera" else feed.binaries
        if not store:
            return None
        kept = [(s, item[1].received_s) for s, item in store.items()]
        # a binarised frame has nothing drawn on it: never waited for
        never_wait = kind != "camera" or len(kept) >= KEEP
        chosen = frame_to_draw(kept, feed.obstacles, time.monotonic(), full=never_wait)
        if chosen is None:
            return None
        seq = chosen[0]
        blobs = feed.blobs.get(seq)
        return (
            seq,
            store[seq],
            feed.obstacles.get(seq),
            None if blobs is None else blobs[0],
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
        seq, (payload, seen), obstacles, blobs_payload, calib = picked
        last[kind] = seq
        try:
            msg = decode(payload, Frame if kind == "camera" else BinaryFrame)
        except MessageError as exc:
            feed.refuse("frame" if kind == "camera" else "binary", exc)
            continue
        fresh = freshness(seen, time.time_ns(), time.monotonic())
        extra: dict = {}
        if kind == "binary":
            small, scale = downscale(binary_image(msg), max_side)
        else:
            small, scale = downscale(msg.image(), max_side)
            camera = calib.camera if calib is not None else None
            marks = object_marks(scene_objects(obstacles) if obstacles else [], camera)
            blobs = []
            if blobs_payload is not None:
                try:
                    blobs = decode(blobs_payload, BlobList).blobs
                except MessageError as exc:
                    feed.refuse("blobs", exc)
            points = control_points(calib, seq)
            small = draw_overlay(small, scale, marks=marks, blobs=blobs, points=points)
            extra = {
                "detected": obstacles is not None,
                "objects": len(marks),
                "robots": [
                    DrawnRobot(
                        label=m.label, x=m.col * scale, y=m.row * scale, arrow=m.tip is not None
                    )
                    for m in marks
                    if m.kind == "robot"
                ],
                "points": len(points),
                "calibration_frame": calibration_frame(calib),
                "calibration_version": calib.version if calib is not None else 0,
            }
        out.append(
            Picture(
                arena=feed.arena,
                kind=kind,
                seq=seq,
                stamp_ns=msg.stamp_ns,
                width=small.shape[1],
                height=small.shape[0],
                scale=scale,
                jpeg=to_jpeg(small, quality),
                fresh=fresh,
                **extra,
            )
        )
    return out
