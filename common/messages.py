"""Messages between ovis services, and the key expressions they travel on.

Every message is a msgspec Struct encoded as a MessagePack **map** (field names on the
wire) with a ``type`` tag, so any language decodes it with a plain msgpack library.
Payloads are published with the Zenoh encoding ``application/msgpack``. Images travel
as raw bytes plus shape and dtype. New fields get defaults and go at the end.

Key expressions are rooted at ``ovis/<arena>/`` (see :class:`Topics`).
"""

from __future__ import annotations

import re
import threading
from typing import Annotated, Any, Literal

import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.calibration.file import Calibration
from ovis.common.camera.projection import PixelJacobian
from ovis.common.sim.arena import SimObject
from ovis.common.vision.markers import Markers
from ovis.common.vision.outline import Patch
from ovis.common.world.detection import Blobs, DetectedObject, PlannerEntry
from ovis.common.world.plans import RobotPlan
from ovis.common.world.robots import RobotState, UnknownMarker

__all__ = [
    "ENCODING",
    "IDLE_STATES",
    "MAX_IMAGE_SIDE",
    "SOURCE_LOST",
    "BinaryFrame",
    "BinaryFrameView",
    "BlobList",
    "BlobMeasure",
    "CalibrateReply",
    "CalibrateRequest",
    "CalibrationUpdate",
    "FloorMaps",
    "Frame",
    "FrameHeader",
    "FrameView",
    "MarkerCorners",
    "Message",
    "MessageError",
    "ObstacleFrame",
    "PlaneMap",
    "ReplayMark",
    "RobotCommand",
    "RobotDrive",
    "ServiceStatus",
    "SourceGap",
    "SourceState",
    "StreamHealth",
    "Topics",
    "TruthFrame",
    "WorldFrame",
    "WorldObject",
    "decode",
    "encode",
    "message_schema",
]

#: Zenoh encoding of every ovis payload.
ENCODING = "application/msgpack"
#: Largest accepted image side, pixels (refuses absurd shapes before allocating).
MAX_IMAGE_SIDE = 16384

Seq = Annotated[int, msgspec.Meta(ge=0)]
Stamp = Annotated[int, msgspec.Meta(ge=0)]
Side = Annotated[int, msgspec.Meta(ge=1, le=MAX_IMAGE_SIDE)]
Finite = Annotated[float, msgspec.Meta(ge=-1e9, le=1e9)]  # rejects NaN and ±inf too
NonNeg = Annotated[float, msgspec.Meta(ge=0.0, le=1e12)]


class MessageError(ValueError):
    """A payload that is not a valid ovis message; the text says why."""


class _Msg(msgspec.Struct, tag_field="type", kw_only=True, forbid_unknown_fields=False):
    """Base of all messages (unknown fields are ignored, so newer senders still work)."""


class Frame(_Msg, tag="frame", kw_only=True):
    """A captured image: ``rows × cols × channels`` uint8, row-major, in ``data``."""

    seq: Seq
    stamp_ns: Stamp  # capture time, ns since the Unix epoch
    rows: Side
    cols: Side
    channels: Literal[1, 3] = 1
    dtype: Literal["uint8"] = "uint8"
    data: bytes
    source: str = ""
    #: the capture's stream identity (random, new each time the capture starts): a new
    #: one means sequence numbers start again, not that frames were lost
    stream: str = ""

    def __post_init__(self) -> None:
        expected = self.rows * self.cols * self.channels
        if len(self.data) != expected:
            raise ValueError(
                f"data holds {len(self.data)} bytes but rows x cols x channels = "
                f"{self.rows} x {self.cols} x {self.channels} needs {expected}"
            )

    def image(self) -> NDArray[np.uint8]:
        """The image as a read-only array (no copy)."""
        shape = (self.rows, self.cols) if self.channels == 1 else (self.rows, self.cols, 3)
        return np.frombuffer(self.data, dtype=np.uint8).reshape(shape)

    @classmethod
    def from_image(
        cls,
        image: NDArray[np.uint8],
        *,
        seq: int,
        stamp_ns: int,
        source: str = "",
        copy: bool = True,
        stream: str = "",
    ) -> Frame:
        """A frame of ``image``. ``copy=False`` keeps a read-only view of a C-contiguous
        image instead of a copy of its bytes, for a frame that is encoded at once (capture
        publishes each frame straight away): the image must not change until then."""
        if (
            image.dtype != np.uint8
            or image.ndim not in (2, 3)
            or (image.ndim == 3 and image.shape[2] != 3)
        ):
            raise ValueError(
                f"expected a uint8 grey (H, W) or BGR (H, W, 3) image, got {image.dtype} "
                f"{image.shape}"
            )
        channels = 1 if image.ndim == 2 else image.shape[2]
        pixels = np.ascontiguousarray(image)
        data = pixels.tobytes() if copy else memoryview(pixels).toreadonly().cast("B")
        return cls(
            seq=seq,
            stamp_ns=stamp_ns,
            rows=image.shape[0],
            cols=image.shape[1],
            channels=channels,
            data=data,  # type: ignore[arg-type]  (a memoryview encodes as bytes do)
            source=source,
            stream=stream,
        )


