"""Binarization (paper §3, "Binarization of the Image"): "pixels having intensity below
the threshold value are converted into black and the remaining pixels are made white",
i.e. ``pixel >= threshold → 1`` for bright objects on a dark floor; ``polarity="dark"``
is the reverse (``pixel < threshold → 1``) for dark objects on a bright floor. Where
the level comes from (:data:`ThresholdMode`): a fixed one, or Otsu's
(:func:`otsu_level`); how ``--threshold`` names them (:func:`parse_threshold`).
"""

from __future__ import annotations

import operator
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.vision.frames import GrayImage, require_gray

__all__ = ["Polarity", "ThresholdMode", "binarize", "otsu_level", "parse_threshold"]

Polarity = Literal["bright", "dark"]


ThresholdMode = Literal["fixed", "otsu", "adaptive", "auto"]


def binarize(gray: GrayImage, threshold: int, polarity: Polarity) -> NDArray[np.uint8]:
    """Binarize a grey image (paper §3): object pixels → 1, floor pixels → 0.

    ``polarity="bright"`` (the paper's rule): ``pixel >= threshold → 1``, below → 0.
    ``polarity="dark"``: ``pixel < threshold → 1``, the rest → 0. With ``"bright"`` a
    threshold of 0 marks every pixel; with ``"dark"`` it marks none.

    Parameters
    ----------
    gray : (H, W) uint8 array
    threshold : int in [0, 255]
        Python or numpy integer (a GA-decoded real must be rounded by the caller).
    polarity : {"bright", "dark"}

    Returns
    -------
    binary : (H, W) uint8 array of 0 and 1
    """
    gray = require_gray(gray)
    if isinstance(threshold, bool):
        raise ValueError(f"threshold: expected an integer in [0, 255], got {threshold!r}")
    try:
        t = operator.index(threshold)
    except TypeError:
        raise ValueError(f"threshold: expected an integer in [0, 255], got {threshold!r}") from None
    if not 0 <= t <= 255:
        raise ValueError(f"threshold: expected an integer in [0, 255], got {t}")
    if polarity == "bright":
        kind = cv2.THRESH_BINARY  # src > t - 1  ⇔  src >= t
    elif polarity == "dark":
        kind = cv2.THRESH_BINARY_INV  # not (src > t - 1)  ⇔  src < t
    else:
        raise ValueError(f"polarity: expected 'bright' or 'dark', got {polarity!r}")
    # cv2 floors the threshold of an 8-bit image, so t - 1 = -1 marks every pixel.
    _, binary = cv2.threshold(gray, t - 1, 1, kind)
    return binary


def otsu_level(prepared: GrayImage, where: NDArray[np.bool_] | None = None) -> int:
    """Otsu's threshold (``cv2.THRESH_OTSU``) of an image, or of its pixels ``where`` is
    true when some are, as a paper-style level (``pixel >= level`` is an object for
    bright polarity)."""
    values = require_gray(prepared)
    if where is not None and where.any():
        values = np.ascontiguousarray(values[where]).reshape(1, -1)
    level, _ = cv2.threshold(values, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    return int(level) + 1  # OpenCV marks pixel > level


def parse_threshold(text: str) -> dict[str, object]:
    """``--threshold`` as ImageParams fields: ``N`` (fixed level 0..255), ``otsu``,
    ``auto`` or ``adaptive:N`` (level N on the local contrast, 128 = the surroundings)."""
    text = text.strip().lower()
    if text in ("otsu", "auto"):
        return {"threshold_mode": text}
    mode, _, value = text.rpartition(":")
    if mode not in ("", "adaptive", "fixed") or not value.isdigit() or int(value) > 255:
        raise ValueError(
            f"--threshold must be a level 0..255, 'otsu', 'auto' or 'adaptive:LEVEL', got {text!r}"
        )
    return {"threshold_mode": mode or "fixed", "threshold": int(value)}
