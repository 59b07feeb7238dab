"""Which Gaussians a splat load keeps: finite, opaque enough, not floating; and their weights."""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from ...cloud import MAX_COORDINATE
from ..orient import knn

#: Largest Gaussian accepted, as a multiple of the diagonal of the centres' bounding box: a
#: Gaussian larger than the whole splat models no surface (a log-scale of 80 is e^80 units).
MAX_SCALE_RATIO = 1.0


def finite_mask(g: dict[str, np.ndarray]) -> np.ndarray:
    """(n,) bool: Gaussians whose centre, scales, rotation and opacity are all finite."""
    ok = np.isfinite(g["centers"]).all(axis=1)
    ok &= np.isfinite(g["scales"]).all(axis=1)
    ok &= np.isfinite(g["rotations"]).all(axis=1)
    ok &= np.isfinite(g["opacity"])
    return ok


def range_mask(g: dict[str, np.ndarray]) -> np.ndarray:
    """(n,) bool: Gaussians (finite ones) whose centre lies within :data:`MAX_COORDINATE`."""
    return np.abs(g["centers"]).max(axis=1, initial=0.0) <= MAX_COORDINATE


def scale_mask(g: dict[str, np.ndarray], ratio: float = MAX_SCALE_RATIO) -> np.ndarray:
    """(n,) bool: Gaussians (finite ones) no larger than ``ratio`` x the diagonal of the bounding
    box of all centres; all kept when the centres have no extent."""
    c = g["centers"]
    if len(c) == 0:
        return np.ones(0, dtype=bool)
    diagonal = float(np.linalg.norm(c.max(axis=0) - c.min(axis=0)))
    if not diagonal > 0:
        return np.ones(len(c), dtype=bool)
    return g["scales"].max(axis=1) <= ratio * diagonal


def opacity_mask(g: dict[str, np.ndarray], min_opacity: float) -> np.ndarray:
    """(n,) bool: Gaussians whose opacity is at least ``min_opacity``."""
    return g["opacity"] >= min_opacity


def floater_mask(points: np.ndarray, ratio: float, k: int = 8, factor: float = 4.0) -> np.ndarray:
    """(n,) bool keeping points whose cluster holds at least ``ratio`` of all points.

    Clusters are connected components of the k-nearest-neighbour graph with edges longer than
    ``factor`` x the median k-th neighbour distance cut. When no cluster is big enough, the
    largest one is kept.
    """
    n = len(points)
    keep = np.ones(n, dtype=bool)
    if ratio <= 0 or n <= k + 1:
        return keep
    dist, idx = knn(points, k)
    radius = factor * float(np.median(dist[:, -1]))
    edges = dist.ravel() <= radius
    rows = np.repeat(np.arange(n), idx.shape[1])[edges]
    graph = sparse.coo_matrix((np.ones(int(edges.sum())), (rows, idx.ravel()[edges])), shape=(n, n))
    _, labels = csgraph.connected_components(graph, directed=False)
    sizes = np.bincount(labels)
    big = sizes >= ratio * n
    if not big.any():
        big[np.argmax(sizes)] = True
    return big[labels]


def gaussian_weights(g: dict[str, np.ndarray]) -> np.ndarray:
    """(n,) float importance of each Gaussian: opacity x geometric mean of its three scales."""
    return g["opacity"] * np.cbrt(np.prod(np.maximum(g["scales"], 0.0), axis=1))
