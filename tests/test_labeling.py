"""Tests of ovis.common.vision.labeling: 8-connected labeling, areas, centroids, moments."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from ovis.common.vision.frames import ImageError
from ovis.common.vision.labeling import Components, filter_components, label_components

FIELDS = ("area_px", "row", "col", "top", "left", "height", "width", "mu_rr", "mu_cc", "mu_rc")


def brute_force(labels: np.ndarray, k: int) -> dict[str, float]:
    """Statistics of component ``k`` straight from its pixel coordinates."""
    r, c = np.nonzero(labels == k)
    r = r.astype(np.float64)
    c = c.astype(np.float64)
    return {
        "area_px": float(r.size),
        "row": r.mean(),
        "col": c.mean(),
        "top": r.min(),
        "left": c.min(),
        "height": r.max() - r.min() + 1,
        "width": c.max() - c.min() + 1,
        "mu_rr": ((r - r.mean()) ** 2).mean(),
        "mu_cc": ((c - c.mean()) ** 2).mean(),
        "mu_rc": ((r - r.mean()) * (c - c.mean())).mean(),
    }


def assert_matches_brute_force(comp: Components) -> None:
    for k in range(1, comp.count + 1):
        expected = brute_force(comp.labels, k)
        for name in FIELDS:
            got = getattr(comp, name)[k - 1]
            assert got == pytest.approx(expected[name], rel=1e-9, abs=1e-9), (k, name)


def _reorder(comp: Components, order: np.ndarray) -> Components:
    """The per-component arrays of ``comp`` permuted by ``order`` (labels unchanged)."""
    return dataclasses.replace(
        comp, border=comp.border[order], **{name: getattr(comp, name)[order] for name in FIELDS}
    )


def ellipse(shape: tuple[int, int], centre: tuple[float, float], a: float, b: float) -> np.ndarray:
    """Pixels whose centre lies in the axis-aligned ellipse (semi-axes a along rows, b cols)."""
    i, j = np.indices(shape)
    return (((i - centre[0]) / a) ** 2 + ((j - centre[1]) / b) ** 2 <= 1.0).astype(np.uint8)


def test_diagonal_neighbours_are_one_component() -> None:
    binary = np.zeros((5, 5), np.uint8)
    binary[1, 1] = binary[2, 2] = binary[3, 1] = 1  # a "<" of three diagonal steps
    binary[0, 4] = 1  # isolated
    comp = label_components(binary)
    assert comp.count == 2
    np.testing.assert_array_equal(comp.area_px, [1.0, 3.0])  # raster order of first pixels
    assert comp.labels[1, 1] == comp.labels[2, 2] == comp.labels[3, 1] == 2
    assert comp.labels[0, 4] == 1
    assert comp.labels.dtype == np.int32 and comp.labels.shape == (5, 5)


def test_rectangle_and_disk_known_areas_and_centroids() -> None:
    binary = np.zeros((60, 80), np.uint8)
    binary[5:15, 10:30] = 1  # 10 × 20 rectangle: rows 5..14, cols 10..29
    binary |= ellipse(binary.shape, (40.3, 55.6), 12.0, 12.0)
    comp = label_components(binary)
    assert comp.count == 2
    assert comp.area_px[0] == 200.0
    assert (comp.row[0], comp.col[0]) == (9.5, 19.5)
    assert (comp.top[0], comp.left[0], comp.height[0], comp.width[0]) == (5, 10, 10, 20)
    # Rectangle moments: variance of a discrete uniform on n points is (n² − 1)/12.
    assert comp.mu_rr[0] == pytest.approx((10**2 - 1) / 12)
    assert comp.mu_cc[0] == pytest.approx((20**2 - 1) / 12)
    assert comp.mu_rc[0] == pytest.approx(0.0, abs=1e-12)
    assert comp.area_px[1] == pytest.approx(np.pi * 144, rel=0.02)
    assert comp.row[1] == pytest.approx(40.3, abs=0.05)
    assert comp.col[1] == pytest.approx(55.6, abs=0.05)
    assert_matches_brute_force(comp)


def test_axis_aligned_ellipse_moments() -> None:
    # Continuous ellipse with semi-axes a (rows) and b (cols): mu_rr = a²/4, mu_cc = b²/4.
    a, b = 30.0, 12.0
    comp = label_components(ellipse((80, 50), (40.25, 24.7), a, b))
    assert comp.count == 1
    assert comp.area_px[0] == pytest.approx(np.pi * a * b, rel=0.01)
    assert comp.mu_rr[0] == pytest.approx(a**2 / 4, rel=0.02)
    assert comp.mu_cc[0] == pytest.approx(b**2 / 4, rel=0.03)
    # Off-centre digitization leaves a tiny correlation (< 1 % of √(mu_rr·mu_cc)).
    assert abs(comp.mu_rc[0]) < 0.01 * np.sqrt(comp.mu_rr[0] * comp.mu_cc[0])
    assert_matches_brute_force(comp)
    # Centred on a pixel corner the pixel set is mirror-symmetric: mu_rc is exactly 0.
    sym = label_components(ellipse((80, 50), (40.5, 24.5), a, b))
    assert sym.row[0] == 40.5 and sym.col[0] == 24.5
    assert sym.mu_rc[0] == 0.0


def test_random_blobs_match_brute_force_and_shapes() -> None:
    rng = np.random.default_rng(3)
    binary = (rng.random((48, 64)) < 0.45).astype(np.uint8)
    comp = label_components(binary)
    assert comp.count > 20
    for name in FIELDS:
        arr = getattr(comp, name)
        assert arr.shape == (comp.count,), name
    for name in ("area_px", "row", "col", "mu_rr", "mu_cc", "mu_rc"):
        assert getattr(comp, name).dtype == np.float64
    assert_matches_brute_force(comp)


def test_bool_input_and_empty_image() -> None:
    comp = label_components(np.zeros((4, 6), dtype=bool))
    assert comp.count == 0
    assert comp.area_px.shape == (0,) and comp.mu_rc.shape == (0,)
    assert (comp.labels == 0).all()
    binary = np.eye(4, dtype=bool)
    assert label_components(binary).count == 1


@pytest.mark.parametrize(
    "binary", [np.zeros((4, 4), np.float64), np.zeros((4, 4, 3), np.uint8), np.zeros((0, 3), bool)]
)
def test_label_components_rejects_bad_input(binary: np.ndarray) -> None:
    with pytest.raises(ImageError, match="binary: expected a non-empty 2-D uint8 or bool image"):
        label_components(binary)


def test_filter_components_relabels_consistently() -> None:
    rng = np.random.default_rng(5)
    binary = (rng.random((40, 50)) < 0.4).astype(np.uint8)
    comp = label_components(binary)
    keep = comp.area_px >= 3
    kept = filter_components(comp, keep)
    assert kept.count == int(keep.sum()) > 0
    np.testing.assert_array_equal(kept.area_px, comp.area_px[keep])
    assert kept.labels.max() == kept.count
    for k in range(1, kept.count + 1):  # labels == k is component k of the result
        assert (kept.labels == k).sum() == kept.area_px[k - 1]
    assert_matches_brute_force(kept)
    # Same components as labeling the filtered binary image from scratch.
    fresh = label_components((kept.labels > 0).view(np.uint8))
    assert fresh.count == kept.count
    for name in FIELDS:
        np.testing.assert_allclose(
            np.sort(getattr(kept, name)), np.sort(getattr(fresh, name)), rtol=1e-12
        )
    none = filter_components(comp, np.zeros(comp.count, bool))
    assert none.count == 0 and (none.labels == 0).all()


def test_filter_components_rejects_bad_mask() -> None:
    comp = label_components(np.eye(5, dtype=np.uint8))
    with pytest.raises(ValueError, match=r"keep_mask: expected a bool array of shape \(1,\)"):
        filter_components(comp, np.ones(2, bool))
    with pytest.raises(ValueError, match="got shape \\(1,\\) int64"):
        filter_components(comp, np.ones(1, np.int64))


@settings(max_examples=50, deadline=None)
@given(
    arrays(
        np.uint8,
        st.tuples(st.integers(1, 30), st.integers(1, 30)),
        elements=st.sampled_from([0, 1]),
    )
)
def test_area_sum_equals_foreground_count(binary: np.ndarray) -> None:
    comp = label_components(binary)
    assert comp.area_px.sum() == binary.sum()
    assert ((comp.labels > 0) == (binary > 0)).all()
    if comp.count:
        assert np.bincount(comp.labels.ravel())[1:].tolist() == comp.area_px.tolist()


@settings(max_examples=50, deadline=None)
@given(
    arrays(np.uint8, (8, 8), elements=st.sampled_from([0, 1])).filter(lambda a: a.any()),
    st.integers(0, 20),
    st.integers(0, 20),
)
def test_translation_moves_centroid_and_keeps_moments(shape: np.ndarray, dr: int, dc: int) -> None:
    a = np.zeros((30, 30), np.uint8)
    b = np.zeros((30, 30), np.uint8)
    a[1:9, 1:9] = shape
    b[1 + dr : 9 + dr, 1 + dc : 9 + dc] = shape
    ca, cb = label_components(a), label_components(b)
    assert ca.count == cb.count
    # Label order is OpenCV's scan order, which a translation may permute: compare the
    # components sorted by centroid.
    oa = np.lexsort((ca.col, ca.row))
    ob = np.lexsort((cb.col, cb.row))
    ca = _reorder(ca, oa)
    cb = _reorder(cb, ob)
    np.testing.assert_allclose(cb.row, ca.row + dr, atol=1e-9)
    np.testing.assert_allclose(cb.col, ca.col + dc, atol=1e-9)
    np.testing.assert_array_equal(cb.top, ca.top + dr)
    for name in ("area_px", "mu_rr", "mu_cc", "mu_rc"):
        np.testing.assert_allclose(getattr(cb, name), getattr(ca, name), atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(
    arrays(np.uint8, st.tuples(st.integers(1, 24), st.integers(1, 24)), elements=st.integers(0, 1))
)
def test_matches_scipy_8_connected_labeling_exactly(binary: np.ndarray) -> None:
    # Random images are full of holes, nested components and one-pixel-wide parts:
    # every component's area, centroid and moments must be those of its own pixels.
    from scipy import ndimage

    ref, n = ndimage.label(binary, structure=np.ones((3, 3)))
    comp = label_components(binary)
    assert comp.count == n
    assert_matches_brute_force(comp)
    # Same partition as scipy's (up to numbering).
    pairs = {(int(a), int(b)) for a, b in zip(comp.labels.ravel(), ref.ravel(), strict=True)}
    assert len(pairs) == n + (1 if (binary == 0).any() else 0)


def test_ring_with_an_island_in_its_hole() -> None:
    binary = np.zeros((30, 30), np.uint8)
    binary[2:28, 2:28] = 1
    binary[6:24, 6:24] = 0  # the hole
    binary[12:18, 12:18] = 1  # an island inside it
    comp = label_components(binary)
    assert comp.count == 2
    assert comp.area_px.tolist() == [26 * 26 - 18 * 18, 36.0]
    assert_matches_brute_force(comp)


def test_min_area_skips_specks_but_never_a_big_enough_component() -> None:
    rng = np.random.default_rng(0)
    binary = (rng.random((120, 160)) > 0.97).astype(np.uint8)  # specks
    binary[40:60, 50:90] = 1
    all_ = label_components(binary)
    big = label_components(binary, min_area_px=100)
    assert big.count == int((all_.area_px >= 100).sum()) >= 1
    np.testing.assert_array_equal(big.area_px, all_.area_px[all_.area_px >= 100])


def test_exact_on_a_full_hd_frame_against_opencv_and_pixel_sums() -> None:
    # Thousands of components of every shape (holes, islands, one-pixel lines, the
    # image border), far from the origin: the border-chain sums must equal the pixel
    # sums exactly, component for component as OpenCV's own labeling sees them.
    import cv2

    rng = np.random.default_rng(11)
    binary = (rng.random((1080, 1920)) < 0.2).astype(np.uint8)
    binary = cv2.morphologyEx(binary, cv2.MORPH_CLOSE, np.ones((2, 2), np.uint8))
    binary[900:1080, 1700:1920] = 1
    binary[950:1040, 1750:1900] = 0  # a hole
    binary[990:1000, 1800:1810] = 1  # an island in it
    comp = label_components(binary)
    n, cc, stats, centroids = cv2.connectedComponentsWithStats(binary, connectivity=8)
    assert comp.count == n - 1 > 1000
    first = np.array([chain[0] for chain in comp.outer])  # (col, row) of each first pixel
    label = cc[first[:, 1], first[:, 0]]
    assert sorted(label.tolist()) == list(range(1, n))
    np.testing.assert_array_equal(comp.area_px, stats[label, cv2.CC_STAT_AREA])
    np.testing.assert_array_equal(comp.top, stats[label, cv2.CC_STAT_TOP])
    np.testing.assert_array_equal(comp.left, stats[label, cv2.CC_STAT_LEFT])
    np.testing.assert_array_equal(comp.height, stats[label, cv2.CC_STAT_HEIGHT])
    np.testing.assert_array_equal(comp.width, stats[label, cv2.CC_STAT_WIDTH])
    np.testing.assert_allclose(comp.col, centroids[label, 0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(comp.row, centroids[label, 1], rtol=0, atol=1e-9)
    # Central second moments straight from the pixels, per OpenCV label.
    rows, cols = np.nonzero(cc)
    k = cc[rows, cols]
    where = np.empty(n, dtype=np.int64)
    where[label] = np.arange(comp.count)
    dr, dc = rows - comp.row[where[k]], cols - comp.col[where[k]]
    for name, w in (("mu_rr", dr * dr), ("mu_cc", dc * dc), ("mu_rc", dr * dc)):
        expected = np.bincount(where[k], weights=w, minlength=comp.count) / comp.area_px
        np.testing.assert_allclose(getattr(comp, name), expected, rtol=1e-9, atol=1e-9)
