"""Detection without a calibration: blobs in pixels only (no floor positions).

The same pipeline as :mod:`ovis.common.world.detection` up to the labelling — smoothing,
background, threshold mode, region of interest — with the size limits in pixels, by
default those of :mod:`ovis.common.vision.objects` (they follow the blobs, not the
frame's size). Useful before a camera is calibrated, to choose the threshold, and on any
photo.
"""

from __future__ import annotations

from typing import Annotated, NamedTuple

import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.config import ImageParams
from ovis.common.vision.frames import as_gray
from ovis.common.vision.labeling import filter_components, label_components
from ovis.common.vision.objects import MIN_OBJECT_PX, background, smallest_object_px
from ovis.common.vision.perimeter import perimeter
from ovis.common.vision.segmentation import segmentation
from ovis.common.vision.shape import compactness
from ovis.common.vision.smoothing import smooth

__all__ = ["PixelDetection", "PixelObject", "detect_pixels"]

NonNegative = Annotated[float, msgspec.Meta(ge=0.0, le=1e12)]


class PixelObject(msgspec.Struct):
    """A blob: centroid (row, col), area and perimeter in pixels, compactness (eq. 13)."""

    id: int
    row: float
    col: float
    area_px: NonNegative
    perimeter_px: NonNegative
    compactness: NonNegative


class PixelDetection(NamedTuple):
    """The objects of a frame (largest first), the smallest area kept (px), how many
    blobs were left out as the background, the local-contrast window (px, 0: none) and
    the threshold level used."""

    objects: list[PixelObject]
    min_area_px: float
    background: int
    window_px: int = 0
    level: int = 0


def detect_pixels(
    image: NDArray[np.uint8],
    params: ImageParams,
    *,
    min_area_px: float | None = None,
    max_area_px: float | None = None,
) -> PixelDetection:
    """Blobs of ``image`` under ``params`` whose area lies in [min, max] pixels, never the
    background (:mod:`ovis.common.vision.objects`); min defaults to
    :func:`~ovis.common.vision.objects.smallest_object_px` of the frame's blobs."""
    gray = as_gray(image)
    seg = segmentation(smooth(gray, params.median), params)
    comp = label_components(
        seg.binary, min_area_px=MIN_OBJECT_PX if min_area_px is None else min_area_px
    )
    behind = background(comp)
    if behind.any():
        comp = filter_components(comp, ~behind)
    lo = smallest_object_px(comp.area_px) if min_area_px is None else min_area_px
    keep = comp.area_px >= lo
    if max_area_px is not None:
        keep &= comp.area_px <= max_area_px
    if not keep.all():
        comp = filter_components(comp, keep)
    perim = perimeter(comp, params.perimeter)
    comp_c = compactness(comp.area_px, perim)
    order = np.argsort(-comp.area_px, kind="stable")
    objects = [
        PixelObject(
            id=k,
            row=float(comp.row[i]),
            col=float(comp.col[i]),
            area_px=float(comp.area_px[i]),
            perimeter_px=float(perim[i]),
            compactness=float(comp_c[i]),
        )
        for k, i in enumerate(order.tolist())
    ]
    return PixelDetection(objects, lo, int(behind.sum()), seg.block_px, seg.level)
