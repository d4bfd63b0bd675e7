"""The local-contrast window and the auto level follow the objects, not the frame: on the
coins photo (scikit-image's data), evenly lit and pasted on canvases, scaled, inverted."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from test_real_detection import evenly_lit, on_canvas, reference_coins

from ovis.common.config import ImageParams
from ovis.common.vision.segmentation import (
    FIRST_WINDOW_PX,
    WINDOW_PER_OBJECT,
    follow_objects,
    segmentation,
)
from ovis.common.world.pixels import detect_pixels

skimage = pytest.importorskip("skimage")
from skimage import data  # noqa: E402

AUTO = ImageParams(median="ordinary", threshold_mode="auto")


@pytest.fixture(scope="module")
def photo() -> tuple[np.ndarray, np.ndarray]:
    """The coins photo evenly lit, and scikit-image's own segmentation of it."""
    labels = reference_coins(data.coins())
    return evenly_lit(data.coins(), labels), labels


def typical_width(labels: np.ndarray) -> float:
    """√ of the area-weighted median coin area of the reference."""
    areas = np.sort(np.bincount(labels.ravel())[1:])
    areas = areas[areas > 0]
    total = np.cumsum(areas)
    return float(np.sqrt(areas[np.searchsorted(total, total[-1] / 2)]))


def test_a_wider_view_gets_the_same_window_and_level(photo) -> None:
    """640×480 and 1920×1440 around the same coins: one window, one level (a third of the
    frame's side and Otsu's level of the whole frame grew with the canvas)."""
    image, labels = photo
    small = segmentation(on_canvas(image, labels, 640, 480, (90, 120))[0], AUTO)
    large = segmentation(on_canvas(image, labels, 1920, 1440, (600, 700))[0], AUTO)
    assert abs(small.block_px - large.block_px) <= small.block_px / 8
    assert abs(small.level - large.level) <= 1
    width = typical_width(labels)
    assert 0.8 <= small.block_px / (WINDOW_PER_OBJECT * width) <= 1.25


def test_the_window_grows_with_the_objects(photo) -> None:
    """The same coins twice as large on the same canvas: a window about twice as wide."""
    image, labels = photo
    twice = cv2.resize(image, None, fx=2.0, fy=2.0, interpolation=cv2.INTER_LINEAR)
    twice_labels = cv2.resize(labels, None, fx=2.0, fy=2.0, interpolation=cv2.INTER_NEAREST)
    one = segmentation(on_canvas(image, labels, 1280, 960)[0], AUTO)
    two = segmentation(on_canvas(twice, twice_labels, 1280, 960)[0], AUTO)
    assert 1.7 <= two.block_px / one.block_px <= 2.3, (one.block_px, two.block_px)
    found = detect_pixels(on_canvas(twice, twice_labels, 1280, 960)[0], AUTO).objects
    assert len(found) == 24


def test_dark_objects_get_the_same_window(photo) -> None:
    """The photo inverted, polarity "dark": the same window and the same 24 coins."""
    image, labels = photo
    canvas = on_canvas(image, labels, 1024, 768, (200, 300))[0]
    dark = ImageParams(median="ordinary", threshold_mode="auto", polarity="dark")
    bright_found = detect_pixels(canvas, AUTO)
    dark_found = detect_pixels(255 - canvas, dark)
    assert abs(bright_found.window_px - dark_found.window_px) <= bright_found.window_px / 8
    assert len(bright_found.objects) == len(dark_found.objects) == 24
    b = np.array([[o.row, o.col] for o in bright_found.objects])
    d = np.array([[o.row, o.col] for o in dark_found.objects])
    assert np.linalg.norm(b[:, None] - d[None], axis=2).min(axis=1).max() < 1.5


def test_a_given_window_is_used_as_it_is(photo) -> None:
    image, _ = photo
    given = ImageParams(median="ordinary", threshold_mode="adaptive", threshold=140, block_px=60)
    assert segmentation(image, given).block_px == 61
    assert segmentation(image, given).level == 140


def test_a_plain_floor_keeps_the_first_window() -> None:
    """No object to follow: the first window, the level over the whole frame."""
    found = follow_objects(np.full((480, 640), 90, np.uint8), "bright")
    assert found.block_px == FIRST_WINDOW_PX and found.near is None
