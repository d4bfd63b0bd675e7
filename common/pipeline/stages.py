"""The per-message steps of the frame path, each one function from the message a stage
receives (and its calibration) to the message it publishes: preprocess (paper §3:
median, binarization), label (labeling, size filter, perimeter, the back-projection
maps) and pose (robot, obstacles, planner inputs, §5.2); with the checks that refuse a
frame before it is processed."""

from __future__ import annotations

from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.calibration.file import Calibration
from ovis.common.camera.plane_table import PlaneTables
from ovis.common.config import CameraModel
from ovis.common.messages import (
    BinaryFrame,
    BlobList,
    BlobPatch,
    FloorMaps,
    Frame,
    MarkerCorners,
    ObstacleFrame,
    PlaneMap,
)
from ovis.common.vision.contrast import ObjectWindow
from ovis.common.vision.frames import GrayImage
from ovis.common.vision.outline import SmoothedDiff, background_spots, blob_patches
from ovis.common.vision.segmentation import Segmentation, background_image, segmentation
from ovis.common.vision.smoothing import smooth
from ovis.common.world.detection import (
    Detector,
    measure_blobs_and_maps,
    size_filter_px,
    size_plane_cm,
    solid_pixels,
)
from ovis.common.world.marker_search import BlobMarkers

__all__ = [
    "MAX_CLOCK_SKEW_S",
    "FloorSpots",
    "SizeFilter",
    "binary_frame",
    "blob_list",
    "clock_skew",
    "obstacle_frame",
    "wrong_size",
]

#: Frames stamped further than this from the local clock are refused (a broken clock or
#: a forged frame would otherwise give nonsense ages and velocities downstream).
MAX_CLOCK_SKEW_S = 3600.0


class _Sized(Protocol):
    seq: int
    rows: int
    cols: int


def clock_skew(frame: Frame, now_ns: int) -> str | None:
    """Why a frame's capture stamp is refused (too far from ``now_ns``), or None."""
    skew = abs(now_ns - frame.stamp_ns) / 1e9
    if skew <= MAX_CLOCK_SKEW_S:
        return None
    return (
        f"frame {frame.seq} is stamped {skew:.0f} s away from this machine's clock; "
        "check the capture host's clock (NTP)"
    )


def wrong_size(frame: _Sized, camera: CameraModel, kind: str) -> str | None:
    """Why a frame (or binary frame) does not have the calibrated camera's size, or None."""
    if (frame.rows, frame.cols) == (camera.rows, camera.cols):
        return None
    return (
        f"{kind} {frame.seq} is {frame.cols}x{frame.rows}, the camera is configured for "
        f"{camera.cols}x{camera.rows}"
    )


class FloorSpots:
    """The bright spots of one empty-floor image (:func:`background_spots`), worked out
    once for it, and the buffers one camera's frames' object pixels are found in
    (:class:`SmoothedDiff`)."""

    def __init__(self) -> None:
        self._floor: NDArray[np.uint8] | None = None
        self._spots: NDArray[np.uint8] | None = None
        self.smoothed = SmoothedDiff()

    def of(self, floor: NDArray[np.uint8]) -> NDArray[np.uint8]:
        if floor is not self._floor or self._spots is None:
            self._floor, self._spots = floor, background_spots(floor)
        return self._spots


def binary_frame(
    frame: Frame,
    gray: GrayImage,
    calib: Calibration,
    markers: BlobMarkers | None = None,
    window: ObjectWindow | None = None,
    spots: FloorSpots | None = None,
) -> BinaryFrame:
    """The preprocessing stage: the median step and binarization (§3) of ``gray`` (the
    frame's grey image) with the calibration's whole segmentation (threshold mode and
    level, polarity, empty-floor background, region of interest, as `ovis detect` and
    the calibration applied it; ``window``: the local-contrast window carried between
    one camera's frames; with measured heights, the pixels brighter than the empty floor
    that the fitted outlines come from, :func:`solid_pixels`, ``spots`` keeping the
    floor's bright spots), packed, with the level used; with marked
    robots configured, also the image the label stage searches their markers in around
    the blobs: the frame's 3×3 median (the smoothing step computes it anyway), or the
    frame itself when the markers' cells are too small for it (``markers``'
    :meth:`~BlobMarkers.search_image`; without ``markers``, the median); with heights
    measured, the grey frame (the label stage cuts each blob's patch from it)."""
    params = calib.image
    median3 = cv2.medianBlur(gray, 3) if calib.pose.robots else None
    measured = calib.pose.heights == "measured"
    if measured:  # the object pixels the fitted outlines come from
        floor = background_image(params, gray.shape)
        if spots is not None:
            mask = solid_pixels(gray, floor, params, spots.of(floor), spots.smoothed)
        else:
            mask = solid_pixels(gray, floor, params, None)
        seg = Segmentation(mask, 0, int(params.threshold))
    else:
        seg = segmentation(smooth(gray, params.median, median3=median3), params, window)
    search = median3
    if median3 is not None and markers is not None:
        search = markers.search_image(gray, median3, calib.version, calib.camera, calib.pose)
    return BinaryFrame(
        seq=frame.seq,
        stamp_ns=frame.stamp_ns,
        rows=frame.rows,
        cols=frame.cols,
        bits=np.packbits(seg.binary).tobytes(),
        threshold=min(255, seg.level),
        calibration_version=calib.version,
        stream=frame.stream,
        # views, not copies: the message is encoded straight away, the images not changed
        median=None if search is None else memoryview(np.ascontiguousarray(search)).cast("B"),  # type: ignore[arg-type]
        gray=memoryview(np.ascontiguousarray(gray)).cast("B") if measured else None,  # type: ignore[arg-type]
    )


