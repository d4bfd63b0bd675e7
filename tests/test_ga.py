"""Binary GA (paper §4): operators and whole runs."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from ovis.common.calibration.ga import (
    bitwise_mutation,
    decode,
    run_ga,
    tournament_selection,
    two_point_crossover,
)
from ovis.common.config import GAConfig


def test_decode_maps_codes_linearly_onto_ranges() -> None:
    bounds = np.array([[100.0, 230.0], [-1e-6, 1e-6]])
    pop = np.zeros((3, 20), dtype=bool)
    pop[1] = True  # all ones -> upper bounds
    pop[2, 0] = True  # MSB of var 0 -> 512/1023
    pop[2, 19] = True  # LSB of var 1 -> 1/1023
    v = decode(pop, bounds, 10)
    np.testing.assert_allclose(v[0], [100.0, -1e-6])
    np.testing.assert_allclose(v[1], [230.0, 1e-6])
    np.testing.assert_allclose(v[2], [100.0 + 130.0 * 512 / 1023, -1e-6 + 2e-6 / 1023])


def test_gray_decoding_neighbours_differ_in_one_bit() -> None:
    bounds = np.array([[0.0, 15.0]])
    codes = np.array([[int(b) for b in f"{i ^ (i >> 1):04b}"] for i in range(16)], dtype=bool)
    np.testing.assert_array_equal(decode(codes, bounds, 4, gray=True)[:, 0], np.arange(16))
    assert (np.abs(np.diff(codes.astype(int), axis=0)).sum(axis=1) == 1).all()


def test_tournament_picks_the_best_entrant() -> None:
    rng = np.random.default_rng(0)
    fitness = np.arange(50, dtype=float)[::-1]  # index 49 is best
    winners = tournament_selection(fitness, 50, rng)
    # With 50 entrants drawn from 50, most tournaments include a top string.
    assert np.mean(fitness[winners]) < 3.0
    binary = tournament_selection(fitness, 2, np.random.default_rng(1))
    assert fitness[binary].mean() < fitness.mean()  # selection pressure


def test_two_point_crossover_swaps_one_segment_and_conserves_bits() -> None:
    rng = np.random.default_rng(3)
    a = np.zeros((1, 40), dtype=bool)
    b = np.ones((1, 40), dtype=bool)
    kids = two_point_crossover(np.vstack([a, b]), 1.0, rng)
    # Column-wise the pair keeps exactly one 0 and one 1.
    assert (kids.sum(axis=0) == 1).all()
    # The swapped part of the first child is one contiguous run.
    edges = np.flatnonzero(np.diff(kids[0].astype(int)))
    assert len(edges) <= 2
    same = two_point_crossover(np.vstack([a, b]), 0.0, rng)
    np.testing.assert_array_equal(same, np.vstack([a, b]))


def test_mutation_rate() -> None:
    pop = np.zeros((1000, 90), dtype=bool)
    flipped = bitwise_mutation(pop, 0.005, np.random.default_rng(0)).mean()
    assert flipped == pytest.approx(0.005, rel=0.1)


def _sphere(v: np.ndarray) -> np.ndarray:
    return np.sum((v - np.array([0.3, -0.7, 0.1])) ** 2, axis=1)


def test_ga_minimises_and_is_reproducible() -> None:
    cfg = GAConfig(population=60, generations=60, seed=7)
    bounds = [(-1.0, 1.0)] * 3
    r1 = run_ga(_sphere, bounds, cfg)
    r2 = run_ga(_sphere, bounds, cfg)
    assert r1.best_fitness < 1e-3
    np.testing.assert_allclose(r1.best_values, [0.3, -0.7, 0.1], atol=0.03)
    np.testing.assert_array_equal(r1.best_bits, r2.best_bits)
    assert [h.best for h in r1.history] == [h.best for h in r2.history]
    assert len(r1.history) == cfg.generations + 1
    best_so_far = [h.best_so_far for h in r1.history]
    assert all(b2 <= b1 for b1, b2 in itertools.pairwise(best_so_far))
    r3 = run_ga(_sphere, bounds, GAConfig(population=60, generations=60, seed=8))
    assert [h.mean for h in r1.history] != [h.mean for h in r3.history]  # another run


def test_dedupe_gives_identical_results_with_fewer_evaluations() -> None:
    cfg = GAConfig(population=40, generations=40, seed=3, pm=0.001)
    a = run_ga(_sphere, [(-1.0, 1.0)] * 3, cfg, dedupe=True)
    b = run_ga(_sphere, [(-1.0, 1.0)] * 3, cfg, dedupe=False)
    np.testing.assert_array_equal(a.best_bits, b.best_bits)
    assert a.history == b.history
    assert a.evaluations < b.evaluations == 40 * 41


def test_elitism_keeps_the_best() -> None:
    cfg = GAConfig(population=20, generations=30, seed=1, elitism=1)
    r = run_ga(_sphere, [(-1.0, 1.0)] * 3, cfg)
    bests = [h.best for h in r.history]
    assert all(b2 <= b1 for b1, b2 in itertools.pairwise(bests))


def test_progress_callback_and_infeasible_mean() -> None:
    seen = []

    def fit(v: np.ndarray) -> np.ndarray:
        f = _sphere(v)
        return np.where(v[:, 0] > 0, f, 1e6)  # half the box is infeasible

    r = run_ga(
        fit,
        [(-1.0, 1.0)] * 3,
        GAConfig(population=30, generations=5, seed=0),
        on_generation=seen.append,
        feasible_below=1e6,
    )
    assert [s.generation for s in seen] == list(range(6))
    assert all(s.mean < 1e6 for s in r.history)
    assert all(0.0 < s.feasible_fraction <= 1.0 for s in r.history)