class FrameView(Frame, tag="frame", kw_only=True):
    """A received :class:`Frame` whose ``data`` is a view of the payload it was decoded
    from (no copy of the pixels); decode-only, for the stages' hot path."""

    data: memoryview  # type: ignore[assignment]


class FrameHeader(_Msg, tag="frame", kw_only=True):
    """The small fields of a :class:`Frame` (decoding it skips the image bytes)."""

    seq: Seq
    stamp_ns: Stamp
    rows: Side
    cols: Side
    stream: str = ""
    channels: Literal[1, 3] = 1


class MarkerCorners(msgspec.Struct):
    """One decoded marker: its id and four corners (row, col, in OpenCV's order:
    top-left, top-right, bottom-right, bottom-left of the printed marker)."""

    id: Annotated[int, msgspec.Meta(ge=0)]
    corners: Annotated[list[Finite], msgspec.Meta(min_length=8, max_length=8)]

    @staticmethod
    def of(markers: Markers) -> list[MarkerCorners]:
        return [
            MarkerCorners(int(i), c.reshape(8).tolist())
            for i, c in zip(markers.ids, markers.corners, strict=True)
        ]

    @staticmethod
    def to_markers(found: list[MarkerCorners] | None, at_border: int = 0) -> Markers:
        if not found:
            return Markers(Markers.none().ids, Markers.none().corners, at_border)
        ids = np.array([m.id for m in found], dtype=np.int64)
        corners = np.array([m.corners for m in found], dtype=np.float64).reshape(-1, 4, 2)
        return Markers(ids, corners, at_border)


MarkerList = Annotated[list[MarkerCorners], msgspec.Meta(max_length=10000)]


class BinaryFrame(_Msg, tag="binary", kw_only=True):
    """A binarized frame (paper §3), one bit per pixel (``np.packbits``, row-major)."""

    seq: Seq
    stamp_ns: Stamp
    rows: Side
    cols: Side
    bits: bytes
    threshold: Annotated[int, msgspec.Meta(ge=0, le=255)]
    calibration_version: Annotated[int, msgspec.Meta(ge=0)]
    #: markers already decoded in the grey frame, passed on as they are (None: the label
    #: stage searches ``median`` for them, if given)
    markers: MarkerList | None = None
    markers_at_border: Annotated[int, msgspec.Meta(ge=0)] = 0
    stream: str = ""  # the capture's stream identity (Frame.stream)
    #: the grey frame's 3×3 median (or the grey frame itself when the markers' cells are
    #: too small for the median), one byte per pixel, row-major: sent only when marked
    #: robots are configured, for the label stage's marker search around the blobs
    median: bytes | None = None
    #: the grey frame itself, one byte per pixel, row-major: sent only when heights are
    #: measured (``[pose] heights``), for the label stage's patches of each blob (the
    #: frame less the empty floor around it, :class:`BlobPatch`)
    gray: bytes | None = None

    def __post_init__(self) -> None:
        expected = (self.rows * self.cols + 7) // 8
        if len(self.bits) != expected:
            raise ValueError(
                f"bits holds {len(self.bits)} bytes, {self.rows} x {self.cols} needs {expected}"
            )
        for name in ("median", "gray"):
            image = getattr(self, name)
            if image is not None and len(image) != self.rows * self.cols:
                raise ValueError(
                    f"{name} holds {len(image)} bytes, {self.rows} x {self.cols} needs "
                    f"{self.rows * self.cols}"
                )

    def gray_image(self) -> NDArray[np.uint8] | None:
        """``gray`` as a read-only (rows, cols) array (no copy), or None."""
        if self.gray is None:
            return None
        return np.frombuffer(self.gray, dtype=np.uint8).reshape(self.rows, self.cols)

    def median_image(self) -> NDArray[np.uint8] | None:
        """``median`` as a read-only (rows, cols) array (no copy), or None."""
        if self.median is None:
            return None
        return np.frombuffer(self.median, dtype=np.uint8).reshape(self.rows, self.cols)

    def mask(self) -> NDArray[np.uint8]:
        """The 0/1 image, (rows, cols) uint8."""
        flat = np.unpackbits(np.frombuffer(self.bits, dtype=np.uint8), count=self.rows * self.cols)
        return flat.reshape(self.rows, self.cols)


