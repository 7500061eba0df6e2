"""Broad phase: the grid and sweep-and-prune find exactly the overlapping pairs that the
all-pairs test finds (the truth), including planes and oversized boxes."""

from __future__ import annotations

from unittest import mock

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from vrsim_cli.stages.collision import broadphase
from vrsim_cli.stages.collision.broadphase import candidate_pairs


def boxes(seed: int, n: int, spread: float, large: int = 0, planes: int = 0):
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-spread, spread, (n, 3))
    half = rng.uniform(0.05, 0.5, (n, 3))
    half[:large] *= 40.0  # a ground slab, a long wall
    lo, hi = centre - half, centre + half
    lo[n - planes:], hi[n - planes:] = -np.inf, np.inf
    return lo, hi


def all_pairs(lo, hi):
    """The truth, pair by pair in plain Python: boxes overlap (touching counts) when
    they do on every axis."""
    return [(i, j) for i in range(len(lo)) for j in range(i + 1, len(lo))
            if all(lo[i, a] <= hi[j, a] and lo[j, a] <= hi[i, a] for a in range(3))]


def pairs(lo, hi, method):
    i, j = candidate_pairs(lo, hi, method)
    assert np.all(i < j)
    return list(zip(i.tolist(), j.tolist()))


@settings(max_examples=60, derandomize=True, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(0, 300),
       spread=st.floats(0.1, 20.0), large=st.integers(0, 3), planes=st.integers(0, 2))
def test_grid_and_sweep_and_prune_find_the_all_pairs_answer(seed, n, spread, large, planes):
    lo, hi = boxes(seed, n, spread, min(large, n), min(planes, n))
    truth = all_pairs(lo, hi)
    assert pairs(lo, hi, "brute") == truth
    assert pairs(lo, hi, "grid") == truth  # sorted by (i, j), no duplicates
    assert pairs(lo, hi, "sap") == truth
    # the grid and sweep and prune themselves also below ALL_PAIRS_N, where
    # candidate_pairs tests every pair instead
    with mock.patch.object(broadphase, "ALL_PAIRS_N", 1):
        assert pairs(lo, hi, "grid") == truth
        assert pairs(lo, hi, "sap") == truth


def test_touching_boxes_count_as_overlapping():
    lo = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    hi = lo + 1.0
    for method in ("grid", "sap", "brute"):
        assert pairs(lo, hi, method) == [(0, 1), (1, 2)]


def test_identical_boxes_in_one_cell_pair_once():
    lo = np.zeros((5, 3))
    hi = np.ones((5, 3))
    expected = [(i, j) for i in range(5) for j in range(i + 1, 5)]
    assert pairs(lo, hi, "grid") == expected == pairs(lo, hi, "sap")


def test_boxes_touching_exactly_far_from_the_origin_are_paired():
    """Centres near 1000 m carry rounding of an ulp: two boxes that touch exactly (overlap
    0) must still land in neighbouring cells (found by review; brute force is the truth)."""
    lo = np.array([[-999.9999333333334, -1000.0, -999.9999],
                   [-1000.0000666666666, -1000.0001666666667, -999.9999],
                   [-999.9999, -999.9999666666666, -999.9999333333334]])
    hi = np.array([[-999.9999, -999.9999666666666, -999.9998666666667],
                   [-1000.0000333333332, -1000.0001333333333, -999.9998666666667],
                   [-999.9998666666667, -999.9999333333333, -999.9999]])
    expected = broadphase.brute_force(lo, hi)
    assert (0, 2) in set(zip(*[x.tolist() for x in expected]))
    for method in ("grid", "sap"):
        got = broadphase.candidate_pairs(lo, hi, method)
        assert [x.tolist() for x in got] == [x.tolist() for x in expected]


def test_a_few_boxes_give_the_all_pairs_answer_on_every_path():
    """Around ALL_PAIRS_N (the all-at-once path below it, the grid and sweep and prune
    above it): dense and sparse boxes, oversized ones, planes, touching ones."""
    for n in range(broadphase.ALL_PAIRS_N + 4):
        for seed in range(12):
            lo, hi = boxes(seed, n, spread=0.3 + seed, large=min(seed % 3, n),
                           planes=min(seed % 2, n))
            if seed % 4 == 3 and n >= 2:  # two boxes touching exactly on a face
                hi[1, 0] = lo[0, 0]
            truth = all_pairs(lo, hi)
            for method in ("grid", "sap", "brute"):
                assert pairs(lo, hi, method) == truth, (n, seed, method)
