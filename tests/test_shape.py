"""Tests of ovis.common.vision.shape: compactness (paper eq. 13) and moment orientation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ovis.common.vision.labeling import label_components
from ovis.common.vision.perimeter import KB_A, perimeter
from ovis.common.vision.shape import MAX_ELONGATION, axis_deg, compactness, orientation


def disk(r: float, centre: tuple[float, float]) -> np.ndarray:
    """Digitized disk: pixels whose centre lies within r of ``centre``."""
    n = int(2 * r + 8)
    i, j = np.indices((n, n))
    return (((i - centre[0]) ** 2 + (j - centre[1]) ** 2) <= r * r).astype(np.uint8)


def rotated_rect(h: float, w: float, angle_rad: float) -> np.ndarray:
    """Digitized h × w rectangle (h along rows before rotation) turned by ``angle_rad``
    from +row towards +col, centred off the pixel grid."""
    n = int(1.5 * max(h, w) + 10)
    i, j = np.indices((n, n)).astype(np.float64)
    c = n / 2 + 0.3
    u = (i - c) * math.cos(angle_rad) + (j - c) * math.sin(angle_rad)
    v = -(i - c) * math.sin(angle_rad) + (j - c) * math.cos(angle_rad)
    return ((np.abs(u) <= h / 2) & (np.abs(v) <= w / 2)).astype(np.uint8)


def compactness_of(binary: np.ndarray, method: str) -> float:
    comp = label_components(binary)
    assert comp.count == 1
    return float(compactness(comp.area_px, perimeter(comp, method))[0])  # type: ignore[arg-type]


# --- compactness -----------------------------------------------------------------------


def test_compactness_formula() -> None:
    assert compactness(math.pi * 100, 2 * math.pi * 10) == pytest.approx(1.0)
    assert compactness(1600.0, 160.0) == pytest.approx(math.pi / 4)
    out = compactness(np.array([4.0, 1.0, 10.0]), np.array([8.0, 0.0, 0.0]))
    np.testing.assert_allclose(out, [4 * math.pi * 4 / 64, 0.0, 0.0])
    assert out.dtype == np.float64
    assert np.isfinite(out).all()
    assert compactness(1.0, 0.0).shape == ()  # scalars give a 0-d array
    assert compactness([[1.0], [2.0]], [1.0, 2.0, 4.0]).shape == (2, 3)  # broadcasts


@pytest.mark.parametrize(
    ("area", "perim", "name"),
    [
        (-1.0, 4.0, "area_px"),
        (1.0, -4.0, "perimeter_px"),
        (np.nan, 4.0, "area_px"),
        (1.0, np.inf, "perimeter_px"),
    ],
)
def test_compactness_rejects_bad_values(area: float, perim: float, name: str) -> None:
    with pytest.raises(ValueError, match=f"{name}: expected finite values >= 0"):
        compactness(area, perim)


@pytest.mark.parametrize("r", [20, 30, 50, 100])
@pytest.mark.parametrize("method", ["kb", "crofton"])
def test_disk_compactness_is_one(r: float, method: str) -> None:
    rng = np.random.default_rng(int(r))
    for u, v in rng.random((3, 2)):
        assert compactness_of(disk(r, (r + 4 + u, r + 4 + v)), method) == pytest.approx(
            1.0, abs=0.05
        )


@pytest.mark.parametrize("side", [40, 60])
@pytest.mark.parametrize("angle_deg", [10.0, 22.5, 30.0, 60.0])
@pytest.mark.parametrize("method", ["kb", "crofton"])
def test_rotated_square_compactness_is_pi_over_4(side: int, angle_deg: float, method: str) -> None:
    value = compactness_of(rotated_rect(side, side, math.radians(angle_deg)), method)
    assert value == pytest.approx(math.pi / 4, abs=0.05)


@pytest.mark.parametrize("side", [40, 60, 100])
def test_axis_aligned_square_kb_compactness_known_answer(side: int) -> None:
    # The KB chain of an s × s square is 4·(s − 1) isothetic steps, each weighing a:
    # compactness = 4π·s² / (4·a·(s − 1))² = (π/4)·(s/(s − 1))² / a² ≈ 0.85 … 0.90.
    binary = np.zeros((side + 4, side + 4), np.uint8)
    binary[2 : 2 + side, 2 : 2 + side] = 1
    expected = (math.pi / 4) * (side / (side - 1)) ** 2 / KB_A**2
    assert compactness_of(binary, "kb") == pytest.approx(expected, rel=1e-12)
    # KB reads isothetic edges 3.96 % short (its minimax design), so an axis-aligned
    # square is not within π/4 ± 0.05 with KB; the 8-direction Crofton estimator is.
    assert expected > math.pi / 4 / KB_A**2 > math.pi / 4 + 0.05
    assert abs(compactness_of(binary, "crofton") - math.pi / 4) < 0.05


def test_elongated_rectangle_is_less_compact_than_square() -> None:
    square = compactness_of(rotated_rect(40, 40, 0.3), "kb")
    slab = compactness_of(rotated_rect(80, 20, 0.3), "kb")
    assert slab < square
    assert slab == pytest.approx(4 * math.pi * 1600 / 200**2, abs=0.05)  # 0.503


# --- orientation -------------------------------------------------------------------------


def moments_of(binary: np.ndarray) -> tuple[float, float, float]:
    comp = label_components(binary)
    assert comp.count == 1
    return comp.mu_rr[0], comp.mu_cc[0], comp.mu_rc[0]


@pytest.mark.parametrize("angle_deg", [0.0, 15.0, 45.0, 70.0, 90.0, -30.0, -60.0])
def test_orientation_of_rotated_rectangle(angle_deg: float) -> None:
    theta = math.radians(angle_deg)
    angle, elongation = orientation(*moments_of(rotated_rect(60, 20, theta)))
    # Fold into (−π/2, π/2].
    expected = math.atan2(math.sin(2 * theta), math.cos(2 * theta)) / 2
    if expected == -math.pi / 2:
        expected = math.pi / 2
    assert float(angle) == pytest.approx(expected, abs=math.radians(1.0))
    assert float(elongation) == pytest.approx(3.0, rel=0.05)


def test_orientation_axis_conventions() -> None:
    # Major axis along +row → 0; along +col → +π/2 (never −π/2, also with mu_rc = −0.0).
    angle, elong = orientation(4.0, 1.0, 0.0)
    assert (float(angle), float(elong)) == (0.0, 2.0)
    angle, elong = orientation(1.0, 4.0, -0.0)
    assert float(angle) == math.pi / 2 and float(elong) == 2.0
    assert axis_deg(1.0, 4.0, -0.0) == 90.0 and axis_deg(4.0, 1.0, 0.0) == 0.0
    # Along the row = col diagonal → +π/4; along row = −col → −π/4.
    assert float(orientation(1.0, 1.0, 0.5)[0]) == pytest.approx(math.pi / 4)
    assert float(orientation(1.0, 1.0, -0.5)[0]) == pytest.approx(-math.pi / 4)


def test_orientation_degenerate_cases_are_finite() -> None:
    # Single pixel: all moments 0 → angle 0, elongation 1.
    angle, elong = orientation(0.0, 0.0, 0.0)
    assert (float(angle), float(elong)) == (0.0, 1.0)
    # One-pixel-wide line: λ₋ = 0 → capped elongation.
    line = np.zeros((5, 30), np.uint8)
    line[2, 3:25] = 1
    angle, elong = orientation(*moments_of(line))
    assert float(angle) == pytest.approx(math.pi / 2)
    assert float(elong) == MAX_ELONGATION
    # A diagonal line has λ₋ = 0 up to rounding: still capped and finite.
    angle, elong = orientation(*moments_of(np.eye(20, dtype=np.uint8)))
    assert float(angle) == pytest.approx(math.pi / 4)
    assert np.isfinite(elong) and float(elong) > 1e5


def test_orientation_of_disk_and_batch() -> None:
    mu = np.array([moments_of(disk(25, (29.3, 29.8))), (9.0, 1.0, 0.0), (0.0, 0.0, 0.0)])
    angle, elong = orientation(mu[:, 0], mu[:, 1], mu[:, 2])
    assert angle.shape == elong.shape == (3,)
    assert elong[0] == pytest.approx(1.0, abs=0.01)
    np.testing.assert_allclose(elong[1:], [3.0, 1.0])


@settings(max_examples=100, deadline=None)
@given(
    st.floats(0.0, 1e4),
    st.floats(0.0, 1e4),
    st.floats(-math.pi, math.pi),
)
def test_orientation_properties(l1: float, l2: float, phi: float) -> None:
    # A covariance with eigenvalues l1, l2 whose first axis is at angle phi.
    c, s = math.cos(phi), math.sin(phi)
    mu_rr = l1 * c * c + l2 * s * s
    mu_cc = l1 * s * s + l2 * c * c
    mu_rc = (l1 - l2) * s * c
    angle, elong = orientation(mu_rr, mu_cc, mu_rc)
    assert -math.pi / 2 < float(angle) <= math.pi / 2
    assert 1.0 <= float(elong) <= MAX_ELONGATION
    assert axis_deg(mu_rr, mu_cc, mu_rc) == pytest.approx(math.degrees(angle), abs=1e-12)
    hi, lo = max(l1, l2), min(l1, l2)
    if hi > 1e-6 and lo > 1e-3 * hi:
        assert float(elong) == pytest.approx(math.sqrt(hi / lo), rel=1e-6)
        if hi > 1.01 * lo:  # the major axis is defined: it is phi (l1) or phi + π/2 (l2)
            major = phi if l1 > l2 else phi + math.pi / 2
            diff = (float(angle) - major) % math.pi
            assert min(diff, math.pi - diff) < 1e-6