class BinaryFrameView(BinaryFrame, tag="binary", kw_only=True):
    """A received :class:`BinaryFrame` whose ``bits`` and ``median`` are views of the
    payload it was decoded from (no copy); decode-only, for the label stage."""

    bits: memoryview  # type: ignore[assignment]
    median: memoryview | None = None  # type: ignore[assignment]
    gray: memoryview | None = None  # type: ignore[assignment]


class BlobMeasure(msgspec.Struct):
    """One size-filtered blob: image measurements (pixels) and shape (the fields of
    :class:`~ovis.common.world.detection.Blobs`)."""

    row: Finite
    col: Finite
    area_px: NonNeg
    perimeter_px: NonNeg
    compactness: NonNeg
    mu_rr: NonNeg
    mu_cc: NonNeg
    mu_rc: Finite


Column = Annotated[list[Finite], msgspec.Meta(max_length=100000)]


class BlobPatch(msgspec.Struct, kw_only=True):
    """One blob's surroundings for measured heights: the frame less the empty floor
    (``D = frame − background``, grey levels) over ``rows`` × ``cols`` pixels from
    (``top``, ``left``), int16 little-endian, row-major; and the blob's area (px²) and
    centroid (row, col) with its holes filled."""

    top: Annotated[int, msgspec.Meta(ge=0, le=MAX_IMAGE_SIDE)]
    left: Annotated[int, msgspec.Meta(ge=0, le=MAX_IMAGE_SIDE)]
    rows: Side
    cols: Side
    diff: bytes
    filled_area_px: NonNeg
    filled_row: Finite
    filled_col: Finite

    def __post_init__(self) -> None:
        if len(self.diff) != 2 * self.rows * self.cols:
            raise ValueError(
                f"diff holds {len(self.diff)} bytes, {self.rows} x {self.cols} int16 needs "
                f"{2 * self.rows * self.cols}"
            )

    @classmethod
    def of(cls, patch: Patch, filled: NDArray[np.float64]) -> BlobPatch:
        rows, cols = patch.diff.shape
        return cls(
            top=patch.top,
            left=patch.left,
            rows=rows,
            cols=cols,
            diff=np.ascontiguousarray(patch.diff, dtype="<i2").tobytes(),
            filled_area_px=float(filled[0]),
            filled_row=float(filled[1]),
            filled_col=float(filled[2]),
        )

    def patch(self) -> Patch:
        diff = np.frombuffer(self.diff, dtype="<i2").reshape(self.rows, self.cols)
        return Patch(self.top, self.left, diff.astype(np.int16))


class PlaneMap(msgspec.Struct):
    """The pixel → plane map at each blob's centroid, column by column (the fields of
    :class:`~ovis.common.camera.projection.PixelJacobian`: the point in cm, cm per pixel step,
    and whether the pixel sees the plane)."""

    x_cm: Column
    y_cm: Column
    dx_drow: Column
    dy_drow: Column
    dx_dcol: Column
    dy_dcol: Column
    valid: Annotated[list[bool], msgspec.Meta(max_length=100000)]

    @classmethod
    def of(cls, j: PixelJacobian) -> PlaneMap:
        return cls(*(np.asarray(f).tolist() for f in j))

    def jacobian(self) -> PixelJacobian:
        """The map as arrays: floats, and ``valid`` as booleans even when there is no
        blob (an empty list would otherwise be a float array, and pose would fail)."""
        return PixelJacobian(
            *(
                np.array(getattr(self, f), dtype=bool if f == "valid" else np.float64)
                for f in PixelJacobian._fields
            )
        )

    def entries(self) -> int | None:
        """How many blobs the columns describe (None if they differ in length)."""
        sizes = {len(getattr(self, f)) for f in self.__struct_fields__}
        return sizes.pop() if len(sizes) == 1 else None


