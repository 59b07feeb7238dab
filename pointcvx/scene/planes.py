"""Planes in point clouds: seeded RANSAC with a least-squares refit, for support planes (floors,
tables, the ground disc under a captured object) and the large flat structure of scenes."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Plane:
    """The plane ``normal . x = offset``.

    Attributes
    ----------
    normal : (3,) float, unit.
    offset : float
    inliers : (n,) bool, the points within ``tolerance`` of the plane.
    tolerance : float, in the points' units.
    """

    normal: np.ndarray
    offset: float
    inliers: np.ndarray
    tolerance: float

    def distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) float signed distances of (n, 3) ``points`` (positive on the normal's side)."""
        return np.asarray(points, dtype=np.float64) @ self.normal - self.offset

    def flipped(self) -> Plane:
        return Plane(-self.normal, -self.offset, self.inliers, self.tolerance)

    def as_dict(self) -> dict:
        return {"normal": np.round(self.normal, 6).tolist(), "offset": round(float(self.offset), 9),
                "inliers": int(self.inliers.sum()), "tolerance": float(self.tolerance)}


def fit_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    """((3,) unit normal, offset) of the least-squares plane of (n, 3) ``points`` (n >= 3)."""
    pts = np.asarray(points, dtype=np.float64)
    center = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - center, full_matrices=False)
    normal = vt[2] / np.linalg.norm(vt[2])
    return normal, float(normal @ center)


def ransac_plane(points: np.ndarray, tolerance: float, *, iterations: int = 300, sample: int = 20000,
                 seed: int = 0, allowed: np.ndarray | None = None) -> Plane | None:
    """The plane with the most (n, 3) ``points`` within ``tolerance``, or None for fewer than 3.

    Hypotheses from seeded random triples are scored on a subsample of at most ``sample``
    points; the best is refit by least squares on its inliers among all points (twice). Only the
    rows where ``allowed`` (n,) bool is true take part.
    """
    pts = np.asarray(points, dtype=np.float64)
    idx = np.flatnonzero(allowed) if allowed is not None else np.arange(len(pts))
    if len(idx) < 3:
        return None
    rng = np.random.default_rng(seed)
    sub = pts[rng.choice(idx, size=min(sample, len(idx)), replace=False)]
    tri = sub[rng.integers(0, len(sub), size=(iterations, 3))]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normals, axis=1)
    ok = length > 1e-12
    if not ok.any():
        return None
    normals, tri = normals[ok] / length[ok, None], tri[ok]
    offsets = np.einsum("ij,ij->i", normals, tri[:, 0])
    best, best_count = 0, -1
    for s in range(0, len(normals), 64):
        counts = (np.abs(sub @ normals[s:s + 64].T - offsets[s:s + 64]) <= tolerance).sum(axis=0)
        j = int(np.argmax(counts))
        if counts[j] > best_count:
            best, best_count = s + j, int(counts[j])
    normal, offset = normals[best], float(offsets[best])
    mask = np.zeros(len(pts), dtype=bool)
    for _ in range(2):
        near = np.abs(pts[idx] @ normal - offset) <= tolerance
        if near.sum() < 3:
            break
        normal, offset = fit_plane(pts[idx[near]])
    mask[idx] = np.abs(pts[idx] @ normal - offset) <= tolerance
    return Plane(normal, offset, mask, float(tolerance))


def find_planes(points: np.ndarray, tolerance: float, *, min_share: float = 0.05, max_planes: int = 6,
                seed: int = 0) -> Iterator[Plane]:
    """Large planes of (n, 3) ``points``, largest first: RANSAC, remove its inliers, repeat while a
    plane holds at least ``min_share`` of all points (at most ``max_planes``). Lazy: a caller that
    stops at the plane it wants pays for no more RANSAC."""
    pts = np.asarray(points, dtype=np.float64)
    free = np.ones(len(pts), dtype=bool)
    for k in range(max_planes):
        plane = ransac_plane(pts, tolerance, seed=seed + k, allowed=free)
        if plane is None or plane.inliers.sum() < min_share * len(pts):
            return
        yield plane
        free &= ~plane.inliers
