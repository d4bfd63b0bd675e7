"""The paper's smoothing step (§3, "Histogramming and Smoothing"): a 3×3 median is
taken around every pixel and "the pixels having intensity below the median value are
... replaced by the median value". That is a one-sided median, ``max(pixel,
median₃ₓ₃)`` (:func:`paper_median`, see ``shared/spec/model-notes.md`` §5): it fills dark
specks (pepper) and never darkens a pixel, so an isolated bright pixel survives. The
ordinary 3×3 median is offered as well; :class:`ovis.common.config.ImageParams`
``median`` names the one in use. Each is one OpenCV call.
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np

from ovis.common.vision.frames import GrayImage, require_gray

__all__ = ["MedianMode", "paper_median", "smooth"]

MedianMode = Literal["paper", "ordinary", "none"]


def paper_median(gray: GrayImage) -> GrayImage:
    """The paper's one-sided 3×3 median (§3): raise each pixel to its 3×3 median.

    ``out = max(gray, median₃ₓ₃(gray))``: a pixel below the median of its window is
    replaced by that median, any other pixel is kept. Isolated dark pixels are filled,
    isolated bright pixels survive, and no pixel ever gets darker.

    Parameters
    ----------
    gray : (H, W) uint8 array

    Returns
    -------
    (H, W) uint8 array
        A new array. Borders use OpenCV's replicated border of ``cv2.medianBlur``.
    """
    gray = require_gray(gray)
    return np.maximum(gray, cv2.medianBlur(gray, 3))


def smooth(gray: GrayImage, mode: MedianMode, *, median3: GrayImage | None = None) -> GrayImage:
    """Apply the smoothing step selected by ``ImageParams.median``.

    Parameters
    ----------
    gray : (H, W) uint8 array
    mode : {"paper", "ordinary", "none"}
        ``"paper"``: :func:`paper_median`; ``"ordinary"``: the symmetric 3×3 median
        ``cv2.medianBlur(gray, 3)``; ``"none"``: ``gray`` is returned unchanged (same
        object, no copy).
    median3 : (H, W) uint8 array, optional
        ``cv2.medianBlur(gray, 3)`` when the caller already has it (the marker search
        wants it too): it is used instead of filtering ``gray`` again.

    Returns
    -------
    (H, W) uint8 array
    """
    gray = require_gray(gray)
    if mode == "paper":
        return paper_median(gray) if median3 is None else np.maximum(gray, median3)
    if mode == "ordinary":
        return cv2.medianBlur(gray, 3) if median3 is None else median3
    if mode == "none":
        return gray
    raise ValueError(f"mode: expected 'paper', 'ordinary' or 'none', got {mode!r}")
