"""A frame's way to object pixels, in the order it goes: grey (:mod:`.frames`), the
paper's median step (:mod:`.smoothing`), the empty floor subtracted and the local
contrast (:mod:`.contrast`), the threshold mode's level and the polarity
(:mod:`.threshold`), the region of interest — all as
:class:`~ovis.common.config.ImageParams` says (:func:`segmentation`). Labeling
(:mod:`.labeling`) takes it from there.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ovis.common.config import ImageParams
from ovis.common.vision.contrast import (
    ObjectWindow,
    Prepared,
    follow_objects,
    subtract_background,
)
from ovis.common.vision.frames import GrayImage, read_mask
from ovis.common.vision.smoothing import smooth
from ovis.common.vision.threshold import Polarity, ThresholdMode, binarize

__all__ = [
    "Segmentation",
    "background_image",
    "prepare",
    "read_roi",
    "segment",
    "segment_gray",
    "segmentation",
]


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


def background_image(params: ImageParams, shape: tuple[int, ...]) -> GrayImage:
    """The empty floor's image (``[image] background``) for frames of ``shape``, read
    once and kept."""
    if not params.background:
        raise ValueError("no background image is configured ([image] background)")
    return _cached_mask(params.background, (int(shape[0]), int(shape[1])), "background")


def read_roi(params: ImageParams, shape: tuple[int, ...]) -> GrayImage:
    """The region-of-interest image (``[image] roi``) for frames of ``shape``, kept."""
    if not params.roi:
        raise ValueError("no region of interest is configured ([image] roi)")
    return _cached_mask(params.roi, (int(shape[0]), int(shape[1])), "region-of-interest")


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


def segment_gray(
    gray: GrayImage,
    params: ImageParams,
    window: ObjectWindow | None = None,
    *,
    median3: GrayImage | None = None,
) -> NDArray[np.uint8]:
    """Object pixels (1) of a grey frame: its smoothing step (from its 3×3 median when
    the caller has it) and :func:`segment`."""
    return segment(smooth(gray, params.median, median3=median3), params, window)
