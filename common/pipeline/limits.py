"""The largest message each input of a stage may be, from the camera's size: a payload
is measured against it before it is copied out of Zenoh, decoded or kept, so that no
message (a forged one, a flood of them) can make a process allocate more than its
camera's frames need; and a frame's payload against what its own header declares
(rows × cols × channels), since the calibrator keeps frames undecoded."""

from __future__ import annotations

import functools
from typing import Literal, NamedTuple

from ovis.common.config import CameraModel
from ovis.common.messages import FrameHeader
from ovis.common.pipeline.stages import wrong_size

__all__ = [
    "HEADER_BYTES",
    "MAX_PAYLOAD_BYTES",
    "SMALL_BYTES",
    "Input",
    "PayloadLimits",
    "frame_payload_problem",
    "oversized",
]

#: What a message may hold besides its image bytes: its other fields and strings.
HEADER_BYTES = 64 << 10
#: The largest message that carries no image (a calibration, a ground truth, a request,
#: a status query), and the least a blob list may be.
SMALL_BYTES = 1 << 20
#: The hard cap, whatever the camera: a colour 4K frame fits.
MAX_PAYLOAD_BYTES = 64 << 20
#: The decoded markers a binary frame or blob list may carry (``MarkerList``: at most
#: 10 000, each an id and 8 floats).
MARKERS_BYTES = 10_000 * 96

Input = Literal["frame", "binary", "blobs", "small"]


class PayloadLimits(NamedTuple):
    """Bytes a message of each kind may be, for one camera (none known: the hard cap);
    never more than :data:`MAX_PAYLOAD_BYTES`."""

    frame: int  # rows × cols × 3 (grey or BGR) + header
    binary: int  # one bit per pixel, the optional median image, markers, header
    blobs: int  # as large as a grey frame (at least SMALL_BYTES), markers, header
    small: int  # everything else

    @classmethod
    def of(cls, camera: CameraModel | None) -> PayloadLimits:
        """The limits for ``camera`` (they depend on its size only: worked out once per
        size, not per message)."""
        return _limits(None if camera is None else (camera.rows, camera.cols))


@functools.lru_cache(maxsize=16)
def _limits(size: tuple[int, int] | None) -> PayloadLimits:
    """:meth:`PayloadLimits.of` a camera of ``size`` (rows, cols; None: none known)."""
    if size is None:
        return PayloadLimits(MAX_PAYLOAD_BYTES, MAX_PAYLOAD_BYTES, MAX_PAYLOAD_BYTES, SMALL_BYTES)
    pixels = size[0] * size[1]
    sizes = (
        3 * pixels + HEADER_BYTES,
        (pixels + 7) // 8 + pixels + MARKERS_BYTES + HEADER_BYTES,
        max(pixels, SMALL_BYTES) + MARKERS_BYTES + HEADER_BYTES,
        SMALL_BYTES,
    )
    return PayloadLimits(*(min(n, MAX_PAYLOAD_BYTES) for n in sizes))


def oversized(size: int, kind: Input, what: str, camera: CameraModel | None) -> str | None:
    """Why a ``size``-byte message of ``kind`` (named ``what`` in the text) is refused
    unread, or None when it fits."""
    limit: int = getattr(PayloadLimits.of(camera), kind)
    if size <= limit:
        return None
    camera_text = "" if camera is None else f" with the {camera.cols}x{camera.rows} camera"
    return (
        f"refused a {size}-byte {what} message unread: a {what} is at most {limit} "
        f"bytes{camera_text}"
    )


def frame_payload_problem(header: FrameHeader, size: int, camera: CameraModel) -> str | None:
    """Why a frame (its header decoded, ``size`` bytes in all) is not kept: another
    size than the camera's, or more bytes than its rows × cols × channels (and header)."""
    problem = wrong_size(header, camera, "frame")
    if problem is not None:
        return problem
    declared = header.rows * header.cols * header.channels
    if not declared <= size <= declared + HEADER_BYTES:
        return (
            f"frame {header.seq} declares {header.cols}x{header.rows}x{header.channels} = "
            f"{declared} bytes of image, its message holds {size}"
        )
    return None