class FloorMaps(msgspec.Struct, kw_only=True):
    """Where the label service's back-projection put each blob: on the obstacles' top
    plane (the size filter's) and on the robot's, for the BlobList's calibration."""

    obstacle: PlaneMap
    robot: PlaneMap


class BlobList(_Msg, tag="blobs", kw_only=True):
    """The blobs of one frame after labeling and size filtering; ``maps`` (optional)
    saves the pose service a back-projection when its calibration is the same."""

    seq: Seq
    stamp_ns: Stamp
    rows: Side
    cols: Side
    calibration_version: Annotated[int, msgspec.Meta(ge=0)]
    blobs: Annotated[list[BlobMeasure], msgspec.Meta(max_length=100000)]
    maps: FloorMaps | None = None
    #: the binary frame's markers, passed on to the pose service
    markers: MarkerList | None = None
    markers_at_border: Annotated[int, msgspec.Meta(ge=0)] = 0
    stream: str = ""  # the capture's stream identity (Frame.stream)
    #: one per blob when heights are measured (``[pose] heights``): its patch of the frame
    #: less the empty floor, which the pose stage fits its solids to
    patches: Annotated[list[BlobPatch], msgspec.Meta(max_length=100000)] | None = None

    def __post_init__(self) -> None:
        if self.patches is not None and len(self.patches) != len(self.blobs):
            raise ValueError(
                f"patches must have one entry per blob ({len(self.patches)} for "
                f"{len(self.blobs)} blobs)"
            )
        if self.maps is None:
            return
        for name in ("obstacle", "robot"):
            if getattr(self.maps, name).entries() != len(self.blobs):
                raise ValueError(
                    f"maps.{name} must have one entry per blob in every column "
                    f"({len(self.blobs)} blobs)"
                )

    @staticmethod
    def measures(blobs: Blobs) -> list[BlobMeasure]:
        """One :class:`BlobMeasure` per blob of a :class:`~ovis.common.world.detection.Blobs`."""
        names = BlobMeasure.__struct_fields__  # positional, in field order: fast for many
        return list(map(BlobMeasure, *(getattr(blobs, f).tolist() for f in names)))

    def to_blobs(self) -> Blobs:
        """The blobs as (n,) arrays, what :meth:`Detector.from_blobs` takes."""
        names = BlobMeasure.__struct_fields__
        table = np.array(
            [msgspec.structs.astuple(b) for b in self.blobs], dtype=np.float64
        ).reshape(-1, len(names))
        filled = None
        if self.patches is not None:
            filled = np.array(
                [(p.filled_area_px, p.filled_row, p.filled_col) for p in self.patches],
                dtype=np.float64,
            ).reshape(-1, 3)
        return Blobs(**{f: table[:, k].copy() for k, f in enumerate(names)}, filled=filled)

    def blob_patches(self) -> list[Patch] | None:
        """The blobs' patches as arrays, or None."""
        return None if self.patches is None else [p.patch() for p in self.patches]


class ObstacleFrame(_Msg, tag="obstacles", kw_only=True):
    """What the pose service publishes on the obstacle topic, one per processed frame.

    ``robot`` is None when no blob passes the robot rule. ``frame_age_ms`` is how old the
    frame was when this was published; ``calibration_version`` which calibration made it.

    With marked robots (``[[pose.robots]]``), ``robots`` holds each robot's filtered pose,
    heading, velocity and age, ``robot_plans`` its planner inputs (obstacles and the
    other robots; angles from its goal direction and from its heading),
    ``unknown_markers`` the markers no robot carries and ``markers_at_border`` those cut
    by the image border; ``robot`` is then the first robot's blob and ``planner`` its
    entries, so a subscriber written for one robot keeps working. These fields are new
    (defaults: empty), the earlier ones unchanged.
    """

    seq: Seq
    stamp_ns: Stamp
    published_ns: Stamp
    frame_age_ms: Finite
    calibration_version: Annotated[int, msgspec.Meta(ge=0)]
    robot: DetectedObject | None
    obstacles: list[DetectedObject]
    planner: list[PlannerEntry]
    arena: str = "default"
    robots: list[RobotState] = []
    robot_plans: list[RobotPlan] = []
    unknown_markers: list[UnknownMarker] = []
    markers_at_border: Annotated[int, msgspec.Meta(ge=0)] = 0
    #: the capture's stream identity of the frame (Frame.stream): whose run it is
    stream: str = ""


