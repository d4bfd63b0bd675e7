"""A frame as the pipeline takes it: checked and made grey (:func:`as_gray`), and image
files of the frame's size (a background, a region of interest: :func:`read_mask`).
Every later step takes and returns ``(H, W) uint8`` grey images (:func:`require_gray`).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["MIN_SIDE", "GrayImage", "ImageError", "as_gray", "read_mask", "require_gray"]

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


def require_gray(gray: object, name: str = "gray") -> GrayImage:
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
