"""Closed seams: each part's hull reaches across the cut into its neighbours.

The parts of a decomposition partition the points, so the hulls of two neighbouring parts stop
at their own outermost points and leave a gap about one sample spacing wide along every cut.
The walls of that gap are boundary of the union of hulls, inside the solid: a collider with a
crack that reaches the surface (a groove a thin object can catch in), and surface that is not
the shape's, counted in the reconstruction error (measured in docs/captures.md, "Closed
seams"). CoACD's and V-HACD's pieces meet on shared cut planes and have no such gaps.

:func:`seam_parts` adds to each part the points of other parts within ``SEAM_SPACINGS`` times
the cloud's median sample spacing, so neighbouring hulls overlap by about a spacing
along the cut instead of leaving a gap. The points' labels (which part each point belongs to)
are unchanged: only the hulls grow.
"""

from __future__ import annotations

import numpy as np

SEAM_SPACINGS = 1.5  # 1.0 left most gaps open (a spacing is a median); 2.5 raised concavity 8 %


def seam_parts(points: np.ndarray, labels: np.ndarray, spacing: float) -> list[np.ndarray]:
    """The point indices of each part's hull, seams closed.

    Parameters
    ----------
    points : (n, 3) float
        Every point of the cloud.
    labels : (n,) int
        The part of each point, ``0 .. k - 1``; ``-1`` for points of no part (noise), which no
        hull takes.
    spacing : float
        The median nearest-neighbour distance of the points; points of two different parts
        within ``SEAM_SPACINGS * spacing`` of each other go into both parts' hulls.

    Returns
    -------
    list of k (m_i,) int64 arrays, sorted: the part's own points and its neighbours' points
    across the seam.
    """
    from scipy.spatial import cKDTree

    labels = np.asarray(labels, dtype=np.int64)
    k = int(labels.max()) + 1 if len(labels) else 0
    own = [np.flatnonzero(labels == i) for i in range(k)]
    if k < 2 or not spacing > 0:
        return own
    kept = np.flatnonzero(labels >= 0)
    pairs = cKDTree(points[kept]).query_pairs(SEAM_SPACINGS * spacing, output_type="ndarray")
    a, b = kept[pairs[:, 0]], kept[pairs[:, 1]]
    cross = labels[a] != labels[b]
    a, b = a[cross], b[cross]
    # Each cross pair gives both parts the other's point: (part, point) rows, deduplicated.
    part = np.concatenate([labels[a], labels[b]])
    point = np.concatenate([b, a])
    order = np.lexsort((point, part))
    part, point = part[order], point[order]
    starts = np.searchsorted(part, np.arange(k + 1))
    return [np.union1d(own[i], point[starts[i]:starts[i + 1]]) for i in range(k)]
