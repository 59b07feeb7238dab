"""Convex pairs and the triplets that teach features about convexity.

Two surface points form a convex pair when the segment between them stays inside the solid.
For an anchor ``a`` with outward normal ``n``:

- positive: shoot a ray from ``a`` into the inward hemisphere (direction ``u`` with
  ``u . n < 0``); the point where it leaves the solid is a convex partner of ``a``.
- negatives: candidates ``c`` from a pool of surface points for which the segment ``a -> c``
  leaves the solid: ``c`` lies outside the inward hemisphere, or the ray towards it hits the
  surface first. From those, ``n_hard`` are drawn with probability proportional to
  ``1 / (d + eps)**power`` where ``d`` is the distance from ``c`` to the positive (hard
  negatives: near the positive but not convex with the anchor), and ``n_uniform`` uniformly.

Defaults follow the paper: 1024 candidates, 256 hard + 256 uniform negatives. ``power`` 1 is the
authors' release, 2 the paper's text.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..solid import Solid


@dataclass
class Triplets:
    """Anchors with one positive each and a fixed number of negatives from a point pool.

    Attributes
    ----------
    pool : (m, 3) float
        Surface points the anchors and negatives index into.
    anchor : (a,) int
        Pool index of each anchor.
    positive : (a, 3) float
        Positive point of each anchor (where its inward ray leaves the solid).
    negative : (a, k) int
        Pool indices of each anchor's negatives.
    """

    pool: np.ndarray
    anchor: np.ndarray
    positive: np.ndarray
    negative: np.ndarray

    def __len__(self) -> int:
        return len(self.anchor)


def inward_directions(normals: np.ndarray, rng: np.random.Generator, min_cos: float = 0.05) -> np.ndarray:
    """(n, 3) unit directions uniform in the inward hemisphere of each (n, 3) unit normal,
    kept at least ``min_cos`` away from tangent (grazing rays are unreliable)."""
    d = rng.normal(size=normals.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    dot = np.einsum("ij,ij->i", d, normals)
    tangent = d - dot[:, None] * normals
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    cos = np.maximum(np.abs(dot), min_cos)  # inward, and never closer to the plane than min_cos
    return np.sqrt(1.0 - cos**2)[:, None] * tangent - cos[:, None] * normals


def positives(solid: Solid, points: np.ndarray, normals: np.ndarray, rng: np.random.Generator,
              offset: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Exit points of inward rays.

    Returns (m, 3) positives and (n,) bool saying which of the (n, 3) anchors got one (a ray
    that never hits anything, e.g. from an open surface, gives none).
    """
    dirs = inward_directions(normals, rng)
    origins = points - offset * normals
    t = solid.first_hit(origins, dirs)
    ok = np.isfinite(t) & (t > offset)
    return origins[ok] + dirs[ok] * t[ok, None], ok


def nonconvex_mask(solid: Solid, anchors: np.ndarray, normals: np.ndarray, cands: np.ndarray,
                   offset: float = 1e-3, tangent_tol: float = 0.05) -> np.ndarray:
    """(a, c) bool: True where the segment from each anchor (a, 3) to each of its candidates
    (a, c, 3) leaves the solid.

    A candidate in front of the anchor's tangent plane (``cos > tangent_tol`` with the outward
    normal) is non-convex without a ray; one nearly in the plane (a flat neighbourhood) is tested
    by its ray like the others, since a segment along a flat face stays in the closed solid.
    """
    d = cands - anchors[:, None, :]  # (a, c, 3), broadcast rather than repeated
    length = np.sqrt(np.einsum("acj,acj->ac", d, d))
    near = length <= 4 * offset  # the anchor itself, or a point too close to tell
    cos = np.einsum("acj,aj->ac", d, normals) / np.maximum(length, 1e-12)
    facing = cos < tangent_tol
    out = ~facing & ~near
    rows, cols = np.nonzero(facing & ~near)
    if len(rows):
        # Shoot from just below the anchor's surface towards the candidate.
        origins = anchors[rows] - offset * normals[rows]
        dv = cands[rows, cols] - origins
        dist = np.sqrt(np.einsum("ij,ij->i", dv, dv))
        t = solid.first_hit(origins, dv / dist[:, None])
        # The ray must reach the candidate, which sits on the surface: hits just before it (a
        # grazing ray meeting the candidate's own face) do not count.
        out[rows, cols] = t < dist * 0.99 - 4 * offset
    return out