class SizeFilter:
    """The smallest blob worth measuring (A^f on the size filter's plane,
    :func:`~ovis.common.world.detection.size_plane_cm`, in px), computed once per
    calibration version."""

    def __init__(self) -> None:
        self._version: int | None = None
        self._px = 0.0

    def min_area_px(self, calib: Calibration) -> float:
        if calib.version != self._version:
            plane = size_plane_cm(calib.pose)
            self._px = size_filter_px(calib.image, calib.camera, plane)
            self._version = calib.version
        return self._px


def blob_list(
    frame: BinaryFrame,
    calib: Calibration,
    min_area_px: float,
    find_markers: BlobMarkers | None = None,
    tables: PlaneTables | None = None,
) -> BlobList:
    """The labeling stage: the blobs of a binary frame (labeling, size filter,
    perimeter, compactness) and where back-projection puts them on the obstacles' and
    the robot's top planes (so that the pose stage needs none; a pinhole camera's read
    from ``tables``, kept by the caller between frames); with marked robots, the
    markers ``find_markers`` finds around the blobs in the image the binary frame brings
    (its ``median``, as
    :meth:`Detector.detect` does), unless the binary frame brings them decoded; with
    heights measured, each blob's patch of the frame less the empty floor (when the
    binary frame brings the grey frame)."""
    planes = (calib.pose.obstacle_height_cm, calib.pose.robot_height_cm)
    blobs, (floor, top) = measure_blobs_and_maps(
        frame.mask(),
        calib.image,
        calib.camera,
        planes,
        min_area_px=min_area_px,
        tables=tables,
        size_plane_cm=size_plane_cm(calib.pose),
    )
    patches = None
    gray = frame.gray_image()
    if calib.pose.heights == "measured" and gray is not None and blobs.box is not None:
        background = background_image(calib.image, gray.shape)
        cut = blob_patches(gray, background, *blobs.box.T)
        assert blobs.filled is not None
        patches = [BlobPatch.of(p, f) for p, f in zip(cut, blobs.filled, strict=True)]
    markers, at_border = frame.markers, frame.markers_at_border
    median3 = frame.median_image()
    if markers is None and median3 is not None and find_markers and calib.pose.robots:
        found = find_markers(median3, blobs, calib.version, calib.camera, calib.pose, top.area_cm2)
        markers, at_border = MarkerCorners.of(found), found.partial
    return BlobList(
        seq=frame.seq,
        stamp_ns=frame.stamp_ns,
        rows=frame.rows,
        cols=frame.cols,
        calibration_version=calib.version,
        blobs=BlobList.measures(blobs),
        maps=FloorMaps(obstacle=PlaneMap.of(floor), robot=PlaneMap.of(top)),
        markers=markers,
        markers_at_border=at_border,
        stream=frame.stream,
        patches=patches,
    )


def obstacle_frame(
    msg: BlobList, detector: Detector, calibration_version: int, arena: str, now_ns: int
) -> ObstacleFrame:
    """The pose stage: robot, obstacles (identities kept by ``detector``) and planner
    inputs of one frame's blobs. The blobs' maps are used only when they were made with
    the detector's calibration (``calibration_version``)."""
    floor = top = None
    if msg.maps is not None and msg.calibration_version == calibration_version:
        floor, top = msg.maps.obstacle.jacobian(), msg.maps.robot.jacobian()
    markers = MarkerCorners.to_markers(msg.markers, msg.markers_at_border)
    det = detector.from_blobs(
        msg.to_blobs(),
        floor=floor,
        top=top,
        stamp_s=msg.stamp_ns / 1e9,
        markers=markers,
        patches=msg.blob_patches(),
        frame_shape=(msg.rows, msg.cols),
    )
    return ObstacleFrame(
        seq=msg.seq,
        stamp_ns=msg.stamp_ns,
        published_ns=now_ns,
        frame_age_ms=(now_ns - msg.stamp_ns) / 1e6,
        calibration_version=calibration_version,
        robot=next((o for o in det.objects if o.kind == "robot"), None),
        obstacles=[o for o in det.objects if o.kind == "obstacle"],
        planner=det.planner,
        arena=arena,
        robots=det.robots,
        robot_plans=det.robot_plans,
        unknown_markers=det.unknown_markers,
        markers_at_border=det.markers_at_border,
        stream=msg.stream,
    )