class StreamHealth(_Msg, tag="health", kw_only=True):
    """Published by the pose service on ``ovis/<arena>/health`` every status period,
    whether frames flow or not, so that a consumer can tell "no obstacles" (an
    ObstacleFrame with an empty list) from "no data" (``state`` "stalled", or "source
    lost" when the capture says its source failed, with its reason)."""

    state: Literal["waiting", "ok", "stalled", "degraded", "failing", "source lost"]
    published_ns: Stamp
    last_seq: int = -1
    seconds_since_frame: float | None = None  # by the publisher's clock, since receipt
    last_frame_age_ms: float | None = None  # capture → publication of the last frame
    frames_dropped: int = 0
    calibration_version: int = 0
    reason: str = ""  # why "degraded", "failing" or "source lost"
    #: the pose stage's run (random, new at each start) and this message's number in it,
    #: so that a reader tells a replayed health message (:mod:`ovis.common.trust.order`)
    stream: str = ""
    seq: Annotated[int, msgspec.Meta(ge=0)] = 0


class SourceGap(msgspec.Struct, kw_only=True):
    """A time the capture's source delivered no frame: from ``start_ns`` (the failure),
    ``seconds`` long (so far, while ``ongoing``), and why (the first error)."""

    start_ns: Stamp
    seconds: NonNeg
    reason: str
    ongoing: bool = False


class SourceState(_Msg, tag="source", kw_only=True):
    """Published by the capture on ``ovis/<arena>/source`` when its source fails or
    delivers again, and repeated while it is lost: ``state`` "source lost" with the
    ``reason`` (the latest error; it starts with "ended" for a folder or video that
    ended with looping off, lost for good), since ``lost_ns``."""

    state: Literal["ok", "source lost"]
    published_ns: Stamp
    reason: str = ""
    lost_ns: Stamp | None = None
    ended: bool = False  # lost for good: no more attempts
    gaps: Annotated[int, msgspec.Meta(ge=0)] = 0  # losses so far, this one included


class WorldObject(msgspec.Struct, kw_only=True):
    """One object of the fused world (several cameras, :mod:`ovis.common.fusion`): its
    world identity (a robot's: its marker's robot id; an obstacle's: kept across
    hand-overs between cameras), where it stands on the shared floor (cm; with heights
    measured its footprint, else its top's centroid on its class's plane), the expected
    error of that position (``sigma_cm``, the larger axis of the merged covariance) and
    the cameras that saw it in this frame. ``z_cm`` is its top's height: where it comes
    from in ``z_source`` ("cameras": measured by two or more of them, combined by their
    information; "one camera"; else "configured" or a robot's "marker"), its 1σ in
    ``z_sigma_cm`` (None: not measured); ``disagreeing`` names the cameras whose
    measured height disagreed with the others' beyond their combined uncertainty and
    was left out (:mod:`ovis.common.fusion.merge`)."""

    id: Annotated[int, msgspec.Meta(ge=0)]
    kind: Literal["robot", "obstacle"]
    x_cm: Finite
    y_cm: Finite
    z_cm: Finite
    radius_cm: NonNeg
    sigma_cm: NonNeg
    cameras: list[str]
    marker_id: Annotated[int, msgspec.Meta(ge=0)] | None = None
    heading_deg: Finite | None = None
    z_sigma_cm: NonNeg | None = None
    z_source: Literal["configured", "marker", "one camera", "cameras"] = "configured"
    disagreeing: list[str] = []


