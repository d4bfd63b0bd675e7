"""Object pixels of a smoothed frame: the empty floor subtracted, the local contrast, the
threshold mode's level, the polarity, the region of interest (see
:class:`~ovis.common.config.ImageParams`).

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

import functools
import math
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.config import ImageParams
from ovis.common.vision.labeling import Components, filter_components, label_components
from ovis.common.vision.objects import (
    MIN_OBJECT_PX,
    background,
    speck_floor_px,
    typical_area_px,
)
from ovis.common.vision.preprocess import (
    GrayImage,
    Polarity,
    ThresholdMode,
    binarize,
    local_contrast,
    otsu_level,
    read_mask,
    subtract_background,
)

__all__ = [
    "FIRST_WINDOW_PX",
    "NEIGHBOURHOOD",
    "SEARCH_ROUNDS",
    "WINDOW_PER_OBJECT",
    "ObjectWindow",
    "Prepared",
    "Segmentation",
    "follow_objects",
    "prepare",
    "segment",
    "segmentation",
]

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


def prepare(
    gray: GrayImage,
    mode: ThresholdMode,
    block_px: int = 0,
    background: GrayImage | None = None,
    polarity: Polarity = "bright",
    window: ObjectWindow | None = None,
) -> Prepared:
    """The image the threshold applies to: the frame, less the background if given, as
    local contrast (:func:`follow_objects`, from ``window`` when given) for the
    "adaptive" and "auto" modes."""
    out = gray if background is None else subtract_background(gray, background)
    if mode in ("adaptive", "auto"):
        return follow_objects(out, polarity, block_px, auto=mode == "auto", window=window)
    return Prepared(out, 0, None)


@functools.lru_cache(maxsize=8)
def _cached_mask(path: str, shape: tuple[int, int], what: str) -> GrayImage:
    image = read_mask(path, shape, what)
    image.setflags(write=False)
    return image


class Segmentation(NamedTuple):
    """Object pixels (1) of a frame, the local-contrast window (px, 0: none) and the
    level they were thresholded at."""

    binary: NDArray[np.uint8]
    block_px: int
    level: int


def segmentation(
    smoothed: GrayImage, params: ImageParams, window: ObjectWindow | None = None
) -> Segmentation:
    """Object pixels of a smoothed frame under ``params`` (see the module's docstring),
    with the window and level used; ``window`` carries the window of a sequence of
    frames (:class:`ObjectWindow`)."""
    shape = smoothed.shape
    floor = None
    if params.background:
        floor = _cached_mask(params.background, shape, "background")
    prepared = prepare(
        smoothed, params.threshold_mode, params.block_px, floor, params.polarity, window
    )
    level = prepared.level(params.threshold_mode, params.threshold)
    binary = binarize(prepared.image, min(255, level), params.polarity)
    if params.roi:
        binary &= (_cached_mask(params.roi, shape, "region-of-interest") > 0).astype(np.uint8)
    return Segmentation(binary, prepared.block_px, level)


def segment(
    smoothed: GrayImage, params: ImageParams, window: ObjectWindow | None = None
) -> NDArray[np.uint8]:
    """Object pixels (1) of a smoothed frame under ``params`` (``window``: see
    :func:`segmentation`)."""
    return segmentation(smoothed, params, window).binary