def anchor_candidates(solid: Solid, points: np.ndarray, normals: np.ndarray, rng: np.random.Generator,
                      *, n_anchors: int, n_candidates: int, pool_size: int | None = None):
    """The draws every triplet sampler shares: a pool of the (n, 3) ``points`` (and ``normals``),
    anchors with a ray-exit positive, ``n_candidates`` candidates per anchor and which of them are
    negatives (their segment to the anchor leaves ``solid``); anchors without a positive or
    without a negative are dropped.

    Returns ``(pool (p, 3) float, anchor (a,) int, positive (a, 3) float, candidates (a, c) int,
    negative (a, c) bool)``, indices into the pool.
    """
    n = len(points)
    if pool_size is not None and pool_size < n:
        keep = np.sort(rng.choice(n, pool_size, replace=False))
        points, normals = points[keep], normals[keep]
        n = pool_size
    anchor = rng.choice(n, size=min(n_anchors, n), replace=False)
    pos, ok = positives(solid, points[anchor], normals[anchor], rng)
    anchor = anchor[ok]
    cand = rng.integers(0, n, size=(len(anchor), n_candidates))
    neg = nonconvex_mask(solid, points[anchor], normals[anchor], points[cand])
    has = neg.any(axis=1)
    return points, anchor[has], pos[has], cand[has], neg[has]


def sample_triplets(
    solid: Solid,
    points: np.ndarray,
    normals: np.ndarray,
    *,
    n_anchors: int = 1024,
    n_candidates: int = 1024,
    n_hard: int = 256,
    n_uniform: int = 256,
    power: float = 1.0,
    pool_size: int | None = None,
    seed: int = 0,
) -> Triplets:
    """Sample anchors, positives and hard/uniform negatives on a shape (all seeded).

    Parameters
    ----------
    solid : Solid
        The shape's inside.
    points, normals : (n, 3) float
        Oriented surface samples (normalised frame).
    n_anchors, n_candidates, n_hard, n_uniform : int
        Counts (paper: 1024 candidates, 256 hard + 256 uniform).
    power : float
        Hard-negative weight ``1 / (d + eps)**power``: 1 as in the release, 2 as in the paper.
    pool_size : int, optional
        Sub-sample the points into a pool of this size first (default: all).

    Returns
    -------
    Triplets
        Anchors without a positive or without any negative (e.g. on convex shapes) are dropped,
        so ``len(result)`` may be below ``n_anchors`` (0 for a convex shape).
    """
    rng = np.random.default_rng(seed)
    points, anchor, pos, cand, neg = anchor_candidates(solid, points, normals, rng, n_anchors=n_anchors,
                                                       n_candidates=n_candidates, pool_size=pool_size)
    k = n_hard + n_uniform
    negative = np.empty((len(anchor), k), dtype=np.int64)
    eps = 1e-3
    for i in range(len(anchor)):
        choices = cand[i, neg[i]]
        if n_uniform:
            negative[i, :n_uniform] = rng.choice(choices, n_uniform, replace=True)
        if n_hard:
            d = np.linalg.norm(points[choices] - pos[i], axis=1)
            w = 1.0 / (d + eps) ** power
            negative[i, n_uniform:] = rng.choice(choices, n_hard, replace=True, p=w / w.sum())
    return Triplets(points, anchor, pos, negative)
