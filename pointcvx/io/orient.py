"""Normals for point sets: estimation, consistent orientation, and a global outward sign.

Used by every loader whose input has no trustworthy normals (scans, splats). Orientation follows
Hoppe et al.: propagate signs along a minimum spanning tree of the k-nearest-neighbour graph,
weighted by 1 - |n_i . n_j| so the tree prefers flat neighbourhoods; then each connected piece is
turned outward by a vote of its points on the convex hull of the whole set.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import ConvexHull, QhullError, cKDTree


def knn(points: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, k) float distances and (n, k) int indices of each point's k nearest others."""
    k = int(min(k, len(points) - 1))
    tree = cKDTree(points)
    dist, idx = tree.query(points, k=k + 1, workers=-1)
    return dist[:, 1:], idx[:, 1:]


def estimate_normals(points: np.ndarray, k: int = 24) -> np.ndarray:
    """(n, 3) unit normals (unoriented) from PCA of each point's ``k`` nearest neighbours.

    The normal is the eigenvector of the smallest eigenvalue of the neighbourhood covariance.
    """
    _, idx = knn(points, k)
    nb = points[idx]  # (n, k, 3), gathered once and centred in place
    nb -= nb.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb)
    _, vecs = np.linalg.eigh(cov)  # ascending eigenvalues
    normals = vecs[:, :, 0]
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def propagate_signs(n: int, edges: np.ndarray, relative: np.ndarray,
                    weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Signs that satisfy ``sign[i] * sign[j] == relative[e]`` along a spanning tree.

    Parameters
    ----------
    n : int
        Number of nodes.
    edges : (m, 2) int
        Undirected edges.
    relative : (m,) float of +-1
        Wanted relative sign of each edge's two nodes.
    weights : (m,) float, optional
        With weights, the minimum spanning tree is used (most trusted edges first); without, a
        breadth-first tree.

    Returns
    -------
    sign : (n,) float of +-1
    labels : (n,) int, the connected piece of each node.
    """
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    rel = np.where(np.asarray(relative) < 0, -1.0, 1.0)
    w = np.ones(len(edges)) if weights is None else np.asarray(weights, dtype=np.float64) + 1e-9
    # One undirected edge per node pair, keeping its smallest weight (most trusted relation).
    lo, hi = np.minimum(edges[:, 0], edges[:, 1]), np.maximum(edges[:, 0], edges[:, 1])
    keep = lo != hi
    lo, hi, w, rel = lo[keep], hi[keep], w[keep], rel[keep]
    # by pair, then weight: the pair as one key (lo * n + hi orders as (lo, hi) does), which
    # halves lexsort's work (0.24 s against 0.43 s at a million edges), the same order
    order = np.lexsort((w, lo * np.int64(n) + hi))
    lo, hi, w, rel = lo[order], hi[order], w[order], rel[order]
    first = np.ones(len(lo), dtype=bool)
    first[1:] = (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])
    lo, hi, w, rel = lo[first], hi[first], w[first], rel[first]
    tree, relm, labels = sign_tree(n, lo, hi, w, rel, spanning=weights is not None)
    # Each node's parent in its piece's BFS tree and the relative sign r to it:
    # sign[child] = sign[parent] * r, i.e. a node's sign is the product of the r along its path
    # to its root. The products are gathered by pointer jumping (each round doubles the length of
    # path covered), not node by node; products of +-1 are exact, so the signs are the same.
    up, step = np.arange(n), np.ones(n)
    for root in np.unique(labels, return_index=True)[1]:
        order, pred = csgraph.breadth_first_order(tree, int(root), directed=False)
        if len(order) < 2:
            continue
        children, parents = order[1:], pred[order[1:]]
        r = np.sign(np.asarray(relm[children, parents]).ravel())
        r[r == 0] = 1.0
        up[children], step[children] = parents, r
    while True:
        far = up[up]
        if np.array_equal(far, up):  # every node points at its root, whose step is 1
            break
        step, up = step * step[up], far
    return step, labels


def sign_tree(n: int, lo: np.ndarray, hi: np.ndarray, w: np.ndarray, rel: np.ndarray, *,
              spanning: bool):
    """The graph :func:`propagate_signs` walks, from its (m,) node pairs ``lo`` < ``hi`` (each
    pair once) with weights ``w`` and relative signs ``rel``: (the symmetric (n, n) tree, its
    minimum spanning tree where ``spanning``, else the whole graph; the symmetric (n, n)
    relative signs; (n,) int connected piece of each node)."""
    graph = sparse.coo_matrix((w, (lo, hi)), shape=(n, n)).tocsr()
    tree = csgraph.minimum_spanning_tree(graph) if spanning else graph
    tree = (tree + tree.T).tocsr()
    relm = sparse.coo_matrix((rel, (lo, hi)), shape=(n, n)).tocsr()
    relm = relm + relm.T
    _, labels = csgraph.connected_components(tree, directed=False)
    return tree, relm, labels


def _propagate(points: np.ndarray, normals: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Signs (n,) of +-1 making normals consistent along an MST of the k-NN graph; labels (n,)."""
    n = len(points)
    _, idx = knn(points, k)
    edges = np.stack([np.repeat(np.arange(n), idx.shape[1]), idx.ravel()], axis=1)
    dots = np.einsum("ij,ij->i", normals[edges[:, 0]], normals[edges[:, 1]])
    # Prefer edges that lie in both tangent planes: across a thin gap or a sharp fold the edge
    # runs along a normal, and propagating through it is where signs go wrong.
    e = points[edges[:, 1]] - points[edges[:, 0]]
    e /= np.maximum(np.linalg.norm(e, axis=1, keepdims=True), 1e-12)
    across = np.abs(np.einsum("ij,ij->i", normals[edges[:, 0]], e)) + np.abs(
        np.einsum("ij,ij->i", normals[edges[:, 1]], e))
    return propagate_signs(n, edges, np.sign(dots), weights=1.0 - np.abs(dots) + across)


def outward_score(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(n,) float, positive where a normal agrees with the outward direction of the convex hull.

    Points on the hull score ``n . hull_normal`` summed over their hull facets; the others score
    ``1e-3 n . (p - centroid)``, a weak vote that only decides pieces with no hull point. Summed
    over a piece, the sign says whether the piece faces out.
    """
    votes = np.einsum("ij,ij->i", normals, points - points.mean(axis=0)) * 1e-3
    try:
        hull = ConvexHull(points)
    except (QhullError, ValueError):
        return votes
    eq = hull.equations  # (f, 4) outward unit normals + offset
    for facet, simplex in enumerate(hull.simplices):
        votes[simplex] += normals[simplex] @ eq[facet, :3]
    return votes


def orient_normals(points: np.ndarray, normals: np.ndarray, k: int = 12) -> tuple[np.ndarray, int]:
    """Make (n, 3) ``normals`` consistent and outward; return them and how many were flipped.

    Each connected piece of the k-NN graph is oriented by MST propagation and then flipped as a
    whole if most of its hull points disagree with the hull's outward normals.
    """
    if len(points) < 3:
        return normals.copy(), 0
    sign, labels = _propagate(points, normals, k)
    oriented = normals * sign[:, None]
    votes = outward_score(points, oriented)
    for label in np.unique(labels):
        members = labels == label
        if votes[members].sum() < 0:
            sign[members] *= -1
    out = normals * sign[:, None]
    return out, int((sign < 0).sum())
