"""Radial distortion (eqs. 7–8): the solve converges and inverts the factor."""

from __future__ import annotations

import numpy as np
import pytest

from ovis.common.camera.distortion import distort_radius, undistort_factor


def test_solve_converges_over_the_paper_ranges() -> None:
    rng = np.random.default_rng(0)
    k = rng.uniform(-1e-6, 1e-6, size=(3, 1000, 1))
    rho_u = np.linspace(0.0, 5.0, 200)[None, :]  # mm; a 192-px image spans about ±1.4 mm
    rho_d, ok = distort_radius(rho_u, k[0], k[1], k[2])
    assert ok.all()
    back = rho_d * undistort_factor(rho_d, k[0], k[1], k[2])
    np.testing.assert_allclose(back, np.broadcast_to(rho_u, back.shape), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("k1,k2,k3", [(0.05, 0.0, 0.0), (-0.02, 0.001, 0.0), (0.0, 0.0, 0.003)])
def test_solve_converges_for_strong_distortion(k1, k2, k3) -> None:
    rho_u = np.linspace(0.0, 2.0, 101)
    rho_d, ok = distort_radius(rho_u, k1, k2, k3)
    back = rho_d * undistort_factor(rho_d, k1, k2, k3)
    np.testing.assert_allclose(back[ok], rho_u[ok], rtol=1e-12, atol=1e-15)
    assert ok[:50].all()


def test_unreachable_radius_is_reported_not_nan() -> None:
    # Strong barrel: g(ρ) = ρ(1 − 0.1ρ²) peaks at ρ = √(10/3), g ≈ 1.217; beyond, no image.
    rho_d, ok = distort_radius(np.array([1.0, 1.3, 5.0]), -0.1, 0.0, 0.0)
    assert ok.tolist() == [True, False, False]
    assert np.isfinite(rho_d).all()


def test_zero_distortion_is_identity() -> None:
    rho = np.array([0.0, 0.3, 1.7])
    rho_d, ok = distort_radius(rho, 0.0, 0.0, 0.0)
    assert ok.all()
    np.testing.assert_array_equal(rho_d, rho)
