"""Mesh -> solid: a triangle mesh as a :class:`~pointcvx.solid.raycast.Solid`, used as it is when
it already is a closed surface (:func:`closed_mesh_solid`), else closed by :func:`watertight_mesh`.

:func:`watertight_mesh` is mesh2sdf-style and takes any triangle soup (open, cracked,
multi-component, self-intersecting, any winding):

1. Grid: ``resolution`` vertices along the longest side of the mesh bounds, cubic voxels of size
   ``h``, a few voxels of padding around the bounds.
2. Narrow band: the surface is rasterised (dense samples of every triangle, each marking its
   nearest grid vertex), dilated by a ball of about three voxels (``level + h`` plus the
   rasterisation slack), and only there the exact unsigned distance and closest triangle are
   computed (Embree, via open3d ``compute_closest_points``). This is what makes the conversion
   fast: distance queries far from the surface are the slowest, and the band holds only a small
   share of the grid's vertices. Farther vertices only need a sign.
3. Sign by flood fill: grid vertices farther than ``level`` from the surface are free; the
   6-connected free components touching the grid boundary are outside, the rest inside (so
   enclosed voids are filled). Holes are sealed first: the walls are thickened by
   ``close_holes`` around the mesh's boundary edges only (the rims of holes and cracks), so holes
   narrower than about ``2 * close_holes`` do not let the flood in, while real gaps between
   closed parts stay open; the outside is then grown back into the thickened walls (leaving
   small dents where holes were plugged).
4. Triangles are classified by walking from their samples along both normal directions to the
   first flood-fill label: *interfaces* (outside on one side, inside on the other) bound the
   solid exactly; *sheets* (outside on both sides: open surfaces, parts thinner than about 1.5
   voxels) are thickened into a slab of half-thickness ``level``. The signed field is ``s * d``
   near interfaces and ``s * d - level`` near sheets (``s`` = -1 inside), so marching cubes at 0
   keeps closed parts at their true size (mesh2sdf's uniform offset of one voxel adds area x
   offset to every part) while thin parts still survive.
5. Marching cubes (scikit-image, Lewiner), outward winding, optional removal of tiny parts.

Deterministic: no randomness, the same input gives the same surface.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from ..cloud import check_points
from ..embree import raycasting_scene
from ..errors import InputError
from .grid import (
    ball_dilate,
    bbox_slices,
    box_dilate,
    dilate_within,
    edge_samples,
    flood_outside,
    grid_for,
    marching_cubes,
    triangle_samples,
    wind_outward,
)
from .raycast import Solid

log = logging.getLogger(__name__)

#: Default offset of open sheets, in voxels (mesh2sdf uses about one voxel everywhere).
SHEET_LEVEL_VOXELS = 0.75
#: Default hole-sealing radius, as a fraction of the longest side of the bounds.
CLOSE_HOLES = 0.03
#: Surface samples per voxel edge when rasterising triangles (spacing ``h * _STEP``).
_STEP = 0.3
#: Worst-case distance from a grid vertex within ``r`` of the surface to the vertex marked by
#: the rasterisation, beyond ``r``, in voxels: sample gap (1.12 * _STEP) + rounding (sqrt(3)/2).
_SLACK = 1.12 * _STEP + 0.8661


# ---------------------------------------------------------------------------------- triangles
def _soup(mesh: Any) -> tuple[np.ndarray, np.ndarray]:
    """(v, 3) float64 vertices and (f, 3) int64 faces of ``mesh``: validated, coincident
    vertices merged (so cracks show as boundary edges), degenerate faces dropped."""
    if isinstance(mesh, tuple) and len(mesh) == 2:
        vertices, faces = mesh
    else:
        vertices, faces = getattr(mesh, "vertices", None), getattr(mesh, "faces", None)
    if vertices is None or faces is None:
        raise InputError(f"expected a triangle mesh, got {type(mesh).__name__}")
    vertices = check_points(vertices, "mesh vertices")
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise InputError(f"mesh faces must have shape (f, 3) with f > 0, got {faces.shape}")
    faces = faces.astype(np.int64)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError("mesh faces reference missing vertices")
    scale = float((vertices.max(axis=0) - vertices.min(axis=0)).max())
    if scale <= 0.0:
        raise InputError("all mesh vertices are identical: the shape has no extent")
    key = np.round((vertices - vertices.min(axis=0)) / (scale * 1e-9)).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    vertices = vertices[first]
    faces = inverse.reshape(-1)[faces]
    tri = vertices[faces]
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    keep = area2 > (scale * 1e-10) ** 2
    if not keep.any():
        raise InputError("the mesh has no triangle with area: all faces are degenerate")
    return vertices, faces[keep]


def _boundary_edges(faces: np.ndarray) -> np.ndarray:
    """(b, 2) int64 vertex pairs of the edges used by exactly one face."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    n = int(edges.max()) + 1
    key = edges[:, 0] * n + edges[:, 1]
    uniq, counts = np.unique(key, return_counts=True)
    once = uniq[counts == 1]
    return np.stack([once // n, once % n], axis=1)


def _closest(vertices: np.ndarray, faces: np.ndarray, query: np.ndarray, chunk: int = 1 << 20):
    """Exact closest points of (n, 3) ``query`` on the triangles (Embree via open3d).

    Returns (n,) float32 distance, (n, 3) float32 closest points, (n,) int64 triangle ids.
    """
    from ..syslibs import import_open3d
    o3d = import_open3d()

    scene = raycasting_scene(vertices, faces)
    n = len(query)
    dist = np.empty(n, dtype=np.float32)
    near = np.empty((n, 3), dtype=np.float32)
    prim = np.empty(n, dtype=np.int64)
    for s in range(0, n, chunk):
        q = np.ascontiguousarray(query[s : s + chunk], dtype=np.float32)
        ans = scene.compute_closest_points(o3d.core.Tensor(q))
        cp = ans["points"].numpy()
        near[s : s + chunk] = cp
        dist[s : s + chunk] = np.linalg.norm(q - cp, axis=1)
        prim[s : s + chunk] = ans["primitive_ids"].numpy()
    return dist, near, prim


# ---------------------------------------------------------------------------------- any soup
def watertight_mesh(
    mesh: Any,
    resolution: int = 128,
    level: float | None = None,
    close_holes: float | None = CLOSE_HOLES,
    min_part: float = 1e-4,
):
    """A closed, outward-wound surface around any triangle soup (see the module docstring).

    Parameters
    ----------
    mesh : trimesh.Trimesh, or ((v, 3) float, (f, 3) int)
        Any triangles: open, cracked, multi-component, self-intersecting, any winding.
    resolution : int
        Grid vertices along the longest side of the bounds (memory and time grow as its cube).
    level : float, optional
        Half-thickness given to open sheets and parts too thin for the grid, in the mesh's
        units; default ``0.75`` voxel. Closed parts keep their true size.
    close_holes : float or None
        Holes and cracks narrower than about twice this radius are sealed, as a fraction of the
        longest side of the bounds (default 0.03); None or 0 seals only what ``level`` does.
        Larger holes let the flood fill in, and the part becomes a slab of thickness
        ``2 * level`` around its surface, like an open sheet.
    min_part : float
        Connected parts of the output enclosing less than this fraction of the total volume
        are dropped (marching-cubes specks); 0 keeps everything.

    Returns
    -------
    trimesh.Trimesh
        Watertight, outward-wound (positive volume), in the input's coordinates.
    """
    import trimesh

    if level is not None and not float(level) > 0:
        raise InputError(f"level must be positive, got {level}")
    vertices, faces = _soup(mesh)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    longest = float((hi - lo).max())

    def band_voxels(h: float) -> int:
        lv = SHEET_LEVEL_VOXELS if level is None else float(level) / h
        return int(math.ceil(lv + 1.0 + _SLACK))

    grid, k = grid_for(lo, hi, resolution, band_voxels)
    h = grid.h
    lvl = SHEET_LEVEL_VOXELS * h if level is None else float(level)
    band_radius = lvl / h + 1.0 + _SLACK  # voxels: every vertex within level + h of the surface
    tri = vertices[faces]

    # 1. Narrow band: rasterise the triangles, dilate, exact distances there only.
    band = np.zeros(grid.shape, dtype=bool)
    flat_band = band.reshape(-1)
    for pts, _ in triangle_samples(tri, _STEP * h):
        flat_band[grid.nearest(pts)] = True
    band = ball_dilate(band, band_radius)
    index = np.flatnonzero(band)
    dist, near, prim = _closest(vertices, faces, grid.positions(index))
    far_value = np.float32((k + 1) * h)
    d = np.full(grid.size, np.inf, dtype=np.float32)
    d[index] = dist
    d = d.reshape(grid.shape)

    # 2. Flood fill from the grid boundary, with walls thickened around boundary edges.
    free = d > lvl
    boundary = _boundary_edges(faces)
    seal_radius = 0.0 if not close_holes else float(close_holes) * longest
    kb = int(math.ceil(seal_radius / h)) if len(boundary) else 0
    if kb > 0:
        seal = np.zeros(grid.shape, dtype=bool)
        seal.reshape(-1)[
            grid.nearest(edge_samples(vertices[boundary[:, 0]], vertices[boundary[:, 1]], h / 2))
        ] = True
        box = bbox_slices(seal, kb)
        seal[box] = box_dilate(seal[box], kb)
        outside = flood_outside(free & ~seal)
        # Grow the outside back into the thickened walls (6-connected, never across a wall).
        grow = int(math.ceil(math.sqrt(3.0) * kb)) + 1
        box = bbox_slices(seal, grow + 1)
        outside[box] = dilate_within(outside[box], free[box], grow)
        del seal
    else:
        outside = flood_outside(free)
    # Labels for probing: 0 wall (d <= level), 1 outside, 2 inside.
    label = np.where(outside, np.uint8(1), np.where(free, np.uint8(2), np.uint8(0)))
    del free

    # 3. Classify triangles from both sides: interface (outward or inverted), sheet, internal.
    face_normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    face_normal /= np.linalg.norm(face_normal, axis=1, keepdims=True)
    # Walk away from each sample along +-n in half-voxel steps and take the first label that is
    # not wall: thin parts still find their inside (a grid vertex on the wrong side of the
    # surface is within level of it, so it reads as wall and is skipped).
    depths = 0.5 * h * np.arange(1, int(math.ceil((lvl + 2.0 * h) / (0.5 * h))) + 1)
    votes = np.zeros((len(faces), 4))  # out|in, in|out, out|out, in|in
    flat_label = label.reshape(-1)

    def first_label(pts: np.ndarray, direction: np.ndarray, labels: np.ndarray) -> np.ndarray:
        seen = np.zeros(len(pts), dtype=np.uint8)
        for delta in depths:
            todo = seen == 0
            if not todo.any():
                break
            seen[todo] = labels[grid.nearest(pts[todo] + delta * direction[todo])]
        return seen

    for pts, tid in triangle_samples(tri, 1.5 * h):
        nrm = face_normal[tid]
        front, back = first_label(pts, nrm, flat_label), first_label(pts, -nrm, flat_label)
        for j, (fa, ba) in enumerate(((1, 2), (2, 1), (1, 1), (2, 2))):
            hit = (front == fa) & (back == ba)
            votes[:, j] += np.bincount(tid, weights=hit, minlength=len(faces))
    interface = votes[:, 0] + votes[:, 1]
    is_interface = (interface > 0) & (interface >= votes[:, 2])
    is_internal = ~is_interface & (votes[:, 3] > votes[:, 2])
    is_sheet = ~is_interface & ~is_internal
    flip = np.where(votes[:, 1] > votes[:, 0], -1.0, 1.0)
    log.debug(
        "watertight: %d faces: %d interface, %d sheet, %d internal; %d boundary edges",
        len(faces), is_interface.sum(), is_sheet.sum(), is_internal.sum(), len(boundary),
    )

    # 4. Signed field: exact distance near interfaces, offset by `level` near sheets.
    lab = flat_label[index]
    sign = np.where(lab == 1, 1.0, -1.0)
    wall = lab == 0
    if wall.any():
        p = prim[wall]
        side = np.einsum(
            "ij,ij->i", grid.positions(index[wall]) - near[wall], face_normal[p] * flip[p, None]
        )
        sign[wall] = np.where(is_interface[p], np.where(side < 0, -1.0, 1.0), 1.0)
        sign[wall & is_internal[prim]] = -1.0
    values = sign * dist - lvl * is_sheet[prim]
    field = np.where(label.reshape(-1) == 1, far_value, -far_value).astype(np.float32)
    field[index] = values
    del label, d, flat_label
    verts, tris = marching_cubes(field.reshape(grid.shape), grid, far_value)
    verts, tris = wind_outward(verts, tris, min_part)
    if len(tris) == 0:
        raise InputError("watertight conversion produced an empty surface")
    return trimesh.Trimesh(verts, tris, process=False)


# ---------------------------------------------------------------------------------- closed input
def closed_mesh_solid(mesh: Any, max_pairs: int = 256) -> Solid | None:
    """``mesh`` itself as a :class:`Solid` when it already is a valid closed surface, else None.

    Valid: watertight and consistently wound, and its connected parts are disjoint or nested
    but never intersect (ray parity would miscount inside overlaps). Parts whose bounding boxes
    overlap are checked by testing up to 64 vertices of one against the other: all inside
    (nested) or all outside is fine, a mix means they intersect. Each part is wound outward if
    it is nested in an even number of others (solid), inward if odd (a void), so ``volume`` is
    right. More than ``max_pairs`` overlapping pairs: None (left to :func:`watertight_mesh`).
    """
    import trimesh

    if not (mesh.is_watertight and mesh.is_winding_consistent):
        return None
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(faces))
    n = int(labels.max()) + 1
    tri = vertices[faces]
    signed = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
    part_volume = np.bincount(labels, weights=signed, minlength=n)
    depth = np.zeros(n, dtype=np.int64)
    if n > 1:
        lo = np.full((n, 3), np.inf)
        hi = np.full((n, 3), -np.inf)
        np.minimum.at(lo, labels, tri.min(axis=1))
        np.maximum.at(hi, labels, tri.max(axis=1))
        overlap = ((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None])).all(axis=2)
        np.fill_diagonal(overlap, False)
        pairs = np.argwhere(overlap)  # (inner candidate, outer candidate), both orders
        if len(pairs) > 2 * max_pairs:
            return None
        for outer in np.unique(pairs[:, 1]):
            solid = Solid(vertices, faces[labels == outer])
            for inner in pairs[pairs[:, 1] == outer, 0]:
                verts = np.unique(faces[labels == inner])
                probe = vertices[verts[np.linspace(0, len(verts) - 1, min(64, len(verts))).astype(int)]]
                inside = solid.contains(probe)
                if inside.any() and not inside.all():
                    return None
                depth[inner] += int(inside.all())
    want = np.where(depth % 2 == 0, 1.0, -1.0)
    flip = (np.sign(part_volume) != want)[labels]
    if flip.any():
        faces = faces.copy()
        faces[flip] = faces[flip][:, ::-1]
    return Solid(vertices, faces)
