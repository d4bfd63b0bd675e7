"""What the threshold applies to: the frame less the empty floor
(:func:`subtract_background`, 128 = as the empty floor; :func:`frame_difference`, signed,
for the outlines of measured heights), or its local contrast (:func:`local_contrast`:
the frame less its Gaussian local mean, 128 = as its surroundings).

The local contrast's window follows the objects, not the frame (``block_px = 0``, the
default): a wider view of the same scene — more floor around the same objects — gets
the same window and the same level, so the same objects.

* **The window** is :data:`WINDOW_PER_OBJECT` times the typical object's extent (the
  square root of the area-weighted median blob area, :mod:`ovis.common.vision.objects`):
  wide enough that an object hardly raises its own surroundings' mean, narrow enough to
  follow uneven light; never wider than :data:`MAX_WINDOW_SHARE` of the frame's shorter
  side. The search starts from a small window (:data:`FIRST_WINDOW_PX`), finds the
  objects, sets the window from their size and looks again, until the window settles
  (within 1/8) or after :data:`SEARCH_ROUNDS` looks. It starts small because a window
  far wider than the objects turns the floor's own light and shade into blobs of its
  size, which would widen it further. A sequence of frames of one camera
  (:class:`ObjectWindow`) starts each frame from the window the last one settled on.
* **The level of "auto"** is Otsu's level of the local contrast around the objects
  (within :data:`NEIGHBOURHOOD` of an extent of each), not of the whole frame: empty
  floor far from any object would otherwise outweigh them and raise the level with the
  frame's size.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.vision.frames import GrayImage, ImageError, require_gray
from ovis.common.vision.labeling import Components, filter_components, label_components
from ovis.common.vision.objects import (
    MIN_OBJECT_PX,
    background,
    speck_floor_px,
    typical_area_px,
)
from ovis.common.vision.threshold import Polarity, ThresholdMode, binarize, otsu_level

__all__ = [
    "FIRST_WINDOW_PX",
    "NEIGHBOURHOOD",
    "NEUTRAL",
    "SEARCH_ROUNDS",
    "WINDOW_PER_OBJECT",
    "ObjectWindow",
    "Prepared",
    "follow_objects",
    "frame_difference",
    "local_contrast",
    "subtract_background",
]

#: The level of "as the local background" in a contrast or background-subtracted image.
NEUTRAL = 128


#: The local-contrast window, in typical object extents.
WINDOW_PER_OBJECT = 4.0


#: The window the search starts from (px).
FIRST_WINDOW_PX = 31


#: Looks at most of the window search.
SEARCH_ROUNDS = 5


#: Where "auto" takes its level: within this many typical extents of an object.
NEIGHBOURHOOD = 0.5


#: The widest window, as a share of the frame's shorter side.
MAX_WINDOW_SHARE = 0.5


#: The narrowest window: around the smallest object there can be.
MIN_WINDOW_PX = int(WINDOW_PER_OBJECT * math.sqrt(MIN_OBJECT_PX)) | 1


def local_contrast(gray: GrayImage, block_px: int) -> GrayImage:
    """``gray − its Gaussian local mean (σ = block/6) + 128``, clipped to uint8: uneven
    lighting removed, 128 where a pixel equals its surroundings. The window ``block_px``
    comes from :func:`follow_objects` by default."""
    gray = require_gray(gray)
    if block_px < 1:
        raise ValueError(f"block_px: expected a window of at least 1 pixel, got {block_px}")
    mean = cv2.GaussianBlur(gray.astype(np.float32), (0, 0), block_px / 6.0)
    return np.clip(gray - mean + NEUTRAL, 0, 255).astype(np.uint8)


def subtract_background(gray: GrayImage, background: GrayImage) -> GrayImage:
    """``gray − background + 128``, clipped: what changed against the empty floor."""
    gray, background = require_gray(gray), require_gray(background, "background")
    if background.shape != gray.shape:
        raise ImageError(
            f"the background image is {background.shape[1]}x{background.shape[0]} but the "
            f"frame is {gray.shape[1]}x{gray.shape[0]}"
        )
    return np.clip(gray.astype(np.int16) - background + NEUTRAL, 0, 255).astype(np.uint8)


def frame_difference(gray: GrayImage, background: GrayImage) -> NDArray[np.int16]:
    """``gray − background``, signed, unclipped: how much brighter than the empty floor."""
    return np.subtract(gray, background, dtype=np.int16)


class Prepared(NamedTuple):
    """What the threshold applies to, and how it was made.

    ``image``: the frame (less the background if given; as local contrast in the
    "adaptive" and "auto" modes); ``block_px``: the local-contrast window (0: none);
    ``near``: where "auto" takes Otsu's level (None: the whole image)."""

    image: GrayImage
    block_px: int
    near: NDArray[np.bool_] | None

    def level(self, mode: ThresholdMode, threshold: int) -> int:
        """The level used: ``threshold`` for "fixed"/"adaptive", Otsu's for "otsu" (of the
        whole image) and "auto" (around the objects)."""
        if mode == "auto":
            return otsu_level(self.image, where=self.near)
        if mode == "otsu":
            return otsu_level(self.image)
        if mode in ("fixed", "adaptive"):
            return int(threshold)
        raise ValueError(f"threshold mode: expected fixed, otsu, adaptive or auto, got {mode!r}")


