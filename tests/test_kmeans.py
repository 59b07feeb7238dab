"""The split's two-way k-means (pointcvx.decomposition.kmeans) against scikit-learn's KMeans,
which it replaces: the same clusters where they are plain, an inertia within a tolerance of
scikit-learn's where they are not, seeded, and sane on degenerate parts."""

from __future__ import annotations

import numpy as np
import pytest

from pointcvx.decomposition.kmeans import nearest_centre, two_means


def _inertia(x, side):
    return sum(float(((x[m] - x[m].mean(0)) ** 2).sum()) for m in (side, ~side) if m.any())


def test_separated_blobs_are_found_exactly():
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.normal(0, 1, (700, 35)), rng.normal(4, 1, (300, 35))])
    side = nearest_centre(x, two_means(x, seed=3))
    truth = np.arange(1000) >= 700
    assert (side == truth).all() or (side == ~truth).all()


@pytest.mark.parametrize("seed", range(6))
def test_inertia_matches_scikit_learn(seed):
    """On features like the split's (unit features, a blended xyz) with no plain clusters, the
    result is as tight as scikit-learn's KMeans(n_clusters=2, n_init=2) within 2 %."""
    from sklearn.cluster import KMeans

    rng = np.random.default_rng(seed)
    f = rng.normal(size=(2000, 32))
    f /= np.linalg.norm(f, axis=1, keepdims=True)
    xyz = rng.uniform(-1, 1, (2000, 3))
    x = np.concatenate([f, 0.5 * xyz + 0.3 * (xyz[:, :1] > 0)], axis=1)
    mine = _inertia(x, nearest_centre(x, two_means(x, seed=seed)))
    theirs = KMeans(n_clusters=2, n_init=2, random_state=seed).fit(x).inertia_
    assert mine <= 1.02 * theirs, (mine, theirs)
    assert mine >= 0.9 * theirs  # the same objective, not something else


def test_same_seed_same_centres_and_seed_matters():
    x = np.random.default_rng(1).normal(size=(500, 8))
    np.testing.assert_array_equal(two_means(x, seed=4), two_means(x, seed=4))
    assert two_means(x, seed=4).shape == (2, 8)


def test_degenerate_parts():
    same = np.ones((50, 4))
    c = two_means(same, seed=0)
    np.testing.assert_array_equal(c, np.ones((2, 4)))
    assert not nearest_centre(same, c).any()  # ties go to the first centre
    one = np.array([[0.5, -1.0]])
    np.testing.assert_array_equal(two_means(one, seed=0), np.repeat(one, 2, axis=0))
    two = np.array([[0.0, 0.0], [1.0, 0.0]])
    assert nearest_centre(two, two_means(two, seed=0)).sum() == 1