class WorldFrame(_Msg, tag="world", kw_only=True):
    """What the fusion service publishes on ``ovis/<arena>/world``: one arena, one list
    of objects, whatever camera saw them. ``stamp_ns`` is the capture stamp of the
    world frame's first camera frame; ``cameras`` the cameras whose frames it holds,
    ``missing`` the live cameras whose frame did not come in time; ``late_frames``
    counts, per camera, the frames that came after their world frame had left."""

    seq: Seq
    stamp_ns: Stamp
    published_ns: Stamp
    arena: str
    objects: list[WorldObject]
    cameras: list[str]
    missing: list[str] = []
    late_frames: dict[str, Annotated[int, msgspec.Meta(ge=0)]] = {}
    #: the fusion service's run (random, new at each start): ``seq`` counts within it,
    #: so that a reader tells a replayed world frame (:mod:`ovis.common.trust.order`)
    stream: str = ""


class TruthFrame(_Msg, tag="truth", kw_only=True):
    """Ground truth of a simulated frame (published by the simulated capture only);
    ``stamp_ns``, its frame's capture stamp (so a world frame finds its truth)."""

    seq: Seq
    objects: list[SimObject]
    stamp_ns: Stamp | None = None


class CalibrateRequest(_Msg, tag="calibrate", kw_only=True):
    """Query payload of ``ovis/<arena>/calibrate``; every field is optional."""

    frame_seq: Seq | None = None  # default: the latest frame (simulated: with its truth)
    seed: Seq | None = None
    population: Annotated[int, msgspec.Meta(ge=2, le=10000)] | None = None
    generations: Annotated[int, msgspec.Meta(ge=1, le=10000)] | None = None
    cancel: bool = False  # cancel the calibration that runs (nothing else is done)
    force: bool = False  # publish a candidate unlike the current calibration (camera moved)


class CalibrateReply(_Msg, tag="calibrate-reply", kw_only=True):
    """Reply to a calibrate query: the new calibration's version and quality, or why not."""

    ok: bool
    version: int = 0
    frame_seq: int = -1
    dipe_px: float = 0.0
    dipe_mm: float | None = 0.0  # None: the pixel pitch is unknown
    dipe_max_px: float = 0.0
    elapsed_s: float = 0.0
    parameters: dict[str, float] = {}
    saved_to: str = ""
    error: str = ""
    busy: bool = False  # a calibration runs: this query was not started (see error)
    progress: float = 0.0  # of the running calibration, 0..1, when busy
    eta_s: float | None = None  # seconds the running calibration still needs, when busy


class CalibrationUpdate(_Msg, tag="calibration", kw_only=True):
    """A calibration, published on ``ovis/<arena>/calibration`` whenever it changes."""

    calibration: Calibration


#: The capture's state that says its source is gone (its last: it did not come back).
SOURCE_LOST = "source lost"
#: States (their beginnings) of a service not at work, not yet or no more: wrong at the
#: end of a run only for a service that handled no frame.
IDLE_STATES = ("starting", "waiting", "recording ended")


class ServiceStatus(_Msg, tag="status", kw_only=True):
    """A service's health: rates, drops and errors (answer of its status queryable)."""

    service: str
    pid: int
    host: str
    started_ns: Stamp
    state: str  # "ok", "waiting for frames", "no calibration", …
    frames_in: int = 0
    frames_out: int = 0
    fps: float = 0.0
    dropped: int = 0
    errors: dict[str, int] = {}
    last_error: str = ""
    calibration_version: int = -1
    last_frame_age_s: float | None = None
    rss_mb: float = 0.0
    restarts: int = 0  # times `ovis up` restarted this service
    reason: str = ""  # why the state is "degraded" or "failing"
    calibration_epoch: str = ""  # the calibrator's store id of the calibration in use
    seq_jumps: int = 0  # sequence jumps beyond the plausible gap (not counted as dropped)
    stream_restarts: int = 0  # times the capture's stream identity changed
    source_gaps: int = 0  # capture: times its source was lost (the current loss included)
    source_gap_s: float = 0.0  # capture: seconds without its source, in total
    gaps: list[SourceGap] = []  # capture: the latest losses, oldest first
    stream: str = ""  # the capture's stream identity of the last frame (the capture's own)
    shm_pool_bytes: int = 0  # the shared-memory pool its large messages go into (0: none)
    shm_written: int = 0  # messages written into that pool (read in place on this host)
    shm_fallbacks: int = 0  # messages sent as plain bytes instead: the pool was full


