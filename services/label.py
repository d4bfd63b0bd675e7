"""Labeling service: 8-connected labeling, size filter (A^f in cm² on the floor),
Koplowitz–Bruckstein perimeter and compactness (paper §3) of each binary frame;
publishes the blobs on ``ovis/<arena>/blobs``."""

from __future__ import annotations

from ovis.common.detection import measure_blobs, size_filter_px
from ovis.common.messages import BinaryFrame, BlobList
from ovis.services.runtime import Service


def main(service: Service) -> None:
    service.follow_calibration()
    publish = service.publisher(service.topics.blobs)
    bound: dict[int, float] = {}  # calibration version -> smallest blob worth measuring

    def min_area(calib) -> float:
        if calib.version not in bound:
            bound.clear()
            plane = calib.pose.obstacle_height_cm
            bound[calib.version] = size_filter_px(calib.image, calib.camera, plane)
        return bound[calib.version]

    def handle(payload: bytes, _receipt_ns: int) -> None:
        frame = service.decode(payload, BinaryFrame, "binary")
        if frame is None:
            return
        calib = service.calibration
        cam = calib.camera
        if not service.fits_camera(frame, "binary"):
            return
        service.saw_frame(frame.seq, frame.stamp_ns)
        blobs = measure_blobs(
            frame.mask(),
            calib.image,
            cam,
            calib.pose.obstacle_height_cm,
            min_area_px=min_area(calib),
        )
        publish(
            BlobList(
                seq=frame.seq,
                stamp_ns=frame.stamp_ns,
                rows=frame.rows,
                cols=frame.cols,
                calibration_version=calib.version,
                blobs=BlobList.measures(blobs),
            )
        )
        service.sent()
        service.state = "ok"

    service.serve(service.inbox(service.topics.binary), handle)