def _odd(px: float, shape: tuple[int, ...]) -> int:
    """An odd window of about ``px`` pixels, at least :data:`MIN_WINDOW_PX` and at most
    :data:`MAX_WINDOW_SHARE` of the frame's shorter side."""
    return int(min(max(px, MIN_WINDOW_PX), max(3, MAX_WINDOW_SHARE * min(shape[:2])))) | 1


def _objects(
    contrast: GrayImage, near: NDArray[np.bool_] | None, polarity: Polarity
) -> tuple[Components, float]:
    """The objects of a local-contrast image at Otsu's level (taken over ``near``): not
    the background, not specks; and their typical area (px)."""
    binary = binarize(contrast, otsu_level(contrast, where=near), polarity)
    comp = label_components(binary, min_area_px=MIN_OBJECT_PX)
    behind = background(comp)
    if behind.any():
        comp = filter_components(comp, ~behind)
    typical = typical_area_px(comp.area_px)
    specks = comp.area_px < speck_floor_px(typical)
    if specks.any():
        comp = filter_components(comp, ~specks)
    return comp, typical


def _neighbourhood(comp: Components, extent: float) -> NDArray[np.bool_]:
    """The objects' pixels and those within :data:`NEIGHBOURHOOD` extents of them."""
    mask = np.zeros(comp.shape, np.uint8)
    cv2.drawContours(mask, comp.outer, -1, 1, cv2.FILLED)
    side = int(2 * NEIGHBOURHOOD * extent) | 1
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (side, side))
    return cv2.dilate(mask, disc).astype(bool)


class ObjectWindow:
    """The settled window of a sequence of frames (one camera), and its objects'
    neighbourhood: each frame's search starts from them, so a scene whose objects keep
    their size costs one look per frame; the search runs again only when the window
    moves by more than the tolerance. ``looks``: how many the last frame took."""

    def __init__(self) -> None:
        self.block_px = 0
        self.near: NDArray[np.bool_] | None = None
        self.looks = 0
        self._key: tuple[tuple[int, ...], str] | None = None

    def start(
        self, shape: tuple[int, ...], polarity: Polarity
    ) -> tuple[int, NDArray[np.bool_] | None]:
        """Where a frame of ``shape`` starts its search: the settled window, or
        :data:`FIRST_WINDOW_PX` for a new camera or polarity."""
        if self._key != (shape, polarity) or not self.block_px:
            return _odd(FIRST_WINDOW_PX, shape), None
        return self.block_px, self.near

    def keep(self, shape: tuple[int, ...], polarity: Polarity, found: Prepared, looks: int) -> None:
        self._key, self.block_px, self.near = (shape, polarity), found.block_px, found.near
        self.looks = looks


def _search(
    gray: GrayImage, polarity: Polarity, block: int, near: NDArray[np.bool_] | None
) -> tuple[Prepared, int]:
    """The window search from ``block`` (objects found at Otsu's level over ``near``),
    and how many looks it took; no objects: the window it started from."""
    for look in range(SEARCH_ROUNDS):
        contrast = local_contrast(gray, block)
        comp, typical = _objects(contrast, near, polarity)
        if not comp.count:
            return Prepared(contrast, block, None), look + 1
        extent = math.sqrt(typical)
        near = _neighbourhood(comp, extent)
        wanted = _odd(WINDOW_PER_OBJECT * extent, gray.shape)
        if abs(wanted - block) * 8 <= block or look == SEARCH_ROUNDS - 1:
            return Prepared(contrast, block, near), look + 1
        block = wanted
    raise AssertionError("unreachable: the last look returns")


def follow_objects(
    gray: GrayImage,
    polarity: Polarity,
    block_px: int = 0,
    *,
    auto: bool = True,
    window: ObjectWindow | None = None,
) -> Prepared:
    """The local contrast of ``gray`` over a window that follows its objects (see the
    module's docstring), or over ``block_px`` when given; and, for "auto" (``auto``), the
    objects' neighbourhood. ``window`` carries the settled window from frame to frame."""
    if block_px:
        block = block_px | 1
        contrast = local_contrast(gray, block)
        if not auto:  # a fixed level on a fixed window: no objects to look for
            return Prepared(contrast, block, None)
        comp, typical = _objects(contrast, None, polarity)
        near = _neighbourhood(comp, math.sqrt(typical)) if comp.count else None
        return Prepared(contrast, block, near)
    if window is None:
        return _search(gray, polarity, _odd(FIRST_WINDOW_PX, gray.shape), None)[0]
    block, near = window.start(gray.shape, polarity)
    found, looks = _search(gray, polarity, block, near)
    if found.near is None and near is not None:  # nothing at the carried window: afresh
        found, more = _search(gray, polarity, _odd(FIRST_WINDOW_PX, gray.shape), None)
        looks += more
    window.keep(gray.shape, polarity, found, looks)
    return found
