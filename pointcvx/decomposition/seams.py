"""Closed seams: neighbouring parts' hulls meet halfway across their cut.

The parts of a decomposition partition the points, so the hulls of two neighbouring parts stop
at their own outermost points and leave a gap about one sample spacing wide along every cut.
The walls of that gap are boundary of the union of hulls, inside the solid: a collider with a
crack that reaches the surface (a groove a thin object can catch in), and surface that is not
the shape's, counted in the reconstruction error. CoACD's and V-HACD's pieces meet on shared
cut planes and have no such gaps.

:func:`seam_points` gives each part's hull, besides its own points, the midpoint of every pair
of points of two different parts within ``SEAM_SPACINGS`` times the cloud's median sample
spacing, so both hulls reach the same points halfway across the gap and meet there. A pair
whose normals differ by more than ``SEAM_CREASE_DEGREES`` straddles an edge of the shape, not a
seam within one face: the hulls are left as they are there (their midpoints raised the
concavity of CAD parts, at convex edges as at concave ones). Taking the neighbour's points
themselves instead of midpoints closed the same gaps with a full spacing of overlap, at a higher
concavity on CAD parts. The measurements are in docs/captures.md, "Closed seams". The points'
labels (which part each point belongs to) are unchanged: only the hulls grow.
"""

from __future__ import annotations

import math

import numpy as np

SEAM_SPACINGS = 1.5  # 1.0 left most gaps open (a spacing is a median); 2.5 raised concavity 8 %
SEAM_CREASE_DEGREES = 60.0  # pairs whose normals differ by more straddle an edge


def seam_points(points: np.ndarray, normals: np.ndarray, labels: np.ndarray, spacing: float,
                crease_degrees: float = SEAM_CREASE_DEGREES) -> list[np.ndarray]:
    """The points of each part's hull, seams closed.

    Parameters
    ----------
    points : (n, 3) float
        Every point of the cloud.
    normals : (n, 3) float
        Their unit normals.
    labels : (n,) int
        The part of each point, ``0 .. k - 1``; ``-1`` for points of no part (noise), which no
        hull takes and no seam pairs.
    spacing : float
        The median nearest-neighbour distance of the points; two points of different parts
        within ``SEAM_SPACINGS * spacing`` of each other, normals within ``crease_degrees``,
        put their midpoint into both parts' hulls.
    crease_degrees : float
        Pairs whose normals differ by more are left apart (180: every pair).

    Returns
    -------
    list of k (m_i, 3) float arrays: the part's own points (in cloud order), then the midpoints
    of its seam pairs.
    """
    points = np.asarray(points, dtype=np.float64)
    labels = np.asarray(labels, dtype=np.int64)
    k = int(labels.max()) + 1 if len(labels) else 0
    own = [points[labels == i] for i in range(k)]
    if k < 2 or not spacing > 0:
        return own
    a, b = seam_pairs(points, np.asarray(normals, dtype=np.float64), labels, spacing, crease_degrees)
    mid = 0.5 * (points[a] + points[b])
    # Each pair's midpoint goes to both its parts: (part, midpoint) rows grouped by part.
    part = np.concatenate([labels[a], labels[b]])
    order = np.argsort(part, kind="stable")
    rows = np.concatenate([mid, mid])[order]
    starts = np.searchsorted(part[order], np.arange(k + 1))
    return [np.vstack([own[i], rows[starts[i]:starts[i + 1]]]) for i in range(k)]


def seam_pairs(points: np.ndarray, normals: np.ndarray, labels: np.ndarray, spacing: float,
               crease_degrees: float = SEAM_CREASE_DEGREES) -> tuple[np.ndarray, np.ndarray]:
    """The seam pairs of :func:`seam_points`: two (p,) int64 arrays ``a, b`` of point indices,
    ``a < b``, of different parts (neither ``-1``), within ``SEAM_SPACINGS * spacing`` of each
    other and with normals within ``crease_degrees`` (180: every pair); in ascending order of
    ``(a, b)``."""
    from scipy.spatial import cKDTree

    kept = np.flatnonzero(labels >= 0)
    pairs = cKDTree(points[kept]).query_pairs(SEAM_SPACINGS * spacing, output_type="ndarray")
    a, b = kept[pairs[:, 0]], kept[pairs[:, 1]]
    agree = np.einsum("ij,ij->i", normals[a], normals[b]) >= math.cos(math.radians(crease_degrees))
    keep = (labels[a] != labels[b]) & agree
    a, b = a[keep], b[keep]
    order = np.lexsort((b, a))
    return a[order], b[order]
