"""The local-contrast window and the auto level follow the objects, not the frame: on the
coins photo (scikit-image's data), evenly lit and pasted on canvases, scaled, inverted."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from test_real_detection import evenly_lit, on_canvas, reference_coins

from ovis.common.config import ImageParams, PinholeParams, PoseConfig
from ovis.common.vision.contrast import (
    FIRST_WINDOW_PX,
    WINDOW_PER_OBJECT,
    ObjectWindow,
    follow_objects,
)
from ovis.common.vision.segmentation import segmentation
from ovis.common.world.detection import Detector
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


def test_the_next_frame_starts_from_the_settled_window(photo) -> None:
    """A sequence of frames: the first searches (several looks), the next ones start from
    the window it settled on and take one look, with the same window and level as a
    search of their own; twice-larger coins move the window: it searches again."""
    image, labels = photo
    canvas = on_canvas(image, labels, 1280, 960, (300, 400))[0]
    window = ObjectWindow()
    first = segmentation(canvas, AUTO, window)
    assert window.looks > 1
    shifted = np.roll(canvas, (5, -7), axis=(0, 1))  # the objects moved a little
    second = segmentation(shifted, AUTO, window)
    assert window.looks == 1
    alone = segmentation(shifted, AUTO)
    assert second.block_px == first.block_px
    assert abs(second.block_px - alone.block_px) <= alone.block_px / 8
    assert abs(second.level - alone.level) <= 1
    twice = cv2.resize(image, None, fx=2.0, fy=2.0, interpolation=cv2.INTER_LINEAR)
    twice_labels = cv2.resize(labels, None, fx=2.0, fy=2.0, interpolation=cv2.INTER_NEAREST)
    larger = segmentation(on_canvas(twice, twice_labels, 1280, 960)[0], AUTO, window)
    assert window.looks > 1 and larger.block_px > 1.7 * first.block_px


def test_a_detector_carries_the_window_between_frames(photo) -> None:
    """Detector.detect on a sequence: one look from the second frame on, the same coins."""
    image, labels = photo
    canvas = on_canvas(image, labels, 1024, 768, (200, 300))[0]
    rows, cols = canvas.shape
    camera = PinholeParams(
        rows=rows,
        cols=cols,
        fx=500.0,
        fy=500.0,
        cx=cols / 2,
        cy=rows / 2,
        rvec=(np.pi, 0.0, 0.0),
        tvec_cm=(0.0, 0.0, 200.0),
    )
    detector = Detector(camera, AUTO, PoseConfig())
    first = detector.detect(canvas)
    assert detector.window.looks > 1
    second = detector.detect(canvas)
    assert detector.window.looks == 1
    assert [(o.row, o.col) for o in second.objects] == [(o.row, o.col) for o in first.objects]
