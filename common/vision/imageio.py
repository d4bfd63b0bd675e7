"""Reading an image file as the pipeline takes it: uint8, grey or BGR (16-bit images
keep their high byte), with an error that says what to give instead."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.vision.frames import ImageError

__all__ = ["read_image", "to_uint8"]


def to_uint8(image: NDArray) -> NDArray[np.uint8]:
    """A 16-bit image as 8 bits (its high byte); an 8-bit image as it is."""
    if image.dtype == np.uint16:
        return (image >> 8).astype(np.uint8)
    return image


def read_image(path: Path) -> NDArray[np.uint8]:
    """Read an image file as uint8 (grey or BGR), or raise :class:`ImageError` saying why."""
    if not path.exists():
        raise ImageError(f"image {path} does not exist")
    if path.is_dir():
        raise ImageError(f"{path} is a folder; give an image file (PNG, JPEG, BMP, …)")
    if path.stat().st_size == 0:
        raise ImageError(f"image {path} is empty (0 bytes)")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None or image.size == 0:
        raise ImageError(f"cannot read {path} as an image; give a PNG, JPEG, BMP or TIFF file")
    return to_uint8(image)