class RobotCommand(_Msg, tag="cmd", kw_only=True):
    """A velocity command for one robot, published by the planner on
    ``ovis/<arena>/robots/<id>/cmd`` with the planner's proof of origin (the robots
    refuse, and count, any other): forwards ``v_cm_s`` and counter-clockwise
    ``omega_deg_s`` in the floor frame, made from the frame captured at ``stamp_ns``
    (a robot stops when that frame is too old). ``stop`` says why the robot must stop
    ("" when it may drive): a stale or unproven frame, the camera's source lost, the
    stream's health not ok, the robot not seen. ``seq`` counts the planner run's
    commands (all robots), ``stream`` is that run (random, new at each start: a replay
    is told by them). The rest says why: the planner, the goal, whether the robot is at
    it, the most critical obstacle (id, the paper's distance and angle) and the fuzzy
    planner's deviation."""

    robot_id: Annotated[int, msgspec.Meta(ge=0)]
    seq: Seq
    stream: str
    stamp_ns: Stamp
    published_ns: Stamp
    v_cm_s: Finite
    omega_deg_s: Finite
    stop: str = ""
    planner: str = ""
    arena: str = "default"
    goal_cm: tuple[Finite, Finite] | None = None
    arrived: bool = False
    critical_id: Annotated[int, msgspec.Meta(ge=0)] | None = None
    distance_cm: Finite | None = None
    angle_deg: Finite | None = None
    deviation_deg: Finite | None = None


class RobotDrive(_Msg, tag="drive", kw_only=True):
    """What a driven robot of the simulated physical world did, published by its capture
    on ``ovis/<arena>/robots/<id>/drive`` with each frame (stamped as the frame): its
    true pose and velocity, its goal and whether and when (``time_s`` since the start)
    it reached it, its contacts with other solids (``collisions``: each new touch) and
    closest approach to any (cm; ≤ 0 touching), the commands it followed and refused
    (``refused``: without the planner's current proof, or not a command; with
    ``follows`` "cmd_vel": ROS 2 messages not followed, ``clamped``: followed clamped
    to the robot's limits), why it stands (``stopped``; "" while it drives), what it
    follows (``follows``: "ovis", the planner's signed commands, or "cmd_vel", ROS
    2's) and the newest command it received (``command_*``: v, ω in ovis's floor
    frame, the stamp of the frame it was made from; its safety rules may not follow
    it)."""

    robot_id: Annotated[int, msgspec.Meta(ge=0)]
    stamp_ns: Stamp
    t_s: NonNeg
    x_cm: Finite
    y_cm: Finite
    heading_deg: Finite
    v_cm_s: Finite
    omega_deg_s: Finite
    goal_cm: tuple[Finite, Finite] | None = None
    goal_reached: bool = False
    time_s: NonNeg | None = None
    collisions: Annotated[int, msgspec.Meta(ge=0)] = 0
    min_clearance_cm: Finite | None = None
    commands: Annotated[int, msgspec.Meta(ge=0)] = 0
    refused: Annotated[int, msgspec.Meta(ge=0)] = 0
    stopped: str = ""
    follows: Literal["ovis", "cmd_vel"] = "ovis"
    clamped: Annotated[int, msgspec.Meta(ge=0)] = 0
    command_v_cm_s: Finite | None = None
    command_omega_deg_s: Finite | None = None
    command_stamp_ns: Stamp | None = None


class ReplayMark(msgspec.Struct, kw_only=True, forbid_unknown_fields=False):
    """Rides as the Zenoh *attachment* of every message that ``ovis replay`` (and ``ovis up
    --source SESSION.mcap``) publishes, so that a consumer can tell a replay from a live
    camera while the payload stays bit-exact as recorded. Not a payload of its own."""

    recording: Annotated[str, msgspec.Meta(max_length=256)]  # the session file's name
    recorded_ns: Stamp  # the message's log time in the recording (its own clock)
    start_ns: Stamp  # the log time of the first message replayed from the recording


Message = (
    Frame
    | BinaryFrame
    | BlobList
    | ObstacleFrame
    | TruthFrame
    | CalibrateRequest
    | CalibrateReply
    | CalibrationUpdate
    | ServiceStatus
    | StreamHealth
    | WorldFrame
    | SourceState
    | RobotCommand
    | RobotDrive
)

