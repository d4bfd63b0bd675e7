"""Preprocessing service: the paper's median step and binarization (§3) of each frame,
with the current calibration's segmentation (threshold mode and level, polarity, background,
region of interest); publishes packed binary frames
on ``ovis/<arena>/binary`` (with marked robots, also the frame's 3×3 median, or the
frame itself for markers with cells too small for the median, in which the label
service searches their markers around the blobs; with measured heights, the grey frame,
from which the label service cuts each blob's patch)."""

from __future__ import annotations

import time

from ovis.common.calibration.file import Calibration
from ovis.common.messages import FrameView
from ovis.common.pipeline.stages import FloorSpots, binary_frame, clock_skew
from ovis.common.vision.contrast import ObjectWindow
from ovis.common.vision.frames import ImageError, as_gray
from ovis.common.world.marker_search import BlobMarkers
from ovis.services.service import Service


def main(service: Service) -> None:
    markers = BlobMarkers()  # which image to send for the marker search, per calibration
    window = [ObjectWindow()]  # the local-contrast window of this camera's frames
    spots = FloorSpots()  # the empty floor's bright spots, with measured heights

    def prepare(calib: Calibration) -> None:
        """The calibration's marker sizes, worked out before its frames come; a new
        calibration's frames search their local-contrast window afresh."""
        window[0] = ObjectWindow()
        if calib.pose.robots:
            markers.sizes(calib.version, calib.camera, calib.pose)

    prepare(service.calibration)
    service.follow_calibration(prepare)
    publish = service.publisher(service.topics.binary)

    def handle(payload: bytes, _receipt_ns: int) -> None:
        frame = service.decode(payload, FrameView, "frame")
        if frame is None or service.refused("bad_frame", clock_skew(frame, time.time_ns())):
            return
        calib = service.calibration
        if not service.fits_camera(frame, "frame"):
            return
        try:
            gray = as_gray(frame.image())
        except ImageError as exc:
            service.error("bad_frame", f"frame {frame.seq}: {exc}")
            return
        service.saw_frame(frame.seq, frame.stamp_ns, frame.stream)
        out = binary_frame(frame, gray, calib, markers, window[0], spots)
        service.publish_result(publish, out)

    service.serve(service.inbox(service.topics.frames), handle)
