"""The voxel grid kit shared by the mesh and cloud routes to a solid.

A :class:`Grid` of cubic voxels sized to a shape's bounds; ball, box and geodesic dilations of
boolean masks; the flood fill that finds the outside; dense samples of triangles and edges for
rasterising a surface onto the grid; a coarse sub-grid for fields that only need their sign far
from the surface; and marching cubes back to a closed, outward-wound triangle surface.

Masks and fields are ``(shape)`` arrays over the grid's vertices, indexed ``ijk``; flat indices
are ``np.ravel_multi_index`` of ``ijk`` in that shape. Everything here is deterministic.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from ..errors import InputError

log = logging.getLogger(__name__)


# ---------------------------------------------------------------------------------- grid
class Grid:
    """A cubic-voxel grid: vertex ``ijk`` sits at ``origin + ijk * h``; ``shape`` (3,) int."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, h: float, pad: int):
        self.h = float(h)
        span = np.maximum(hi - lo, 0.0)
        self.shape = tuple(int(s) for s in np.ceil(span / h - 1e-9).astype(int) + 1 + 2 * pad)
        self.origin = (lo + hi) / 2.0 - (np.array(self.shape) - 1) * h / 2.0

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    def nearest(self, points: np.ndarray) -> np.ndarray:
        """(n,) int64 flat index of the grid vertex nearest to each of (n, 3) ``points``,
        clipped to the grid."""
        ijk = np.rint((points - self.origin) / self.h).astype(np.int64)
        np.clip(ijk, 0, np.array(self.shape) - 1, out=ijk)
        return np.ravel_multi_index(ijk.T, self.shape)

    def positions(self, flat: np.ndarray) -> np.ndarray:
        """(n, 3) float positions of grid vertices given by (n,) flat indices."""
        ijk = np.stack(np.unravel_index(flat, self.shape), axis=1)
        return self.origin + ijk * self.h


def grid_for(lo: np.ndarray, hi: np.ndarray, resolution: int, band_for_h) -> tuple[Grid, int]:
    """Grid with ``resolution`` vertices along the longest side of ``lo``..``hi``, padded by the
    band half-width (``band_for_h(h)`` voxels) plus two voxels. Returns (grid, band voxels)."""
    resolution = int(resolution)
    longest = float((hi - lo).max())
    if not np.isfinite(longest) or longest <= 0.0:
        raise InputError("the shape has no extent")
    h0 = longest / max(resolution - 1, 1)
    k = band_for_h(h0)
    pad = k + 2
    inner = resolution - 1 - 2 * pad
    if inner < 8:
        raise InputError(f"resolution {resolution} is too small for a band of {k} voxels")
    h = longest / inner
    return Grid(lo, hi, h, pad), min(k, band_for_h(h))


# ---------------------------------------------------------------------------------- masks
def ball_dilate(mask: np.ndarray, radius: float) -> np.ndarray:
    """``mask`` dilated by the lattice ball of ``radius`` voxels (exact Euclidean, not a cube).

    Scatters every True voxel to each offset of the ball: cheap for thin masks (a rasterised
    surface), which are all it is used for. Voxels closer than ``radius`` to the grid border
    wrap around in the flat index, so callers keep the mask ``radius`` voxels inside.
    """
    r = int(math.floor(radius))
    ax = np.arange(-r, r + 1)
    o = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), axis=-1).reshape(-1, 3)
    o = o[(o**2).sum(axis=1) <= radius**2 + 1e-9]
    sy, sz = mask.shape[1] * mask.shape[2], mask.shape[2]
    offsets = o[:, 0] * sy + o[:, 1] * sz + o[:, 2]
    seed = np.flatnonzero(mask)
    out = np.zeros(mask.size, dtype=bool)
    for off in offsets:
        idx = seed + off
        np.clip(idx, 0, mask.size - 1, out=idx)
        out[idx] = True
    return out.reshape(mask.shape)


def box_dilate(mask: np.ndarray, k: int) -> np.ndarray:
    """``mask`` dilated by the cube of half-width ``k`` voxels (separable, fast on any mask)."""
    from scipy import ndimage

    if k <= 0:
        return mask.copy()
    return ndimage.maximum_filter(mask, size=2 * k + 1, mode="constant", cval=False)


