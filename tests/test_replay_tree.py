"""SumTree and MinTree against brute force (np.cumsum / np.searchsorted / np.min)."""

import numpy as np
import pytest

from dqn_mine.replay import MinTree, SumTree

CAPACITIES = [1, 7, 1000, 100003]


def _random_updates(rng, tree_pairs, values, rounds, batch):
    """Apply the same random batched updates (with duplicates) to the trees and to ``values``."""
    cap = values.shape[0]
    for _ in range(rounds):
        idx = rng.integers(0, cap, batch)
        new = rng.integers(0, 5, batch).astype(np.float64)     # integers: exact sums, many zeros
        for tree, transform in tree_pairs:
            tree.update(idx, transform(new))
        # duplicates: numpy's fancy assignment keeps the last value, as the trees do
        values[idx] = new


@pytest.mark.parametrize("cap", CAPACITIES)
def test_sum_tree_matches_cumsum(cap):
    rng = np.random.default_rng(cap)
    tree, values = SumTree(cap), np.zeros(cap)
    _random_updates(rng, [(tree, lambda v: v)], values, rounds=20, batch=min(512, 2 * cap))
    if values.sum() == 0:
        tree.update([0], [3.0])
        values[0] = 3.0
    cum = np.cumsum(values)
    assert tree.total() == cum[-1]
    np.testing.assert_array_equal(tree.values, values)
    u = rng.random(4096) * cum[-1]
    np.testing.assert_array_equal(tree.find(u), np.searchsorted(cum, u, side="right"))
    # exact boundaries: u == cumsum[i] belongs to the next positive leaf, never to a zero one
    u = np.concatenate([[0.0], cum[:-1][cum[:-1] < cum[-1]]])
    found = tree.find(u)
    np.testing.assert_array_equal(found, np.searchsorted(cum, u, side="right"))
    assert (values[found] > 0).all()


@pytest.mark.parametrize("cap", CAPACITIES)
def test_zero_leaves_never_found(cap):
    rng = np.random.default_rng(1)
    tree = SumTree(cap)
    values = np.where(rng.random(cap) < 0.7, 0.0, rng.random(cap))
    values[-1] = 0.0                             # a zero at the very end: u near total
    if not values.any():
        values[0] = 0.5
    tree.update(np.arange(cap), values)
    u = np.concatenate([rng.random(2000) * tree.total(),
                        [0.0, np.nextafter(tree.total(), 0), tree.total()]])  # past the end too
    found = tree.find(u)
    assert (values[found] > 0).all()
    idx, vals = tree.find_with_values(u)
    np.testing.assert_array_equal(idx, found)
    np.testing.assert_array_equal(vals, values[found])


def test_rounding_past_a_zero_leaf_takes_the_last_positive_leaf():
    # tiny values next to a huge one: partial sums round, the search must still avoid zeros
    cap = 5000
    values = np.zeros(cap)
    values[::3] = 1e-12
    values[17] = 1e12
    tree = SumTree(cap)
    tree.update(np.arange(cap), values)
    u = np.linspace(0, tree.total(), 20001)
    assert (values[tree.find(u)] > 0).all()


def test_sum_tree_update_recomputes_not_accumulates():
    tree = SumTree(1000)
    rng = np.random.default_rng(0)
    for _ in range(2000):                        # many float updates: no drift
        tree.update(rng.integers(0, 1000, 32), rng.random(32) * 1e-3 + 1e3 * rng.random())
    assert tree.total() == pytest.approx(tree.values.sum(), rel=1e-12)
    tree.update(np.arange(1000), np.zeros(1000))
    assert tree.total() == 0.0
    with pytest.raises(ValueError):
        tree.find([0.0])


@pytest.mark.parametrize("cap", CAPACITIES)
def test_min_tree_matches_min(cap):
    rng = np.random.default_rng(cap + 1)
    tree, values = MinTree(cap), np.full(cap, np.inf)
    assert tree.min() == np.inf
    _random_updates(rng, [(tree, lambda v: np.where(v > 0, v, np.inf))], values, rounds=20,
                    batch=min(512, 2 * cap))
    values = np.where(values > 0, values, np.inf)
    assert tree.min() == values.min()
    np.testing.assert_array_equal(tree.values, values)
    tree.update(np.arange(cap), np.full(cap, np.inf))
    tree.update([cap - 1], [0.25])
    assert tree.min() == 0.25


def test_sum_tree_find_is_vectorised_over_the_batch():
    tree = SumTree(2 ** 16)
    tree.update(np.arange(2 ** 16), np.ones(2 ** 16))
    u = np.arange(2 ** 16) + 0.5
    np.testing.assert_array_equal(tree.find(u), np.arange(2 ** 16))
