"""Labeling service: 8-connected labeling, size filter (A^f in cm², on the obstacles'
plane, or the floor when heights are measured),
Koplowitz–Bruckstein perimeter and compactness (paper §3) of each binary frame;
publishes the blobs on ``ovis/<arena>/blobs``, with where its back-projection put them on
the obstacles' and the robot's top planes (the pose service then needs none), and with
marked robots their markers, searched for around the blobs in the frame's median, and
with measured heights each blob's patch of the frame less the empty floor."""

from __future__ import annotations

from ovis.common.calibration.file import Calibration
from ovis.common.camera.plane_table import PlaneTables
from ovis.common.config import PinholeParams
from ovis.common.messages import BinaryFrameView
from ovis.common.pipeline.stages import SizeFilter, blob_list
from ovis.common.world.detection import size_plane_cm
from ovis.common.world.marker_search import BlobMarkers
from ovis.services.service import Service


def main(service: Service) -> None:
    tables = PlaneTables(background=True)  # a pinhole camera's plane maps, per calibration
    size_filter = SizeFilter()
    find_markers = BlobMarkers()

    def prepare(calib: Calibration, *, wait: bool = False) -> None:
        """What a calibration's frames need, made before they come: the smallest blob,
        the marker sizes, and (in the background unless ``wait``) the plane tables."""
        size_filter.min_area_px(calib)
        if calib.pose.robots:
            find_markers.sizes(calib.version, calib.camera, calib.pose)
        if isinstance(calib.camera, PinholeParams):
            pose = calib.pose
            heights = {pose.obstacle_height_cm, pose.robot_height_cm, size_plane_cm(pose)}
            tables.prepare(calib.camera, heights, wait=wait)

    # at start, all of it before the first frame (which would otherwise take many frame
    # periods and make the next frames queue up behind it); a new calibration's while
    # the frames go on
    service.follow_calibration(prepare)
    service.await_calibration()  # a real camera's: the calibrator's, not the configured one
    prepare(service.calibration, wait=True)
    publish = service.publisher(service.topics.blobs)

    def handle(payload: bytes, _receipt_ns: int) -> None:
        frame = service.decode(payload, BinaryFrameView, "binary")
        if frame is None:
            return
        calib = service.calibration
        if not service.fits_camera(frame, "binary"):
            return
        service.saw_frame(frame.seq, frame.stamp_ns, frame.stream)
        blobs = blob_list(frame, calib, size_filter.min_area_px(calib), find_markers, tables)
        service.publish_result(publish, blobs)

    service.serve(service.inbox(service.topics.binary), handle)