def dilate_within(seed: np.ndarray, mask: np.ndarray, iterations: int) -> np.ndarray:
    """Geodesic dilation of ``seed`` inside ``mask`` by ``iterations`` 6-connected steps."""
    from scipy import ndimage

    structure = ndimage.generate_binary_structure(3, 1)
    return ndimage.binary_dilation(seed, structure=structure, iterations=iterations, mask=mask)


def flood_outside(free: np.ndarray) -> np.ndarray:
    """(shape) bool: the 6-connected components of ``free`` that touch the grid boundary."""
    from scipy import ndimage

    labels, count = ndimage.label(free)
    faces = [labels[0], labels[-1], labels[:, 0], labels[:, -1], labels[:, :, 0], labels[:, :, -1]]
    touching = np.unique(np.concatenate([f.ravel() for f in faces]))
    lut = np.zeros(count + 1, dtype=bool)
    lut[touching] = True
    lut[0] = False
    return lut[labels]


def bbox_slices(mask: np.ndarray, margin: int) -> tuple[slice, ...] | None:
    """Slices of the bounding box of ``mask``'s True voxels grown by ``margin`` (None if empty)."""
    out = []
    for axis in range(3):
        other = tuple(a for a in range(3) if a != axis)
        hit = np.flatnonzero(mask.any(axis=other))
        if len(hit) == 0:
            return None
        out.append(slice(max(hit[0] - margin, 0), min(hit[-1] + margin + 1, mask.shape[axis])))
    return tuple(out)


