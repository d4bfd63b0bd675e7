"""Preprocessing service: the paper's median step and binarization (§3) of each frame,
with the current calibration's threshold and polarity; publishes packed binary frames
on ``ovis/<arena>/binary``."""

from __future__ import annotations

import time

import numpy as np

from ovis.common.messages import BinaryFrame, Frame, MarkerCorners
from ovis.common.vision.preprocess import ImageError, as_gray, binarize, smooth
from ovis.common.world.marker_search import FrameMarkers
from ovis.services.runtime import Service

#: Frames stamped further than this from the local clock are refused (a broken clock or
#: a forged frame would otherwise give nonsense ages and velocities downstream).
MAX_CLOCK_SKEW_S = 3600.0


def main(service: Service) -> None:
    service.follow_calibration()
    publish = service.publisher(service.topics.binary)
    find_markers = FrameMarkers()

    def handle(payload: bytes, _receipt_ns: int) -> None:
        frame = service.decode(payload, Frame, "frame")
        if frame is None:
            return
        skew = abs(time.time_ns() - frame.stamp_ns) / 1e9
        if skew > MAX_CLOCK_SKEW_S:
            service.error(
                "bad_frame",
                f"frame {frame.seq} is stamped {skew:.0f} s away from this machine's clock; "
                "check the capture host's clock (NTP)",
            )
            return
        calib = service.calibration
        if not service.fits_camera(frame, "frame"):
            return
        try:
            gray = as_gray(frame.image())
        except ImageError as exc:
            service.error("bad_frame", f"frame {frame.seq}: {exc}")
            return
        service.saw_frame(frame.seq, frame.stamp_ns)
        params = calib.image
        binary = binarize(smooth(gray, params.median), params.threshold, params.polarity)
        markers = find_markers(gray, calib.version, calib.camera, calib.pose)
        publish(
            BinaryFrame(
                seq=frame.seq,
                stamp_ns=frame.stamp_ns,
                rows=frame.rows,
                cols=frame.cols,
                bits=np.packbits(binary).tobytes(),
                threshold=params.threshold,
                calibration_version=calib.version,
                markers=None if markers is None else MarkerCorners.of(markers),
                markers_at_border=0 if markers is None else markers.partial,
            )
        )
        service.sent()
        service.state = "ok"

    service.serve(service.inbox(service.topics.frames), handle)