_ENCODER = msgspec.msgpack.Encoder()
_DECODERS: dict[Any, msgspec.msgpack.Decoder] = {}
#: msgspec works out a message class's decoding on a decoder's first build, which is not
#: safe from two threads at once (a process whose cameras' threads first decoded the
#: same class together died of a segmentation fault): decoders are built one at a time,
#: and every message's here, at import
_DECODERS_BUILT = threading.Lock()


def encode(message: _Msg) -> bytes:
    """MessagePack bytes of a message (a map with a ``type`` tag)."""
    return _ENCODER.encode(message)


def decode(payload: bytes | memoryview, expected: Any = Message) -> Any:
    """Decode and validate a payload as ``expected`` (a message class or union).

    Raises :class:`MessageError` naming what is wrong (e.g. ``Expected `int` >= 0 - at
    `$.seq```), never anything else.
    """
    decoder = _DECODERS.get(expected) or _decoder(expected)
    if len(payload) == 0:
        raise MessageError("empty payload")
    try:
        return decoder.decode(payload)
    except msgspec.ValidationError as exc:
        raise MessageError(f"wrong schema: {exc}") from None
    except msgspec.DecodeError as exc:
        raise MessageError(f"not MessagePack: {exc}") from None
    except UnicodeDecodeError as exc:
        raise MessageError(f"a string is not valid UTF-8: {exc}") from None
    except RecursionError:
        raise MessageError("nested too deeply") from None


def _decoder(expected: Any) -> msgspec.msgpack.Decoder:
    """The decoder of ``expected``, built once, by one thread at a time."""
    with _DECODERS_BUILT:
        decoder = _DECODERS.get(expected)
        if decoder is None:
            decoder = _DECODERS[expected] = msgspec.msgpack.Decoder(expected)
        return decoder


for _expected in (Message, *Message.__args__):
    _decoder(_expected)


def message_schema() -> dict[str, Any]:
    """JSON Schema of every message (``ovis schema``)."""
    (schemas,), components = msgspec.json.schema_components([Message])
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        **schemas,
        "$defs": components,
    }


_ARENA_RE = re.compile(r"[A-Za-z0-9_.-]{1,64}")


class Topics:
    """Key expressions of one arena, all rooted at ``ovis/<arena>/``."""

    def __init__(self, arena: str = "default", camera: str | None = None) -> None:
        for what, name in (("arena", arena), ("camera", camera)):
            if name is not None and not _ARENA_RE.fullmatch(name):
                raise ValueError(
                    f"{what} name {name!r} must be 1-64 letters, digits, '_', '.' or '-' "
                    "(it becomes a Zenoh key chunk)"
                )
        self.arena = arena
        self.camera = camera
        #: the fused world of every camera (the fusion service), always at the arena's root
        self.world = f"ovis/{arena}/world"
        # one camera of several: its chain's topics are ovis/<arena>/cam/<name>/…
        root = f"ovis/{arena}" if camera is None else f"ovis/{arena}/cam/{camera}"
        self.root = root
        self.frames = f"{root}/frames"
        self.binary = f"{root}/binary"
        self.blobs = f"{root}/blobs"
        self.obstacles = f"{root}/obstacles"
        self.truth = f"{root}/truth"
        self.health = f"{root}/health"
        self.source = f"{root}/source"
        self.calibration = f"{root}/calibration"
        self.calibrate = f"{root}/calibrate"
        self.status_all = f"{root}/status/*"
        self.alive_all = f"{root}/alive/*"
        #: every robot's commands (the planner's) and drive reports (the world's)
        self.commands_all = f"{root}/robots/*/cmd"
        self.drives_all = f"{root}/robots/*/drive"

    def of_camera(self, camera: str) -> Topics:
        """The topics of one camera's chain in this arena (``ovis/<arena>/cam/<name>/…``)."""
        return Topics(self.arena, camera)

    def status(self, service: str) -> str:
        return f"{self.root}/status/{service}"

    def alive(self, service: str) -> str:
        return f"{self.root}/alive/{service}"

    def command(self, robot_id: int) -> str:
        """Where robot ``robot_id``'s velocity commands go (the planner's, signed)."""
        return f"{self.root}/robots/{int(robot_id)}/cmd"

    def drive(self, robot_id: int) -> str:
        """Where the simulated world reports how robot ``robot_id`` drives."""
        return f"{self.root}/robots/{int(robot_id)}/drive"
