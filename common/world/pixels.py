"""Detection without a calibration: blobs in pixels only (no floor positions).

The same pipeline as :mod:`ovis.common.world.detection` up to the labelling — smoothing,
background, threshold mode, region of interest — with the size limits in pixels. Useful
before a camera is calibrated, to choose the threshold, and on any photo.
"""

from __future__ import annotations

from typing import Annotated

import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.config import ImageParams
from ovis.common.vision.labeling import filter_components, label_components
from ovis.common.vision.perimeter import perimeter
from ovis.common.vision.preprocess import as_gray, segment, smooth
from ovis.common.vision.shape import compactness

__all__ = ["DEFAULT_MIN_AREA_FRACTION", "PixelObject", "default_min_area_px", "detect_pixels"]

#: Without a calibration, blobs smaller than this fraction of the frame are specks.
DEFAULT_MIN_AREA_FRACTION = 1e-3

NonNegative = Annotated[float, msgspec.Meta(ge=0.0, le=1e12)]


class PixelObject(msgspec.Struct):
    """A blob: centroid (row, col), area and perimeter in pixels, compactness (eq. 13)."""

    id: int
    row: float
    col: float
    area_px: NonNegative
    perimeter_px: NonNegative
    compactness: NonNegative


def default_min_area_px(shape: tuple[int, ...]) -> float:
    """The default smallest blob: :data:`DEFAULT_MIN_AREA_FRACTION` of the frame."""
    return DEFAULT_MIN_AREA_FRACTION * shape[0] * shape[1]


def detect_pixels(
    image: NDArray[np.uint8],
    params: ImageParams,
    *,
    min_area_px: float | None = None,
    max_area_px: float | None = None,
) -> list[PixelObject]:
    """Blobs of ``image`` under ``params`` whose area lies in [min, max] pixels (min
    defaults to :func:`default_min_area_px`), largest first."""
    gray = as_gray(image)
    binary = segment(smooth(gray, params.median), params)
    lo = default_min_area_px(gray.shape) if min_area_px is None else min_area_px
    comp = label_components(binary, min_area_px=lo)
    keep = comp.area_px >= lo
    if max_area_px is not None:
        keep &= comp.area_px <= max_area_px
    comp = filter_components(comp, keep)
    perim = perimeter(comp, params.perimeter)
    comp_c = compactness(comp.area_px, perim)
    order = np.argsort(-comp.area_px, kind="stable")
    return [
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
