"""Which blobs are objects: not the frame's background, not specks.

Both defaults follow the blobs, not the frame's size, so a scene framed wider (the same
objects in more pixels of floor) gives the same objects:

* **Background** (:func:`background`): a blob that touches the image border and covers
  more than half the frame is the floor or a photo's backdrop on the object side of the
  threshold, never an object (an object cut by the border cannot be measured anyway).
* **Specks** (:func:`smallest_object_px`), without a calibration (sizes in pixels): a
  blob is a speck below an absolute floor of :data:`MIN_OBJECT_PX`, or below
  :data:`SPECK_FRACTION` of the typical object's area — the area-weighted median of the
  blobs' areas, the size of the blob a random object pixel belongs to, which the many
  small specks hardly move. With a calibration the size filter is A^f in cm² instead.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ovis.common.vision.labeling import Components

__all__ = [
    "BACKGROUND_FRACTION",
    "MIN_OBJECT_PX",
    "SPECK_FRACTION",
    "background",
    "smallest_object_px",
    "speck_floor_px",
    "typical_area_px",
]

#: A blob touching the border and covering more than this fraction of the frame is the
#: background.
BACKGROUND_FRACTION = 0.5

#: Smallest object in pixels, whatever the others (a 4×4 square: below it, what the
#: 3×3 median leaves of noise).
MIN_OBJECT_PX = 16.0

#: A blob under this fraction of the typical object's area is a speck.
SPECK_FRACTION = 1.0 / 20.0


def background(comp: Components) -> NDArray[np.bool_]:
    """(n,) True for each component that is the background: it touches the image border
    and covers more than :data:`BACKGROUND_FRACTION` of the frame."""
    rows, cols = comp.shape
    touches = (
        (comp.top == 0)
        | (comp.left == 0)
        | (comp.top + comp.height == rows)
        | (comp.left + comp.width == cols)
    )
    return touches & (comp.area_px > BACKGROUND_FRACTION * rows * cols)


def typical_area_px(area_px: NDArray[np.float64]) -> float:
    """The area-weighted median of blob areas (px): half the blobs' pixels lie in blobs at
    least this large. 0 without blobs."""
    if not area_px.size:
        return 0.0
    area = np.sort(area_px)
    total = np.cumsum(area)
    return float(area[np.searchsorted(total, total[-1] / 2.0)])


def smallest_object_px(area_px: NDArray[np.float64]) -> float:
    """The smallest object (px) among blobs of these areas (the background left out):
    :data:`SPECK_FRACTION` of the typical object's area, and at least
    :data:`MIN_OBJECT_PX`."""
    return speck_floor_px(typical_area_px(area_px[area_px >= MIN_OBJECT_PX]))


def speck_floor_px(typical_px: float) -> float:
    """The smallest object (px) when the typical object covers ``typical_px``:
    :data:`SPECK_FRACTION` of it, and at least :data:`MIN_OBJECT_PX`."""
    return max(MIN_OBJECT_PX, SPECK_FRACTION * typical_px)
