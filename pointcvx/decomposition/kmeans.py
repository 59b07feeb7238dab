"""Two-way k-means in numpy: the split of a part in the feature + position embedding.

Lloyd's iterations from a greedy k-means++ start, best inertia of ``n_init`` starts, as
scikit-learn's ``KMeans(n_clusters=2)`` does; written out because importing
``sklearn.cluster`` costs a process about 0.5 s (its import pulls in ``scipy.stats``) and each
``KMeans.fit`` call several milliseconds of set-up, for a problem of a few thousand points in
about 35 dimensions. Deterministic for a seed.
"""

from __future__ import annotations

import numpy as np


def _sq_dist(x: np.ndarray, centres: np.ndarray, x_sq: np.ndarray) -> np.ndarray:
    """(n, k) squared distances of (n, d) ``x`` (with (n,) squared norms ``x_sq``) to (k, d)
    ``centres``, clipped at 0 against round-off."""
    d = x_sq[:, None] - 2.0 * (x @ centres.T) + (centres * centres).sum(1)[None, :]
    return np.maximum(d, 0.0)


def _plus_plus(x: np.ndarray, x_sq: np.ndarray, rng: np.random.Generator, n_trials: int = 2) -> np.ndarray:
    """(2, d) greedy k-means++ start: a uniform first centre, then the best (lowest inertia)
    of ``n_trials`` candidates drawn with probability proportional to squared distance."""
    first = x[rng.integers(len(x))]
    d0 = _sq_dist(x, first[None], x_sq)[:, 0]
    total = float(d0.sum())
    if total <= 0.0:  # every point at the first centre: any second centre will do
        return np.stack([first, first])
    cand = np.searchsorted(np.cumsum(d0), rng.random(n_trials) * total, side="right")
    cand = np.minimum(cand, len(x) - 1)
    dc = _sq_dist(x, x[cand], x_sq)
    best = int(np.argmin(np.minimum(d0[:, None], dc).sum(0)))
    return np.stack([first, x[cand[best]]])


def _lloyd(x: np.ndarray, x_sq: np.ndarray, centres: np.ndarray, max_iter: int, tol: float):
    """Lloyd's iterations from (2, d) ``centres``: (final centres, inertia). Stops when the
    centres move less than ``tol`` (squared, summed) or after ``max_iter`` iterations; a
    cluster that empties keeps its centre."""
    for _ in range(max_iter):
        side = np.argmin(_sq_dist(x, centres, x_sq), axis=1).astype(bool)
        new = centres.copy()
        for k, members in enumerate((~side, side)):
            if members.any():
                new[k] = x[members].mean(axis=0)
        shift = float(((new - centres) ** 2).sum())
        centres = new
        if shift <= tol:
            break
    inertia = float(_sq_dist(x, centres, x_sq).min(axis=1).sum())
    return centres, inertia


def two_means(x: np.ndarray, seed: int = 0, n_init: int = 2, max_iter: int = 300,
              tol: float = 1e-4) -> np.ndarray:
    """(2, d) float64 centres of a two-way k-means of (n, d) float ``x`` (n >= 1).

    ``n_init`` greedy k-means++ starts, each refined by Lloyd's iterations; the one of lowest
    inertia wins. ``tol`` is relative to the mean per-dimension variance of ``x``, as in
    scikit-learn. Same seed, same centres.
    """
    x = np.asarray(x, dtype=np.float64)
    rng = np.random.default_rng(seed)
    x_sq = (x * x).sum(1)
    tol_abs = tol * float(x.var(axis=0).mean())
    best, best_inertia = None, np.inf
    for _ in range(max(int(n_init), 1)):
        centres, inertia = _lloyd(x, x_sq, _plus_plus(x, x_sq, rng), max_iter, tol_abs)
        if inertia < best_inertia:
            best, best_inertia = centres, inertia
    return best


def nearest_centre(x: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """(n,) bool: whether each of (n, d) ``x`` is nearer the second of the (2, d) ``centres``."""
    x = np.asarray(x, dtype=np.float64)
    d = _sq_dist(x, centres, (x * x).sum(1))
    return d[:, 1] < d[:, 0]
