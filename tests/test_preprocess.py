"""Tests of the first steps of a frame: grey conversion (vision.frames), the paper's median
(vision.smoothing), binarization (vision.threshold)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numpy.lib.stride_tricks import sliding_window_view

from ovis.common.vision.frames import ImageError, as_gray
from ovis.common.vision.smoothing import paper_median, smooth
from ovis.common.vision.threshold import binarize

gray_images = arrays(
    np.uint8,
    st.tuples(st.integers(3, 24), st.integers(3, 24)),
    elements=st.integers(0, 255),
)


def brute_median3(gray: np.ndarray) -> np.ndarray:
    """3×3 median with replicated border, by brute force."""
    padded = np.pad(gray, 1, mode="edge")
    windows = sliding_window_view(padded, (3, 3)).reshape(*gray.shape, 9)
    return np.median(windows, axis=-1).astype(np.uint8)


# --- as_gray -------------------------------------------------------------------------


def test_as_gray_passes_grey_through_without_copy() -> None:
    gray = np.arange(20, dtype=np.uint8).reshape(4, 5)
    assert as_gray(gray) is gray


def test_as_gray_converts_bgr_and_bgra_with_bt601_weights() -> None:
    bgr = np.zeros((3, 4, 3), dtype=np.uint8)
    bgr[..., 0] = 255  # pure blue
    bgr[0, 0] = (0, 0, 255)  # pure red
    bgr[0, 1] = (0, 255, 0)  # pure green
    gray = as_gray(bgr)
    assert gray.shape == (3, 4) and gray.dtype == np.uint8
    assert gray[1, 1] == 29  # round(0.114 · 255)
    assert gray[0, 0] == 76  # round(0.299 · 255)
    assert gray[0, 1] == 150  # round(0.587 · 255)
    bgra = np.concatenate([bgr, np.full((3, 4, 1), 7, np.uint8)], axis=2)
    np.testing.assert_array_equal(as_gray(bgra), gray)


def test_as_gray_accepts_non_contiguous_views() -> None:
    bgr = np.random.default_rng(0).integers(0, 256, (6, 8, 3), dtype=np.uint8)
    view = bgr[::2, ::2]
    np.testing.assert_array_equal(as_gray(view), cv2.cvtColor(view.copy(), cv2.COLOR_BGR2GRAY))


@pytest.mark.parametrize(
    ("image", "message"),
    [
        (
            np.zeros((0, 5)),
            "expected a 2-D uint8 grey image or (H, W, 3) uint8 BGR, got shape (0, 5) float64",
        ),
        (
            np.zeros((0, 5), np.uint8),
            "expected a 2-D uint8 grey image or (H, W, 3) uint8 BGR, got shape (0, 5) uint8",
        ),
        (
            np.zeros(10, np.uint8),
            "expected a 2-D uint8 grey image or (H, W, 3) uint8 BGR, got shape (10,) uint8",
        ),
        (
            np.zeros((4, 4), np.float32),
            "expected a 2-D uint8 grey image or (H, W, 3) uint8 BGR, got shape (4, 4) float32",
        ),
        (
            np.zeros((4, 4), np.uint16),
            "expected a 2-D uint8 grey image or (H, W, 3) uint8 BGR, got shape (4, 4) uint16",
        ),
        (
            np.zeros((4, 4, 2), np.uint8),
            "expected a 2-D uint8 grey image or (H, W, 3) uint8 BGR, got shape (4, 4, 2) uint8",
        ),
        (
            np.zeros((4, 4, 3, 1), np.uint8),
            "expected a 2-D uint8 grey image or (H, W, 3) uint8 BGR, got shape (4, 4, 3, 1) uint8",
        ),
        (
            [[1, 2, 3]] * 3,
            "expected a 2-D uint8 grey image or (H, W, 3) uint8 BGR, got list",
        ),
        (
            np.zeros((2, 9), np.uint8),
            "expected an image of at least 3x3 pixels, got shape (2, 9) uint8",
        ),
    ],
)
def test_as_gray_rejects_bad_images(image: object, message: str) -> None:
    with pytest.raises(ImageError) as info:
        as_gray(image)  # type: ignore[arg-type]
    assert str(info.value) == message
    assert isinstance(info.value, ValueError)


# --- median ----------------------------------------------------------------------------


def test_paper_median_fills_pepper_but_keeps_isolated_bright_pixel() -> None:
    gray = np.full((7, 7), 100, dtype=np.uint8)
    gray[2, 2] = 0  # pepper
    gray[4, 5] = 255  # salt
    out = paper_median(gray)
    assert out[2, 2] == 100
    assert out[4, 5] == 255
    expected = np.full((7, 7), 100, dtype=np.uint8)
    expected[4, 5] = 255
    np.testing.assert_array_equal(out, expected)
    # The ordinary median removes both specks: it differs exactly at the bright pixel.
    ordinary = smooth(gray, "ordinary")
    np.testing.assert_array_equal(ordinary, np.full((7, 7), 100, dtype=np.uint8))
    assert np.argwhere(ordinary != out).tolist() == [[4, 5]]


def test_paper_median_keeps_a_bright_one_pixel_line() -> None:
    # The ordinary median erases a 1-pixel bright line; the paper's never darkens it.
    gray = np.full((9, 9), 50, dtype=np.uint8)
    gray[:, 4] = 200
    assert (paper_median(gray)[:, 4] == 200).all()
    assert (smooth(gray, "ordinary")[:, 4] == 50).all()


@settings(max_examples=60, deadline=None)
@given(gray_images)
def test_paper_median_is_max_of_pixel_and_median(gray: np.ndarray) -> None:
    out = paper_median(gray)
    assert out.dtype == np.uint8 and out.shape == gray.shape
    assert (out >= gray).all()  # never darkens
    np.testing.assert_array_equal(out, np.maximum(gray, brute_median3(gray)))
    np.testing.assert_array_equal(smooth(gray, "ordinary"), brute_median3(gray))


def test_smooth_modes() -> None:
    gray = np.random.default_rng(1).integers(0, 256, (10, 12), dtype=np.uint8)
    assert smooth(gray, "none") is gray
    np.testing.assert_array_equal(smooth(gray, "paper"), paper_median(gray))
    with pytest.raises(ValueError, match="mode: expected 'paper', 'ordinary' or 'none', got 'x'"):
        smooth(gray, "x")  # type: ignore[arg-type]


def test_median_rejects_colour_image() -> None:
    with pytest.raises(ImageError, match=r"gray: expected a 2-D uint8 grey image .* \(4, 4, 3\)"):
        paper_median(np.zeros((4, 4, 3), np.uint8))


# --- binarize --------------------------------------------------------------------------


def test_binarize_bright_threshold_boundary() -> None:
    gray = np.array([[0, 127, 128], [129, 200, 255], [128, 1, 254]], dtype=np.uint8)
    out = binarize(gray, 128, "bright")
    assert out.dtype == np.uint8
    np.testing.assert_array_equal(out, [[0, 0, 1], [1, 1, 1], [1, 0, 1]])


def test_binarize_dark_is_the_complement() -> None:
    gray = np.array([[0, 127, 128], [129, 200, 255], [128, 1, 254]], dtype=np.uint8)
    np.testing.assert_array_equal(binarize(gray, 128, "dark"), [[1, 1, 0], [0, 0, 0], [0, 1, 0]])


@pytest.mark.parametrize(
    ("threshold", "bright", "dark"),
    [(0, 9, 0), (1, 8, 1), (255, 1, 8), (np.int64(254), 2, 7), (np.uint8(128), 5, 4)],
)
def test_binarize_extreme_thresholds(threshold: int, bright: int, dark: int) -> None:
    gray = np.array([[0, 1, 2], [100, 128, 200], [253, 254, 255]], dtype=np.uint8)
    assert binarize(gray, threshold, "bright").sum() == bright
    assert binarize(gray, threshold, "dark").sum() == dark


@settings(max_examples=60, deadline=None)
@given(gray_images, st.integers(0, 255))
def test_binarize_matches_comparison(gray: np.ndarray, threshold: int) -> None:
    bright = binarize(gray, threshold, "bright")
    dark = binarize(gray, threshold, "dark")
    np.testing.assert_array_equal(bright, (gray >= threshold).astype(np.uint8))
    np.testing.assert_array_equal(bright + dark, np.ones_like(gray))


@pytest.mark.parametrize("threshold", [-1, 256, 1.5, 128.0, True, "128"])
def test_binarize_rejects_bad_threshold(threshold: object) -> None:
    gray = np.zeros((3, 3), np.uint8)
    with pytest.raises(ValueError, match=r"threshold: expected an integer in \[0, 255\]"):
        binarize(gray, threshold, "bright")  # type: ignore[arg-type]


def test_binarize_rejects_bad_polarity_and_image() -> None:
    gray = np.zeros((3, 3), np.uint8)
    with pytest.raises(ValueError, match="polarity: expected 'bright' or 'dark', got 'white'"):
        binarize(gray, 10, "white")  # type: ignore[arg-type]
    with pytest.raises(ImageError, match=r"got shape \(3, 3\) float64"):
        binarize(np.zeros((3, 3)), 10, "bright")
