"""Image pre-processing of paper §3: grey conversion, median smoothing, binarization.

Paper §3, "Histogramming and Smoothing": a 3×3 median is taken around every pixel and
"the pixels having intensity below the median value are ... replaced by the median
value". That is a one-sided median, ``max(pixel, median₃ₓ₃)`` (:func:`paper_median`,
see ``shared/spec/model-notes.md`` §5): it fills dark specks (pepper) and never darkens a
pixel, so an isolated bright pixel survives. The ordinary 3×3 median is offered as well;
:class:`ovis.common.config.ImageParams` ``median`` names the one in use.

Paper §3, "Binarization of the Image": "pixels having intensity below the threshold
value are converted into black and the remaining pixels are made white", i.e.
``pixel >= threshold → 1`` for bright objects on a dark floor. ``polarity="dark"``
is the reverse (``pixel < threshold → 1``) for dark objects on a bright floor.

Every function takes and returns ``(H, W) uint8`` arrays and runs as one OpenCV call.
"""

from __future__ import annotations

import operator
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = [
    "ImageError",
    "MedianMode",
    "Polarity",
    "as_gray",
    "binarize",
    "local_contrast",
    "otsu_level",
    "paper_median",
    "smooth",
    "subtract_background",
]

MedianMode = Literal["paper", "ordinary", "none"]
Polarity = Literal["bright", "dark"]

GrayImage = NDArray[np.uint8]

#: Smallest image side accepted: a 3×3 window must fit.
MIN_SIDE = 3

_EXPECTED = "expected a 2-D uint8 grey image or (H, W, 3) uint8 BGR"


class ImageError(ValueError):
    """An image that cannot be processed; the message says what was expected."""


def _describe(image: object) -> str:
    if isinstance(image, np.ndarray):
        return f"shape {image.shape} {image.dtype}"
    return f"{type(image).__name__}"


def _require_gray(gray: object, name: str = "gray") -> GrayImage:
    """Return ``gray`` if it is a ``(H, W) uint8`` array with H, W >= 3, else raise."""
    if (
        not isinstance(gray, np.ndarray)
        or gray.ndim != 2
        or gray.dtype != np.uint8
        or min(gray.shape) < MIN_SIDE
    ):
        raise ImageError(
            f"{name}: expected a 2-D uint8 grey image of at least {MIN_SIDE}x{MIN_SIDE}, "
            f"got {_describe(gray)}"
        )
    return gray


def as_gray(image: NDArray[np.uint8]) -> GrayImage:
    """Validate a camera frame and return it as a grey image.

    Parameters
    ----------
    image : (H, W) uint8, (H, W, 3) uint8 BGR or (H, W, 4) uint8 BGRA array
        The frame; H and W must be at least 3 (a 3×3 window must fit).

    Returns
    -------
    gray : (H, W) uint8 array
        ``image`` itself when it is already grey (no copy), else ``cv2.cvtColor``'s
        BGR(A) → grey conversion (ITU-R BT.601 weights).

    Raises
    ------
    ImageError
        If ``image`` is not a numpy array, is empty or smaller than 3×3, is not uint8,
        or has a shape other than (H, W), (H, W, 3) or (H, W, 4).
    """
    if not isinstance(image, np.ndarray):
        raise ImageError(f"{_EXPECTED}, got {_describe(image)}")
    shape_ok = image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (3, 4))
    if not shape_ok or image.size == 0 or image.dtype != np.uint8:
        raise ImageError(f"{_EXPECTED}, got {_describe(image)}")
    if min(image.shape[:2]) < MIN_SIDE:
        raise ImageError(
            f"expected an image of at least {MIN_SIDE}x{MIN_SIDE} pixels, got {_describe(image)}"
        )
    if image.ndim == 2:
        return image
    code = cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
    return cv2.cvtColor(np.ascontiguousarray(image), code)


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
    gray = _require_gray(gray)
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
    gray = _require_gray(gray)
    if mode == "paper":
        return paper_median(gray) if median3 is None else np.maximum(gray, median3)
    if mode == "ordinary":
        return cv2.medianBlur(gray, 3) if median3 is None else median3
    if mode == "none":
        return gray
    raise ValueError(f"mode: expected 'paper', 'ordinary' or 'none', got {mode!r}")


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
    gray = _require_gray(gray)
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


ThresholdMode = Literal["fixed", "otsu", "adaptive", "auto"]

#: The level of "as the local background" in a contrast or background-subtracted image.
NEUTRAL = 128


def local_contrast(gray: GrayImage, block_px: int) -> GrayImage:
    """``gray − its Gaussian local mean (σ = block/6) + 128``, clipped to uint8: uneven
    lighting removed, 128 where a pixel equals its surroundings. The window ``block_px``
    comes from :func:`ovis.common.vision.segmentation.follow_objects` by default."""
    gray = _require_gray(gray)
    if block_px < 1:
        raise ValueError(f"block_px: expected a window of at least 1 pixel, got {block_px}")
    mean = cv2.GaussianBlur(gray.astype(np.float32), (0, 0), block_px / 6.0)
    return np.clip(gray - mean + NEUTRAL, 0, 255).astype(np.uint8)


def subtract_background(gray: GrayImage, background: GrayImage) -> GrayImage:
    """``gray − background + 128``, clipped: what changed against the empty floor."""
    gray, background = _require_gray(gray), _require_gray(background, "background")
    if background.shape != gray.shape:
        raise ImageError(
            f"the background image is {background.shape[1]}x{background.shape[0]} but the "
            f"frame is {gray.shape[1]}x{gray.shape[0]}"
        )
    return np.clip(gray.astype(np.int16) - background + NEUTRAL, 0, 255).astype(np.uint8)


def otsu_level(prepared: GrayImage, where: NDArray[np.bool_] | None = None) -> int:
    """Otsu's threshold (``cv2.THRESH_OTSU``) of an image, or of its pixels ``where`` is
    true when some are, as a paper-style level (``pixel >= level`` is an object for
    bright polarity)."""
    values = _require_gray(prepared)
    if where is not None and where.any():
        values = np.ascontiguousarray(values[where]).reshape(1, -1)
    level, _ = cv2.threshold(values, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    return int(level) + 1  # OpenCV marks pixel > level


def read_mask(path: str, shape: tuple[int, int], what: str) -> GrayImage:
    """A grey image file (background or region of interest) of the frame's ``shape``."""
    image = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise ImageError(f"cannot read the {what} image {path}")
    if image.shape != shape:
        raise ImageError(
            f"the {what} image {path} is {image.shape[1]}x{image.shape[0]}, the frame "
            f"{shape[1]}x{shape[0]}"
        )
    return image


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
