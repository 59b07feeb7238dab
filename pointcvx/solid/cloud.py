"""Cloud -> solid: a closed proxy surface reconstructed from an oriented point cloud (splats,
scans, point sets), for clouds that have no mesh.

Near the points, the field is Hoppe's signed tangent-plane distance averaged over ``neighbors``
nearest oriented points (Gaussian weights, for noise). Farther away, the sign comes from a flood
fill through grid vertices not covered by the points (dilated by the typical point spacing).

The flood fill *leaks* when a large share (:data:`LEAK_SHARE`) of the free voxels just behind the
points (by their normals) is reached from outside: open or partial scans. Then the far sign
falls back to the tangent-plane sign of the nearest points, overruled where the cloud's
generalized winding number (:func:`winding_number`) is clearly inside or outside
(:data:`WINDING_SURE`): deep in a thick part the nearest points can be a sub-surface layer of a
splat, whose planes leave hollows.

In both cases the solid is cut to the points' bounding box plus one voxel, so an open cloud
gives the region behind it within its bounds: a slab as thick as its bounding box for a flat
patch, about the filled hemisphere for a hemisphere scan. The inside is then closed by two
voxels (:data:`CLOUD_CLOSING`): real captures leave pinholes and tunnels in the tangent-plane
sign (noisy centres, the odd wrong normal), which a decomposer reads as concavity; the price is
that folds narrower than about four voxels fill. Never empty: a cloud with nothing behind its
normals gets a thin shell around the points. Normals matter: where many are flipped, the
surface follows them.

Deterministic: no randomness, the same input gives the same surface.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from ..cloud import check_points
from ..errors import InputError
from ..workers import kd_workers
from .grid import (
    Grid,
    ball_dilate,
    box_field,
    coarse_vertices,
    flood_outside,
    grid_for,
    marching_cubes,
    wind_outward,
)
from .raycast import Solid

log = logging.getLogger(__name__)

#: Share of the free band voxels found behind the points but outside by the flood fill above
#: which a cloud counts as open (see :func:`surface_from_cloud`): closed clouds, even with some
#: wrong normals, stay well below it, open captures well above.
LEAK_SHARE = 0.2
#: Voxels of morphological closing of cloud solids (:func:`surface_from_cloud`): it fills the
#: pinholes and tunnels that noisy points and wrong normals leave in the tangent-plane sign.
CLOUD_CLOSING = 2
#: Winding numbers below / above which the far field of an open (leaked) cloud is surely
#: outside / inside (:func:`surface_from_cloud`); between them, the nearest tangent planes
#: decide.
WINDING_SURE = (0.25, 0.75)


# ---------------------------------------------------------------------------------- fields
def _check_normals(normals: Any, n: int) -> np.ndarray:
    """(n, 3) float64 unit normals from ``normals``, checked: finite, none of zero length."""
    nrm = np.asarray(normals, dtype=np.float64)
    if nrm.shape != (n, 3):
        raise InputError(f"normals must have shape ({n}, 3), got {nrm.shape}")
    if not np.isfinite(nrm).all():
        raise InputError("normals contain NaN or infinite values")
    length = np.linalg.norm(nrm, axis=1, keepdims=True)
    if (length <= 1e-12).any():
        raise InputError(f"{int((length <= 1e-12).sum())} normals have zero length")
    return nrm / length


def _hoppe(tree, points, normals, query, neighbors, sigma, chunk: int = 1 << 17) -> np.ndarray:
    """(m,) float: Hoppe's signed tangent-plane distance at (m, 3) ``query``, Gaussian-weighted
    over the ``neighbors`` nearest oriented points (negative behind the normals)."""
    out = np.empty(len(query))
    k = min(neighbors, len(points))
    for s in range(0, len(query), chunk):
        q = query[s : s + chunk]
        dist, idx = tree.query(q, k=k, workers=kd_workers(len(q)))
        if k == 1:
            dist, idx = dist[:, None], idx[:, None]
        # Far from the points, widen the kernel with the distance so the sign stays smooth.
        scale2 = np.maximum(sigma**2, dist[:, :1] ** 2)
        w = np.exp(-(dist**2 - dist[:, :1] ** 2) / scale2)
        plane = np.einsum("mkj,mkj->mk", q[:, None, :] - points[idx], normals[idx])
        out[s : s + chunk] = (w * plane).sum(axis=1) / w.sum(axis=1)
    return out


def _coarse_hoppe(tree, points, normals, grid: Grid, flat: np.ndarray, neighbors, sigma,
                  stride: int = 2) -> np.ndarray:
    """(m,) float: :func:`_hoppe` at the grid vertices ``flat``, evaluated on every ``stride``-th
    vertex and copied to the others (far from the points, only its smooth sign matters)."""
    at, inverse = coarse_vertices(grid, flat, stride)
    return _hoppe(tree, points, normals, at, neighbors, sigma)[inverse]


# ---------------------------------------------------------------------------------- winding number
def dipole_cells(points: np.ndarray, normals: np.ndarray, cell: float, k: int = 8,
                 max_points: int = 50000):
    """Oriented area of a cloud lumped per cubic cell of side ``cell``, for
    :func:`winding_number` far from the points.

    Each point stands for the area ``pi r_k^2 / k`` around it (``r_k``: distance to its
    ``k``-th neighbour), along its unit normal. The areas run a little high, so a closed cloud
    reads a little above 1 inside, more where its points cluster.
    Beyond ``max_points`` points, every ``ceil(n / max_points)``-th stands for its neighbours
    (its ``r_k`` is measured among the kept points).

    Parameters
    ----------
    points, normals : (n, 3) float
    cell : float
    k : int
    max_points : int

    Returns
    -------
    centres : (c, 3) float
        Area-weighted centroid of each non-empty cell.
    moments : (c, 3) float
        Sum of area x unit normal over each cell.
    """
    from scipy.spatial import cKDTree

    stride = max(1, math.ceil(len(points) / max_points))
    pts = np.asarray(points, dtype=np.float64)[::stride]
    nrm = np.asarray(normals, dtype=np.float64)[::stride]
    nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    kk = min(k, len(pts) - 1)
    if kk < 1:
        area = np.ones(len(pts))
    else:
        area = np.pi * cKDTree(pts).query(pts, k=kk + 1, workers=kd_workers(len(pts)))[0][:, -1] ** 2 / kk
    key = np.floor((pts - pts.min(axis=0)) / cell).astype(np.int64)
    inverse = np.unique(key, axis=0, return_inverse=True)[1].reshape(-1)
    n_cells = int(inverse.max()) + 1
    total = np.maximum(np.bincount(inverse, area, n_cells), 1e-300)
    centres = np.stack([np.bincount(inverse, area * pts[:, j], n_cells) for j in range(3)], axis=1)
    moments = np.stack([np.bincount(inverse, area * nrm[:, j], n_cells) for j in range(3)], axis=1)
    return centres / total[:, None], moments


def winding_number(centres: np.ndarray, moments: np.ndarray, query: np.ndarray,
                   chunk: int = 2048) -> np.ndarray:
    """(m,) float: generalized winding number of oriented area elements at (m, 3) ``query``:
    the sum of ``moment . (centre - q) / (4 pi |centre - q|^3)``, about 1 inside a closed
    outward-oriented surface and 0 outside; a hole in the surface takes off the solid angle it
    subtends, so an open capture still reads well above 0.5 deep inside its visible part.

    ``centres``, ``moments``: (c, 3) float, e.g. from :func:`dipole_cells` (accurate a few
    cells away from them).
    """
    query = np.asarray(query, dtype=np.float64)
    along = np.einsum("ij,ij->i", centres, moments)
    c2 = np.einsum("ij,ij->i", centres, centres)
    out = np.empty(len(query))
    for s in range(0, len(query), chunk):  # in place: this loop is the whole cost
        q = query[s : s + chunk]
        d2 = q @ centres.T
        d2 *= -2.0
        d2 += c2
        d2 += np.einsum("ij,ij->i", q, q)[:, None]
        np.maximum(d2, 1e-24, out=d2)
        cube = np.sqrt(d2)
        cube *= d2
        num = q @ moments.T
        np.subtract(along, num, out=num)
        num /= cube
        out[s : s + chunk] = num.sum(axis=1)
    return out / (4.0 * np.pi)


def _coarse_winding(points, normals, grid: Grid, flat: np.ndarray, stride: int = 3) -> np.ndarray:
    """(m,) float: :func:`winding_number` of the cloud at the grid vertices ``flat``, from cells
    of ``stride`` voxels, evaluated on every ``stride``-th vertex and copied to the others."""
    at, inverse = coarse_vertices(grid, flat, stride)
    centres, moments = dipole_cells(points, normals, stride * grid.h)
    return winding_number(centres, moments, at)[inverse]


# ---------------------------------------------------------------------------------- surface
def surface_from_cloud(
    points: Any,
    normals: Any,
    resolution: int = 96,
    neighbors: int = 8,
    min_part: float = 1e-3,
    closing: int = CLOUD_CLOSING,
):
    """A closed, outward-wound proxy surface of an oriented point cloud (see the module docstring).

    Parameters
    ----------
    points : (n, 3) float
    normals : (n, 3) float
        Outward normals (need not be unit length).
    resolution : int
        Grid vertices along the longest side of the points' bounds.
    neighbors : int
        Oriented points averaged into each tangent-plane distance (noise robustness).
    min_part : float
        Parts enclosing less than this fraction of the volume are dropped (floaters).
    closing : int
        Voxels of morphological closing of the inside before marching cubes (0: none). It
        fills the pinholes and tunnels that noisy points and the odd wrong normal leave in the
        tangent-plane sign, and concave gaps narrower than about ``2 * closing`` voxels.

    Returns
    -------
    trimesh.Trimesh
        Watertight and outward-wound, in the points' coordinates.
    """
    import trimesh
    from scipy.spatial import cKDTree

    pts = check_points(points)
    nrm = _check_normals(normals, len(pts))
    if len(pts) < 4:
        raise InputError(f"only {len(pts)} points: at least 4 are needed for a surface")
    tree = cKDTree(pts)
    probe = pts[:: max(1, len(pts) // 20000)]
    kk = min(7, len(pts))
    nn = tree.query(probe, k=kk, workers=kd_workers(len(probe)))[0][:, -1]
    cover = float(np.median(nn))  # about the radius of the gaps between points
    lo, hi = pts.min(axis=0), pts.max(axis=0)

    def wall_voxels(h: float) -> int:
        return int(min(max(math.ceil(cover / h + 1.0), 2), 5))

    grid, kw = grid_for(lo, hi, resolution, lambda h: wall_voxels(h) + 1)
    kw -= 1
    h = grid.h
    sigma = max(cover, h)

    occ = np.zeros(grid.shape, dtype=bool)
    occ.reshape(-1)[grid.nearest(pts)] = True
    wall = ball_dilate(occ, kw)
    band = ball_dilate(occ, kw + 1.0)
    del occ
    outside = flood_outside(~wall)
    index = np.flatnonzero(band)
    near_values = _hoppe(tree, pts, nrm, grid.positions(index), neighbors, sigma)
    far_value = (kw + 2) * h

    # Leak test on the free voxels of the band (the shell around the walls), where the tangent
    # planes are reliable: if a large share of the shell is confidently behind the points and
    # yet reached by the flood, the flood got inside (an open or partial cloud). Wrong normals
    # on closed clouds give a smaller share.
    flat_out = outside.reshape(-1)[index]
    shell = ~wall.reshape(-1)[index]
    behind = shell & (near_values < -0.5 * h) & flat_out
    leaked = bool(behind.sum() > LEAK_SHARE * max(shell.sum(), 1))
    if not leaked:  # the flood fill is right about the shell: keep Hoppe's magnitude only
        near_values[shell] = np.where(flat_out[shell], 1.0, -1.0) * np.abs(near_values[shell])
    far = np.flatnonzero(~band.reshape(-1))
    if leaked:
        far_values = _coarse_hoppe(tree, pts, nrm, grid, far, min(neighbors, 4), sigma)
        # The nearest tangent planes misread the middle of thick parts where a layer of wrong
        # or sub-surface points lies nearer than the true wall (hollows in a real splat's
        # tube); where the winding number is clear, its sign wins.
        winding = _coarse_winding(pts, nrm, grid, far)
        sure_in, sure_out = winding > WINDING_SURE[1], winding < WINDING_SURE[0]
        far_values[sure_in] = -np.maximum(np.abs(far_values[sure_in]), h)
        far_values[sure_out] = np.maximum(np.abs(far_values[sure_out]), h)
    else:
        far_values = np.where(outside.reshape(-1)[far], far_value, -far_value)
    log.debug("cloud surface: %d points, h=%.4g, wall %d voxels, leaked=%s", len(pts), h, kw, leaked)
    field = np.empty(grid.size, dtype=np.float32)
    field[index] = np.clip(near_values, -far_value, far_value)
    field[far] = np.clip(far_values, -far_value, far_value)
    # Nothing lies beyond the points' bounds (one voxel of slack): intersect with that box, so
    # open clouds end at their bounds instead of running on into the padding.
    field = np.maximum(field.reshape(grid.shape), box_field(grid, lo - h, hi + h))
    if closing > 0:
        field = _close_inside(field, int(closing), h)
    verts, tris = marching_cubes(field, grid, far_value)
    verts, tris = wind_outward(verts, tris, min_part)
    if len(tris) == 0:
        # Nothing behind any normal: a thin shell around the points, so there is a solid.
        log.debug("cloud surface: no inside found, using a shell of %.3g", sigma)
        field = np.full(grid.size, far_value, dtype=np.float32)
        field[index] = tree.query(grid.positions(index))[0] - sigma
        verts, tris = marching_cubes(field.reshape(grid.shape), grid, far_value)
        verts, tris = wind_outward(verts, tris, min_part)
    if len(tris) == 0:
        raise InputError("could not reconstruct a surface from the point cloud")
    return trimesh.Trimesh(verts, tris, process=False)


def solid_from_cloud(
    points: Any,
    normals: Any,
    resolution: int = 96,
    neighbors: int = 8,
    min_part: float = 1e-3,
    closing: int = CLOUD_CLOSING,
) -> Solid:
    """:class:`Solid` of an oriented point cloud: :func:`surface_from_cloud` wrapped."""
    return Solid.from_trimesh(surface_from_cloud(points, normals, resolution, neighbors, min_part,
                                                 closing))


def _close_inside(field: np.ndarray, k: int, h: float) -> np.ndarray:
    """(shape) float ``field`` (negative inside) with its inside closed by ``k`` steps of the
    6-connected cross: grid vertices the closing adds get the field's magnitude, negated, so
    the new surface runs where the old one was mirrored."""
    from scipy import ndimage

    inside = field < 0
    closed = ndimage.binary_closing(inside, structure=ndimage.generate_binary_structure(3, 1),
                                    iterations=k, border_value=0)
    added = closed & ~inside
    if not added.any():
        return field
    out = field.copy()
    out[added] = -np.maximum(np.abs(field[added]), np.float32(1e-3 * h))
    return out
