"""Closed bases for objects that stood on a removed support plane.

A capture never sees the underside of what stands on the floor or a table, and isolation
removes the support's band with whatever of the object lies in it. Left so, an object's cloud
is open at the bottom: the solid rebuilt from it is cut off at the points' bounding box, the
hull ends a band's height above the support (in a simulator the object drops onto it), and the
open bottom reads as concavity. :func:`base_samples` closes it: for each piece whose lowest
sideways-facing point is within the band (plus :data:`RESTING` spacings) of the plane, the slice
of its lowest sideways-facing points is its footprint (the plane's own noise left above its
band faces up and draws none); each connected footprint (a leg, a box's rim) gets a cap on the plane
(its convex outline filled at the cloud's density, normals down) and a skirt from the slice down
to the plane (the slice's points repeated below it, their normals kept level).
"""

from __future__ import annotations

import numpy as np

from .components import components
from .isolate import plane_basis, spacing
from .planes import Plane

#: A piece rests on the support when its lowest point is at most the removed band plus this many
#: of its sample spacings above the plane.
RESTING = 3.0
#: Sample spacings (median nearest-neighbour distances) between cap and skirt samples: random
#: samples of a surface are about this much closer to their nearest neighbour than the side of
#: the square each one covers, so a grid at this step has the cloud's density.
STEP_SPACINGS = 2.0
#: Length of a normal's level part above which a point faces sideways (a wall of the object,
#: within 60 degrees of level).
SIDEWAYS = 0.5
#: Fewest points in a footprint to close.
MIN_FOOTPRINT = 3


def cap(footprint: np.ndarray, step: float) -> np.ndarray:
    """(m, 2) float points inside the convex outline of (k, 2) ``footprint``, one in each
    ``step``-wide square of a grid, placed at random in it (seeded): the density of random samples
    at their spacings, not a grid's (whose nearest neighbours are all a step away, which would
    read as a sparser cloud); the outline's own corners when it is smaller than a step, empty
    when it is a line."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(footprint)
    except (QhullError, ValueError):
        return np.zeros((0, 2))
    lo, hi = footprint.min(axis=0), footprint.max(axis=0)
    axes = [np.arange(lo[d] + step / 2, hi[d], step) for d in range(2)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 2)
    grid += np.random.default_rng(0).uniform(-step / 2, step / 2, grid.shape)
    inside = np.all(grid @ hull.equations[:, :2].T + hull.equations[:, 2] <= 0, axis=1)
    return grid[inside] if inside.any() else footprint[hull.vertices]


def base_samples(points: np.ndarray, normals: np.ndarray, labels: np.ndarray, plane: Plane,
                 band: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Samples closing the bases of the pieces of (n, 3) ``points`` that rest on ``plane``.

    Parameters
    ----------
    points, normals : (n, 3) float, the objects (the support and its band already removed).
    labels : (n,) int, the piece of each point (:func:`.components.components`).
    plane : Plane, oriented with the objects on its positive side.
    band : float, the height above the plane up to which points were removed with it.

    Returns
    -------
    (m, 3) float points, (m, 3) float unit normals, (m,) int64 the index of the object point
    each sample was made from (for its colour and weight); m = 0 when nothing rests on it.
    """
    from scipy.spatial import cKDTree

    pts = np.asarray(points, dtype=np.float64)
    nrm = np.asarray(normals, dtype=np.float64)
    up = plane.normal / np.linalg.norm(plane.normal)
    axes = np.stack(plane_basis(up))
    height = pts @ up - plane.offset
    out_p, out_n, out_src = [], [], []
    labels = np.asarray(labels)
    # the walls of what stands on the plane meet it: the footprint is drawn by points facing
    # sideways, not by the strips of the plane's own noise left above its band (facing up)
    level = nrm - np.outer(nrm @ up, up)
    length = np.linalg.norm(level, axis=1)
    sideways = length > SIDEWAYS
    for piece in range(int(labels.max()) + 1 if len(labels) else 0):
        idx = np.flatnonzero(labels == piece)
        s = spacing(pts[idx], sample=len(idx))  # all of them: a subsample reads sparser
        idx = idx[sideways[idx]]
        if s <= 0 or len(idx) < MIN_FOOTPRINT:
            continue
        low = height[idx].min()
        if low > band + RESTING * s:
            continue  # held above the support, or on something else
        step = STEP_SPACINGS * s
        slab = idx[height[idx] <= low + step]
        if len(slab) < MIN_FOOTPRINT:
            continue
        feet = components(pts[slab])
        for foot in range(int(feet.max()) + 1):
            src = slab[feet == foot]
            if len(src) < MIN_FOOTPRINT:
                continue
            flat = pts[src] @ axes.T  # (k, 2) in the plane
            grid = cap(flat, step)
            if len(grid):
                out_p.append(grid @ axes + plane.offset * up)
                out_n.append(np.tile(-up, (len(grid), 1)))
                out_src.append(src[cKDTree(flat).query(grid)[1]])
            # the skirt: each slice point repeated every step down to the plane, its normal level
            copies = np.floor(height[src] / step).astype(np.int64)
            if copies.sum() == 0:
                continue
            rep = np.repeat(src, copies)
            k = np.concatenate([np.arange(1, c + 1) for c in copies if c > 0])
            out_p.append(pts[rep] - np.outer(k * step, up))
            out_n.append(level[rep] / length[rep, None])
            out_src.append(rep)
    if not out_p:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    return np.concatenate(out_p), np.concatenate(out_n), np.concatenate(out_src).astype(np.int64)
