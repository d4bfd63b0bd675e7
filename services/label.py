"""Labeling service: 8-connected labeling, size filter (A^f in cm² on the floor),
Koplowitz–Bruckstein perimeter and compactness (paper §3) of each binary frame;
publishes the blobs on ``ovis/<arena>/blobs``, with where its back-projection put them on
the obstacles' and the robot's top planes (the pose service then needs none)."""

from __future__ import annotations

from ovis.common.messages import BinaryFrame, BlobList, FloorMaps, PlaneMap
from ovis.common.world.detection import measure_blobs_and_maps, size_filter_px
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
        planes = (calib.pose.obstacle_height_cm, calib.pose.robot_height_cm)
        blobs, (floor, top) = measure_blobs_and_maps(
            frame.mask(), calib.image, cam, planes, min_area_px=min_area(calib)
        )
        publish(
            BlobList(
                seq=frame.seq,
                stamp_ns=frame.stamp_ns,
                rows=frame.rows,
                cols=frame.cols,
                calibration_version=calib.version,
                blobs=BlobList.measures(blobs),
                maps=FloorMaps(obstacle=PlaneMap.of(floor), robot=PlaneMap.of(top)),
                markers=frame.markers,
                markers_at_border=frame.markers_at_border,
            )
        )
        service.sent()
        service.state = "ok"

    service.serve(service.inbox(service.topics.binary), handle)
