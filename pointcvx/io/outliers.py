"""Statistical outlier removal: points far from their k nearest neighbours compared with the rest.

Shared by the scan and splat loaders. The rule is open3d's: the statistic is each point's mean
distance to its ``k`` nearest neighbours, and a point is an outlier when that statistic exceeds
its mean over all points by more than ``std_ratio`` standard deviations.
"""

from __future__ import annotations

import numpy as np

from .orient import knn


def outlier_mask(points: np.ndarray, k: int, std_ratio: float) -> np.ndarray:
    """(n,) bool, True for the statistical outliers among (n, 3) float ``points``.

    Parameters
    ----------
    points : (n, 3) float
    k : int
        Neighbours of each point; 0 (or no more points than ``k + 1``) finds no outlier.
    std_ratio : float
        Standard deviations above the mean of the statistic where outliers begin.
    """
    n = len(points)
    if k <= 0 or n <= k + 1:
        return np.zeros(n, dtype=bool)
    dist, _ = knn(points, k)
    mean_d = dist.mean(axis=1)
    return mean_d > mean_d.mean() + std_ratio * mean_d.std()
