"""Connected pieces of a point cloud: points closer than a few of their local spacings belong
together (a k-NN graph with gaps scaled to each point's own spacing, so sparse far regions of a
depth frame stay whole). A point's spacing is the distance to its :data:`SPACING_RANK`-th
neighbour, so that a close pair or triple of points is not a piece of its own."""

from __future__ import annotations

import numpy as np

from ..workers import kd_workers

#: Neighbours per point in the graph.
NEIGHBORS = 8
#: An edge joins two points closer than this many times the larger of their local spacings.
GAP_FACTOR = 3.0
#: The neighbour whose distance is a point's local spacing.
SPACING_RANK = 4


def components(points: np.ndarray, *, neighbors: int = NEIGHBORS, gap: float = GAP_FACTOR) -> np.ndarray:
    """(n,) int64 labels of the connected pieces of (n, 3) ``points``, largest piece first (label 0).

    A point's local spacing is the distance to its :data:`SPACING_RANK`-th neighbour; an edge of
    the k-NN graph is kept when shorter than ``gap`` times the larger spacing of its two ends.
    """
    from scipy import sparse
    from scipy.sparse import csgraph
    from scipy.spatial import cKDTree

    pts = np.asarray(points, dtype=np.float64)
    n = len(pts)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    k = min(neighbors + 1, n)
    dist, idx = cKDTree(pts).query(pts, k=k, workers=kd_workers(n))
    dist, idx = dist.reshape(n, k), idx.reshape(n, k)
    spacing = dist[:, min(SPACING_RANK, k - 1)]
    limit = gap * np.maximum(spacing[:, None], spacing[idx])
    keep = (dist <= limit) & (idx != np.arange(n)[:, None])
    rows = np.repeat(np.arange(n), k)[keep.ravel()]
    graph = sparse.coo_matrix((np.ones(len(rows)), (rows, idx.ravel()[keep.ravel()])), shape=(n, n))
    _, labels = csgraph.connected_components(graph, directed=False)
    sizes = np.bincount(labels)
    order = np.argsort(-sizes, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return rank[labels].astype(np.int64)