def box_field(grid: Grid, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(shape) float32: how far each grid vertex lies outside the box ``lo``..``hi`` (largest
    per-axis excess; negative inside), for intersecting a field with the box by ``maximum``."""
    out = None
    for axis in range(3):
        x = grid.origin[axis] + grid.h * np.arange(grid.shape[axis])
        d = np.maximum(lo[axis] - x, x - hi[axis]).astype(np.float32)
        shape = [1, 1, 1]
        shape[axis] = -1
        d = d.reshape(shape)
        out = d if out is None else np.maximum(out, d)
    return np.broadcast_to(out, grid.shape)


def coarse_vertices(grid: Grid, flat: np.ndarray, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """Every ``stride``-th grid vertex near the vertices ``flat``: ((c, 3) float positions,
    (m,) int index of the coarse vertex standing for each of ``flat``)."""
    ijk = np.stack(np.unravel_index(flat, grid.shape), axis=1)
    coarse = np.rint(ijk / stride).astype(np.int64)
    cshape = tuple(int(v) for v in coarse.max(axis=0) + 1)
    cflat = np.ravel_multi_index(coarse.T, cshape)
    used, inverse = np.unique(cflat, return_inverse=True)
    at = grid.origin + np.stack(np.unravel_index(used, cshape), axis=1) * (stride * grid.h)
    return at, inverse.reshape(-1)


# ---------------------------------------------------------------------------------- sampling
def triangle_samples(tri: np.ndarray, step: float, chunk: int = 1 << 21):
    """Yield ((m, 3) float points, (m,) int triangle ids) covering (f, 3, 3) triangles ``tri`` so
    that every point of every triangle lies within ``1.12 * step`` of a sample.

    Rows parallel to each triangle's longest edge, ``step`` apart, each sampled every ``step``:
    the count follows area / step^2 + perimeter / step, so long slivers stay cheap.
    """
    e = np.stack([tri[:, 2] - tri[:, 1], tri[:, 0] - tri[:, 2], tri[:, 1] - tri[:, 0]], axis=1)
    longest = np.argmax(np.einsum("fij,fij->fi", e, e), axis=1)  # edge opposite vertex `longest`
    f = np.arange(len(tri))
    a = tri[f, longest]
    b = tri[f, (longest + 1) % 3]
    c = tri[f, (longest + 2) % 3]
    base = np.linalg.norm(c - b, axis=1)
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    height = area2 / np.maximum(base, 1e-300)
    n_rows = np.maximum(np.ceil(height / step), 1).astype(np.int64)  # rows 0..n_rows
    # Batches of triangles holding about `chunk` samples (over-estimated) each.
    estimate = (n_rows + 1) * (np.ceil(base / step).astype(np.int64) + 1)
    batch = (np.cumsum(estimate) - estimate) // chunk
    cuts = np.concatenate([[0], np.flatnonzero(np.diff(batch)) + 1, [len(tri)]])
    for start, stop in zip(cuts[:-1], cuts[1:], strict=True):
        sl = slice(int(start), int(stop))
        rows = n_rows[sl] + 1
        row_tri = np.repeat(np.arange(sl.start, sl.stop), rows)
        first = np.cumsum(rows) - rows
        t = (np.arange(len(row_tri)) - np.repeat(first, rows)) / n_rows[row_tri]
        p0 = b[row_tri] + t[:, None] * (a[row_tri] - b[row_tri])
        p1 = c[row_tri] + t[:, None] * (a[row_tri] - c[row_tri])
        n_pts = np.ceil((1.0 - t) * base[row_tri] / step).astype(np.int64)
        per_row = n_pts + 1
        pt_row = np.repeat(np.arange(len(row_tri)), per_row)
        k = np.arange(len(pt_row)) - np.repeat(np.cumsum(per_row) - per_row, per_row)
        s = k / np.maximum(n_pts[pt_row], 1)
        pts = p0[pt_row] + s[:, None] * (p1[pt_row] - p0[pt_row])
        yield pts, row_tri[pt_row]


def edge_samples(v0: np.ndarray, v1: np.ndarray, step: float) -> np.ndarray:
    """(m, 3) float points every ``step`` (or closer) along segments (e, 3) ``v0``..``v1``."""
    n = np.maximum(np.ceil(np.linalg.norm(v1 - v0, axis=1) / step), 1).astype(np.int64)
    seg = np.repeat(np.arange(len(v0)), n + 1)
    k = np.arange(len(seg)) - np.repeat(np.cumsum(n + 1) - (n + 1), n + 1)
    s = (k / n[seg])[:, None]
    return v0[seg] + s * (v1[seg] - v0[seg])


# ---------------------------------------------------------------------------------- surface
def marching_cubes(field: np.ndarray, grid: Grid, outside_value: float):
    """Zero level set of (shape) float ``field`` (negative inside) as (v, 3) float64 vertices and
    (t, 3) int64 triangles in world coordinates; the grid border is forced outside."""
    from skimage import measure

    field = np.array(field, dtype=np.float32, copy=True)
    for axis in range(3):
        idx = [slice(None)] * 3
        for end in (0, -1):
            idx[axis] = end
            field[tuple(idx)] = outside_value
    # Break exact ties (constant far values, checkerboards of +-far) with a tiny deterministic
    # relative jitter: marching cubes' ambiguity tests give non-manifold edges on exact ties.
    jitter = (np.arange(field.size, dtype=np.float64) * 0.6180339887498949) % 1.0
    field *= (1.0 + 1e-4 * jitter).astype(np.float32).reshape(field.shape)
    field[field == 0.0] = np.float32(1e-7 * grid.h)  # no vertex exactly on the level
    if field.min() >= 0.0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    verts, tris, _, _ = measure.marching_cubes(field, level=0.0, spacing=(grid.h,) * 3)
    return verts.astype(np.float64) + grid.origin, tris.astype(np.int64)


def wind_outward(verts: np.ndarray, tris: np.ndarray, min_part: float):
    """Wind (t, 3) ``tris`` outward (positive volume) and drop connected parts enclosing less
    than ``min_part`` of the total volume (and unreferenced vertices)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if len(tris) == 0:
        return verts, tris
    t = verts[tris]
    vol = np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])) / 6.0
    if vol.sum() < 0:
        tris = tris[:, ::-1].copy()
        vol = -vol
    if min_part > 0:
        nv = len(verts)
        rows = np.concatenate([tris[:, 0], tris[:, 1]])
        cols = np.concatenate([tris[:, 1], tris[:, 2]])
        graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(nv, nv))
        _, comp = connected_components(graph, directed=False)
        part = comp[tris[:, 0]]
        part_vol = np.bincount(part, weights=vol)
        total = np.abs(part_vol).sum()
        keep = np.abs(part_vol) >= min_part * total
        if not keep.all():
            log.debug("dropping %d of %d parts below %g of the volume", (~keep).sum(), len(keep), min_part)
            tris = tris[keep[part]]
    used = np.zeros(len(verts), dtype=bool)
    used[tris.reshape(-1)] = True
    remap = np.cumsum(used) - 1
    return verts[used], remap[tris]
