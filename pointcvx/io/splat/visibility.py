"""Outward normals by visibility: votes of the directions from which each point is seen."""

from __future__ import annotations

import numpy as np

from ..orient import knn

#: Neighbours of the k-NN graph along which normal signs are propagated.
ORIENT_NEIGHBORS = 12
#: Directions the cloud is z-buffered from to tell the outside of each surface piece.
VISIBILITY_VIEWS = 32


def view_directions(m: int) -> np.ndarray:
    """(m, 3) unit vectors spread evenly over the sphere (Fibonacci lattice)."""
    i = np.arange(m) + 0.5
    polar = np.arccos(1.0 - 2.0 * i / m)
    azimuth = np.pi * (1.0 + np.sqrt(5.0)) * i
    return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)],
                    axis=1)


def visibility_votes(points: np.ndarray, normals: np.ndarray, views: int = VISIBILITY_VIEWS,
                     pixel: float = 2.0, spacing: float | None = None,
                     depth_tolerance: float = 3.0, layer_gap: float = 2.0) -> np.ndarray:
    """(n,) float: how strongly each normal faces the directions its point is seen from.

    The points are z-buffered orthographically from ``views`` directions ``v`` around the cloud,
    with square pixels ``pixel`` x the median distance to the 4th neighbour (``spacing``), so the
    splat looks closed. In each pixel, going back from the front-most point, the points of the
    first layer are seen from ``v``: those before the first depth gap wider than ``layer_gap``
    spacings, at most ``depth_tolerance`` pixels behind the front. Each votes ``n . v``.
    Outward normals face the outside, where an onlooker stands, so a positive sum means
    'outward'; thin parts (a guitar neck) get their two sides right, which sign propagation
    along a neighbour graph cannot. Zero for points never seen.

    Why layers: Gaussian centres scatter in depth, so a tolerance of a few pixels finds more of
    a noisy front surface, but a plain tolerance also takes the far side of a thin wall (the
    inside of a cup would vote with its outside); the gap test stops the layer at the wall's
    back, so the tolerance can stay wide.
    """
    n = len(points)
    votes = np.zeros(n)
    if n < 5:
        return votes
    if spacing is None:
        spacing = float(np.median(knn(points, 4)[0][:, -1]))
    centered = points - points.mean(axis=0)
    extent = float(np.linalg.norm(centered, axis=1).max())
    h = max(pixel * spacing, extent / 2048.0, 1e-12)
    # (A spacing of 0, from duplicated centres, would make every step a gap.)
    gap = layer_gap * max(spacing, h / pixel)
    for v in view_directions(views):
        a = np.cross(v, (1.0, 0.0, 0.0) if abs(v[0]) < 0.9 else (0.0, 1.0, 0.0))
        a /= np.linalg.norm(a)
        b = np.cross(v, a)
        u = np.floor(centered @ a / h).astype(np.int64)
        w = np.floor(centered @ b / h).astype(np.int64)
        u -= u.min()
        w -= w.min()
        key = u * (int(w.max()) + 1) + w
        depth = centered @ v  # larger is nearer to an onlooker far out along +v
        seen = np.zeros(n, dtype=bool)
        seen[first_layer(key, depth, gap, depth_tolerance * h)] = True
        votes[seen] += normals[seen] @ v
    return votes


def first_layer(key: np.ndarray, depth: np.ndarray, gap: float, tolerance: float) -> np.ndarray:
    """Indices of the points in the front layer of their pixel: (n,) int ``key`` pixel ids,
    (n,) float ``depth`` (larger is nearer). Going back from the front-most point of a pixel, a
    layer ends at the first step deeper than ``gap`` or ``tolerance`` behind the front."""
    if len(key) == 0:
        return np.zeros(0, dtype=np.int64)
    order = np.lexsort((-depth, key))  # by pixel, front first
    k, d = key[order], depth[order]
    first = np.r_[True, k[1:] != k[:-1]]
    group = np.cumsum(first) - 1
    step = np.r_[0.0, d[:-1] - d[1:]]
    broken = np.cumsum((step > gap) & ~first)
    passed = broken - broken[first][group] > 0  # a wide step lies between the front and here
    return order[~passed & (d >= d[first][group] - tolerance)]


def orient_by_visibility(points: np.ndarray, normals: np.ndarray, views: int = VISIBILITY_VIEWS,
                         k: int = ORIENT_NEIGHBORS, min_vote: float = 0.5,
                         neighbors: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, int]:
    """Flip (n, 3) consistently signed ``normals`` where :func:`visibility_votes` disagree.

    Each point's vote is smoothed with those of its ``k`` nearest neighbours lying along its
    tangent plane (``|edge . n| < 0.5``, so the far side of a thin part does not count), each
    counted as ``vote_j (n_i . n_j)``. Points whose score reaches ``min_vote`` take its sign; the
    others keep theirs. ``neighbors`` may pass precomputed ``knn(points, >= max(k, 4))``.
    Returns the normals and how many changed sign.
    """
    dist, idx = knn(points, max(k, 4)) if neighbors is None else neighbors
    votes = visibility_votes(points, normals, views, spacing=float(np.median(dist[:, 3])))
    idx = idx[:, :k]
    edge = points[idx] - points[:, None, :]
    edge /= np.maximum(np.linalg.norm(edge, axis=2, keepdims=True), 1e-300)
    tangential = np.abs(np.einsum("nkj,nj->nk", edge, normals)) < 0.5
    align = np.einsum("nkj,nj->nk", normals[idx], normals)
    count = np.maximum(tangential.sum(axis=1), 1)
    score = votes + 3.0 * (votes[idx] * align * tangential).sum(axis=1) / count
    flip = score <= -min_vote
    sign = np.where(flip, -1.0, 1.0)
    return normals * sign[:, None], int(flip.sum())
