"""Convex hulls and CoACD's concavity metric, for the decomposition's stop rule and for evaluation.

One set of primitives serves two uses:

* :func:`part_concavity` -- the concavity of a part given only its surface samples and the whole
  shape's :class:`~pointcvx.solid.Solid`; fast enough for the recursive decomposition's hot loop.
* :func:`evaluate` -- the paper's evaluation protocol (CoACD's metric): concavity of every
  ``M ∩ hull_i`` with exact booleans (manifold3d), Chamfer reconstruction error, volume IoU and
  surface coverage of the union of hulls, in the [-1, 1]^3 frame of the shape.

Concavity (CoACD): ``Concavity(P) = max(Hb, k * Rv)`` with ``k = 0.3``, ``Hb`` the two-way
Hausdorff distance between the surface of ``P`` and the surface of its convex hull, and
``Rv = (3 |V(hull) - V(P)| / (4 pi))^(1/3)`` the radius of the sphere of the missing volume.

A :class:`Hull` is a convex polytope as arrays: outward triangles and outward plane equations
``n . x + d <= 0`` inside. Degenerate input (fewer than 4 points, coplanar or collinear points) gives
a flat hull of volume 0 rather than an error, so no decomposition stage can crash on a thin part.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import time
from dataclasses import dataclass

import numpy as np

from .cloud import check_points
from .errors import InputError

log = logging.getLogger(__name__)

K_CONCAVITY = 0.3
_CHUNK = 1 << 21  # entries of a (points x planes) block evaluated at once
_FOUR_THIRDS_PI = 4.0 * np.pi / 3.0
_FLOAT32_TOL = 1e-6  # plane tests in float32: "strictly inside" means deeper than this (relative)


# ---------------------------------------------------------------------------------------- hulls
@dataclass(eq=False)
class Hull:
    """A convex polytope.

    Attributes
    ----------
    vertices : (v, 3) float64
        Extreme points.
    faces : (f, 3) int64
        Triangles over ``vertices``, wound outward. Flat hulls list each triangle once per side;
        hulls of collinear or identical points have none.
    equations : (p, 4) float64
        Outward unit normals and offsets: a point ``x`` is inside when ``n . x + d <= 0`` for
        every row. Flat hulls carry both sides of their plane plus in-plane edge planes, so they
        describe a zero-thickness solid.
    volume : float
    area : float
        Total area of ``faces`` (both sides for a flat hull).
    dim : int
        3 for a solid hull, 2 flat, 1 a segment, 0 a point.
    index : (v,) int64, optional
        For a hull made by :func:`convex_hull`: the rows of its input that are the vertices
        (flat hulls: whose projections onto the plane are).
    """

    vertices: np.ndarray
    faces: np.ndarray
    equations: np.ndarray
    volume: float
    area: float
    dim: int = 3
    index: np.ndarray | None = None

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """((3,), (3,)) float: the axis-aligned bounding box."""
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    @property
    def triangles(self) -> np.ndarray:
        """(f, 3, 3) float: the corner coordinates of ``faces``."""
        return self.vertices[self.faces]

    def to_trimesh(self):
        """A ``trimesh.Trimesh`` of the hull's triangles (no processing)."""
        import trimesh

        return trimesh.Trimesh(self.vertices.copy(), self.faces.copy(), process=False)

    def __repr__(self) -> str:
        return (
            f"Hull(dim={self.dim}, vertices={len(self.vertices)}, faces={len(self.faces)}, "
            f"volume={self.volume:.6g}, area={self.area:.6g})"
        )


def _as_points(points, what: str = "points") -> np.ndarray:
    return check_points(points, what, allow_empty=True)


def _triangle_areas(tri: np.ndarray) -> np.ndarray:
    """(f,) float: areas of (f, 3, 3) triangles."""
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def _basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing unit ``normal`` (3,) to an orthonormal basis."""
    helper = np.eye(3)[int(np.argmin(np.abs(normal)))]
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(normal, u)


def _box_planes(center: np.ndarray, axes: np.ndarray, half: np.ndarray) -> np.ndarray:
    """(2a, 4) float: planes of the slab box ``|axes_j . (x - center)| <= half_j``."""
    rows = []
    for a, h in zip(axes, half, strict=True):
        for s in (1.0, -1.0):
            n = s * a
            rows.append(np.append(n, -float(n @ center) - h))
    return np.array(rows)


def _solid_hull(points: np.ndarray, options: str | None) -> Hull:
    from scipy.spatial import ConvexHull

    qh = ConvexHull(points, qhull_options=options)
    used = np.asarray(qh.vertices, dtype=np.int64)
    remap = np.full(len(points), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    faces = remap[np.asarray(qh.simplices, dtype=np.int64)]
    vertices = points[used]
    eq = np.asarray(qh.equations, dtype=np.float64)
    tri = vertices[faces]
    wrong = np.einsum("ij,ij->i", np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), eq[:, :3]) < 0
    faces[wrong] = faces[wrong][:, ::-1]
    return Hull(vertices, faces, eq, float(qh.volume), float(qh.area), 3, used)


def _flat_hull(points: np.ndarray, center: np.ndarray, normal: np.ndarray) -> Hull:
    """The hull of points lying (about) on the plane through ``center`` with unit ``normal``."""
    from scipy.spatial import ConvexHull, QhullError

    u, v = _basis(normal)
    uv = np.stack([(points - center) @ u, (points - center) @ v], axis=1)
    try:
        ring = np.asarray(ConvexHull(uv).vertices, dtype=np.int64)  # counter-clockwise in (u, v)
    except QhullError:
        return _line_hull(points)
    poly = center + uv[ring, :1] * u + uv[ring, 1:] * v  # projected onto the plane
    m = len(poly)
    fan = np.stack([np.zeros(m - 2, np.int64), np.arange(1, m - 1), np.arange(2, m)], axis=1)
    faces = np.concatenate([fan, fan[:, ::-1]])  # up side (ccw about +normal), then down side
    edges = np.roll(poly, -1, axis=0) - poly
    out = np.cross(edges, normal)  # in-plane, pointing away from a ccw polygon
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    eq = np.concatenate(
        [
            [np.append(normal, -float(normal @ center)), np.append(-normal, float(normal @ center))],
            np.concatenate([out, -np.einsum("ij,ij->i", out, poly)[:, None]], axis=1),
        ]
    )
    area = float(_triangle_areas(poly[fan]).sum())
    return Hull(poly, faces, eq, 0.0, 2.0 * area, 2, ring)


def _line_hull(points: np.ndarray) -> Hull:
    """The hull of collinear (or identical) points: a segment (or a point)."""
    center = points.mean(axis=0)
    centered = points - center
    _, _, vt = np.linalg.svd(centered, full_matrices=False)
    axis = vt[0]
    t = centered @ axis
    ends = np.array([int(np.argmin(t)), int(np.argmax(t))])
    lo, hi = points[ends[0]], points[ends[1]]
    length = float(t.max() - t.min())
    u, v = _basis(axis)
    if length <= 0.0:
        vertices, ends = points[:1].copy(), ends[:1] * 0
        eq = _box_planes(vertices[0], np.eye(3), np.zeros(3))
        dim = 0
    else:
        vertices = np.stack([lo, hi])
        eq = _box_planes((lo + hi) / 2, np.stack([axis, u, v]), np.array([length / 2, 0.0, 0.0]))
        dim = 1
    return Hull(vertices, np.zeros((0, 3), np.int64), eq, 0.0, 0.0, dim, ends)


def convex_hull(points) -> Hull:
    """The convex hull of (n, 3) ``points`` as a :class:`Hull`; never fails on degenerate input.

    Qhull first; if it refuses (precision trouble on nearly flat input) qhull again with joggled
    input (``QJ``). Coplanar points (within 1e-9 of the extent) give a flat hull, collinear ones a
    segment, identical ones a point, all of volume 0. Raises :class:`InputError` only for empty or
    non-finite input.
    """
    from scipy.spatial import QhullError

    pts = _as_points(points)
    if len(pts) == 0:
        raise InputError("no points to take the convex hull of")
    extent = float((pts.max(axis=0) - pts.min(axis=0)).max())
    if extent <= 0.0:
        return _line_hull(pts)
    center = pts.mean(axis=0)
    sub = pts[:: max(1, len(pts) // 20000)] - center
    _, sv, vt = np.linalg.svd(sub / extent, full_matrices=False)
    flat_tol = 1e-9 * np.sqrt(len(sub))
    if len(pts) < 4 or sv[2] <= flat_tol:
        if sv[1] <= flat_tol:
            return _line_hull(pts)
        return _flat_hull(pts, center, vt[2])
    for options in (None, "QJ"):
        try:
            return _solid_hull(pts, options)
        except QhullError as exc:
            log.debug("qhull failed with options %s: %s", options, str(exc).splitlines()[0])
    return _flat_hull(pts, center, vt[2])


def _signed_plane_distance(hull: Hull, points: np.ndarray, dtype=np.float64) -> np.ndarray:
    """(n,) float: max over the hull's planes of ``n . p + d`` (<= 0 inside; the exact distance
    to the boundary, negated, for points inside a solid hull; a lower bound of the distance for
    points outside). ``dtype=np.float32`` halves the cost for containment tests that allow an
    error of about 1e-6 (relative to the coordinates)."""
    normals = hull.equations[:, :3].T.astype(dtype)
    offsets = hull.equations[:, 3].astype(dtype)
    out = np.empty(len(points))
    step = max(1, _CHUNK // max(1, len(offsets)))
    for s in range(0, len(points), step):
        block = points[s : s + step].astype(dtype, copy=False) @ normals
        block += offsets
        out[s : s + step] = block.max(axis=1)
    return out


def _max_inside_depth(hull: Hull, points: np.ndarray, skip: np.ndarray | None = None) -> float:
    """max over (n, 3) ``points`` inside ``hull`` of their distance to its boundary (0 if none).

    Same value as ``distance_to_hull_boundary(hull, points).max()`` for points inside, without
    the full (points x planes) product: over 8192 points by :func:`_lipschitz_max`; otherwise an
    upper bound per point from a few candidate planes (those of the nearest facet centroids and
    of the largest facets), then exact depths in decreasing order of the bound until no
    remaining bound can beat the best exact depth. ``skip`` (int rows) are points known to lie
    on the boundary (the hull's vertices).
    """
    from scipy.spatial import cKDTree

    if skip is not None and len(points):
        keep = np.ones(len(points), dtype=bool)
        keep[skip] = False
        points = points[keep]
    if len(points) == 0 or hull.dim < 3:
        return 0.0
    eq = hull.equations
    if len(points) * len(eq) <= 1 << 19:
        return float(max(0.0, -_signed_plane_distance(hull, points).min()))
    if len(points) > 8192:  # the depth is 1-Lipschitz: bound most points by a few exact ones
        return _lipschitz_max(points, lambda q: np.maximum(-_signed_plane_distance(hull, q), 0.0), 16)
    centers = hull.triangles.mean(axis=1)
    kk = min(2, len(centers))
    tree = cKDTree(centers, leafsize=32, balanced_tree=False, compact_nodes=False)
    idx = tree.query(points, k=kk)[1].reshape(len(points), kk)
    cand = eq[idx]  # (n, kk, 4) (faces and equations are row-aligned for solid hulls)
    sd = np.einsum("nkj,nj->nk", cand[..., :3], points) + cand[..., 3]
    big = eq[np.argsort(-_triangle_areas(hull.triangles))[:16]]
    sd = np.concatenate([sd, points @ big[:, :3].T + big[:, 3]], axis=1)
    bound = np.maximum(-sd.max(axis=1), 0.0)  # >= true depth of each point
    order = np.argsort(-bound)
    best, s, step = 0.0, 0, 32
    cap = max(32, _CHUNK // max(1, len(eq)))
    while s < len(order) and bound[order[s]] > best:
        chunk = order[s : s + step]
        chunk = chunk[bound[chunk] > best]
        block = points[chunk] @ eq[:, :3].T
        block += eq[:, 3]
        best = max(best, float(-block.max(axis=1).min()))
        s, step = s + step, min(2 * step, cap)
    return best


def hull_contains(hull: Hull, points, tol: float = 1e-9) -> np.ndarray:
    """(n,) bool: which (n, 3) ``points`` are inside ``hull`` or within ``tol`` outside its planes.

    A negative ``tol`` asks for points strictly inside, at least ``-tol`` from every facet plane.
    """
    pts = _as_points(points)
    return _signed_plane_distance(hull, pts) <= tol


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = b - a
    den = float(d @ d)
    t = np.zeros(len(points)) if den <= 0 else np.clip((points - a) @ d / den, 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * d), axis=1)


def _distance_fn(vertices: np.ndarray, faces: np.ndarray):
    """A function (n, 3) points -> (n,) unsigned distance to a triangle soup (Embree, float32)."""
    from .syslibs import import_open3d
    o3d = import_open3d()

    from .solid import raycasting_scene

    scene = raycasting_scene(vertices, faces)

    def distance(points: np.ndarray) -> np.ndarray:
        q = o3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float32))
        return scene.compute_distance(q).numpy().astype(np.float64)

    return distance


def _triangle_distance(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n,) float: unsigned distance from (n, 3) ``points`` to a triangle soup (Embree, float32)."""
    return _distance_fn(vertices, faces)(points)


def _lipschitz_max(points: np.ndarray, fn, stride: int = 8) -> float:
    """max over (n, 3) ``points`` of a 1-Lipschitz function ``fn`` ((m, 3) -> (m,)), exactly,
    evaluating ``fn`` on every ``stride``-th point and then only where the bound
    ``fn(q) + |p - q|`` (q the nearest evaluated point) could beat the best value found."""
    from scipy.spatial import cKDTree

    n = len(points)
    if n == 0:
        return 0.0
    if n <= 4 * 1024:
        return float(fn(points).max())
    sub = np.arange(0, n, stride)
    vals = fn(points[sub])
    best = float(vals.max())
    rest = np.setdiff1d(np.arange(n), sub, assume_unique=True)
    tree = cKDTree(points[sub], leafsize=32, balanced_tree=False, compact_nodes=False)
    d, j = tree.query(points[rest])
    bound = vals[j] + d
    cand = rest[bound > best]
    bound = bound[bound > best]
    order = np.argsort(-bound)
    s, step = 0, 256
    while s < len(order) and bound[order[s]] > best:
        best = max(best, float(fn(points[cand[order[s : s + step]]]).max()))
        s, step = s + step, 2 * step
    return best


def distance_to_hull_boundary(hull: Hull, points) -> np.ndarray:
    """(n,) float: unsigned distance from (n, 3) ``points`` to the boundary of ``hull``.

    Points inside: ``min_j -(n_j . p + d_j)`` over the facet planes (exact for a convex solid).
    Points outside: the exact distance to the hull's triangles (Embree, float32 precision), or to
    the segment / point of a degenerate hull.
    """
    pts = _as_points(points)
    sd = _signed_plane_distance(hull, pts)
    dist = np.maximum(-sd, 0.0)
    if hull.dim < 3:
        dist[:] = 0.0
    scale = float(np.abs(hull.vertices).max()) if len(hull.vertices) else 1.0
    outside = sd > 1e-12 * max(scale, 1.0)
    if outside.any():
        q = pts[outside]
        if hull.dim >= 2:
            dist[outside] = _triangle_distance(hull.vertices, hull.faces, q)
        else:
            dist[outside] = _segment_distance(q, hull.vertices[0], hull.vertices[-1])
    return dist


def _sample_triangles(tri: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) float area-weighted uniform samples of (f, 3, 3) triangles and (n,) int their faces."""
    area = _triangle_areas(tri)
    total = area.sum()
    if n <= 0 or len(tri) == 0 or not total > 0:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    face = rng.choice(len(tri), size=n, p=area / total)
    r1, r2 = rng.random((2, n))
    s1 = np.sqrt(r1)
    w = np.stack([1.0 - s1, s1 * (1.0 - r2), s1 * r2], axis=1)
    return np.einsum("nk,nkj->nj", w, tri[face]), face


def _sample_hull_surface(hull: Hull, n: int, rng: np.random.Generator) -> np.ndarray:
    if n <= 0:
        return np.zeros((0, 3))
    if hull.dim >= 2 and hull.area > 0:
        return _sample_triangles(hull.triangles, n, rng)[0]
    a, b = hull.vertices[0], hull.vertices[-1]
    return a + rng.random(n)[:, None] * (b - a)


def sample_hull_surface(hull: Hull, n: int, seed: int = 0) -> np.ndarray:
    """(n, 3) float: area-weighted uniform samples of the hull's boundary, seeded.

    Degenerate hulls: uniform on the polygon (flat), on the segment, or the point repeated.
    """
    return _sample_hull_surface(hull, int(n), np.random.default_rng(seed))


def _sample_hull_interior(hull: Hull, n: int, rng: np.random.Generator) -> np.ndarray:
    if n <= 0:
        return np.zeros((0, 3))
    if hull.dim < 3 or not hull.volume > 0:
        return _sample_hull_surface(hull, n, rng)
    apex = hull.vertices.mean(axis=0)  # interior: the hull is convex
    tri = hull.triangles - apex
    vol = np.abs(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])))
    tet = rng.choice(len(tri), size=n, p=vol / vol.sum())
    w = -np.log(1.0 - rng.random((n, 4)))  # Dirichlet(1, 1, 1, 1): uniform in a tetrahedron
    w /= w.sum(axis=1, keepdims=True)
    return apex + np.einsum("nk,nkj->nj", w[:, 1:], tri[tet])


def sample_hull_interior(hull: Hull, n: int, seed: int = 0) -> np.ndarray:
    """(n, 3) float: uniform samples of the hull's volume (fan of tetrahedra from the vertex
    mean, no rejection), seeded. Hulls of volume 0 give surface samples."""
    return _sample_hull_interior(hull, int(n), np.random.default_rng(seed))


# ---------------------------------------------------------------------------------- distances
def nearest_distance(points, targets) -> np.ndarray:
    """(n,) float: Euclidean distance from each of (n, 3) ``points`` to the nearest of (m, 3)
    ``targets`` (kd-tree)."""
    from scipy.spatial import cKDTree

    pts = _as_points(points)
    tgt = _as_points(targets, "targets")
    if len(pts) == 0:
        return np.zeros(0)
    if len(tgt) == 0:
        raise InputError("no target points to measure distances to")
    tree = cKDTree(tgt, leafsize=32, balanced_tree=False, compact_nodes=False)
    return tree.query(pts, workers=-1 if len(pts) > 50000 else 1)[0]


def chamfer_distance(a, b) -> float:
    """Chamfer distance of two samplings (n, 3) and (m, 3): the mean of the two directional mean
    nearest-neighbour Euclidean distances, ``(mean_a d(a, B) + mean_b d(b, A)) / 2``."""
    return 0.5 * float(nearest_distance(a, b).mean() + nearest_distance(b, a).mean())


def hausdorff_distance(a, b) -> float:
    """Two-way Hausdorff distance of two samplings (n, 3) and (m, 3)."""
    return float(max(nearest_distance(a, b).max(), nearest_distance(b, a).max()))


def rv_term(volume_difference: float) -> float:
    """CoACD's Rv: radius of the sphere of volume ``|volume_difference|``."""
    return float((abs(volume_difference) / _FOUR_THIRDS_PI) ** (1.0 / 3.0))


def _concavity_terms(hb_part: float, hb_hull: float, hull_volume: float, part_volume: float,
                     k: float) -> dict[str, float]:
    """CoACD's concavity ``max(Hb, k * Rv)`` from its two Hausdorff directions and the volumes,
    with every term, as both concavity functions report them."""
    hb = max(hb_part, hb_hull)
    rv = rv_term(hull_volume - part_volume)
    return {
        "concavity": max(hb, k * rv),
        "hb": hb,
        "hb_part": hb_part,
        "hb_hull": hb_hull,
        "rv": rv,
        "hull_volume": float(hull_volume),
        "part_volume": float(part_volume),
    }


# ------------------------------------------------------------------- concavity during decomposition
#: Hull-surface samples closer than this to the solid's surface lie on the shape, not in the
#: air (normalised frame).
SURFACE_TOL = 1e-3
#: A part's samples leave gaps of up to about this many times their typical spacing.
GAP_SPACINGS = 4.0


def _max_outside(solid, samples: np.ndarray, dist: np.ndarray, surface_gap: float = 0.0,
                 tol: float = SURFACE_TOL) -> float:
    """max of (n,) ``dist`` over the (n, 3) hull-surface ``samples`` that are concavity (0 if
    none): those in the air (outside ``solid``), and those on the solid's surface (within
    ``tol``) further than ``surface_gap`` from the part.

    A sample on the surface near the part sits on a face the part shares with its hull, in a gap
    between the part's samples: not concavity. One on the surface far from the part lies on
    *another* part's face: the hull spreads over it. (The inside test of a point on the surface
    depends on the face's orientation, so surface samples are told apart by distance first.)
    Tests samples in decreasing order of ``dist``, in growing batches, and stops at the first
    batch holding one that counts: exact, and cheap unless most far samples are inside.
    """
    order = np.argsort(-dist)
    s, step = 0, 64
    while s < len(order):
        chunk = order[s : s + step]
        on_surface = solid.distance(samples[chunk]) <= tol
        counts = on_surface & (dist[chunk] > surface_gap)
        air = np.flatnonzero(~on_surface)
        if len(air):
            counts[air] = ~solid.contains(samples[chunk[air]])
        if counts.any():
            return float(dist[chunk[int(np.argmax(counts))]])
        s, step = s + step, 4 * step
    return 0.0


def sample_spacing(points: np.ndarray) -> float:
    """Median distance from each of the (n, 3) ``points`` to its nearest neighbour."""
    from scipy.spatial import cKDTree

    if len(points) < 2:
        return 0.0
    return float(np.median(cKDTree(points).query(points, k=2)[0][:, 1]))


def part_concavity(
    points,
    solid,
    *,
    k: float = K_CONCAVITY,
    hull: Hull | None = None,
    n_hull_samples: int = 1000,
    n_volume_samples: int = 1000,
    seed: int = 0,
    surface_gap: float | None = None,
    return_terms: bool = False,
):
    """Concavity of a part known by its surface samples, inside the whole shape's solid.

    Parameters
    ----------
    points : (n, 3) float
        Samples of the part's share of the shape's surface. Where the part was cut from the rest
        of the shape there is no surface, hence no samples (no cap).
    solid : pointcvx.solid.Solid or None
        The whole shape. ``None`` gives the pure surface version (see below).
    k : float
        Weight of the volume term (CoACD: 0.3).
    hull : Hull, optional
        ``convex_hull(points)`` if already known (saves the qhull call, about a third of the
        time); it must be the hull of ``points``: points outside it count as depth 0.
    n_hull_samples, n_volume_samples : int
        Samples of the hull's surface (for Hb) and of its volume (for Rv).
    seed : int
        Seeds both samplings; same input and seed, same result.
    surface_gap : float, optional
        The largest gap expected between neighbouring part samples (default: ``GAP_SPACINGS``
        times their median spacing). Hull-surface samples on the solid's surface and within
        this of the part lie on the part's own faces and are not concavity.
    return_terms : bool
        Return a dict of the terms instead of the concavity alone.

    Returns
    -------
    float, or dict with ``concavity``, ``hb``, ``hb_part`` (part -> hull), ``hb_hull``
    (hull -> part), ``rv``, ``hull_volume``, ``part_volume``, ``outside_fraction``.

    Definition
    ----------
    With ``H = conv(points)`` and ``S`` the solid::

        Hb = max( max_p dist(p, boundary of H),
                  max over hull-surface samples h NOT inside S of min_p |h - p| )
        Rv = (3 |V(H) - V(H ∩ S)| / (4 pi))^(1/3)
        concavity = max(Hb, k * Rv)

    ``dist(p, boundary of H)`` is exact (facet planes; the points are inside their hull). The
    hull-surface samples inside the solid lie on or across the cut, through the interior, where the
    part has no samples: they are not concavity and are skipped. The part's volume is the solid
    inside its hull: ``V(H) - V(H ∩ S)`` is ``V(H)`` times the fraction of ``n_volume_samples``
    uniform samples of ``H`` that fall outside ``S`` (Monte Carlo). Material of other parts that
    lies inside ``H`` therefore counts as the part's, as in :func:`evaluate` (``M ∩ hull``).

    ``solid=None``: ``Hb`` counts every hull-surface sample and ``Rv = 0``.

    The hull -> part direction measures distances to the nearest *sample*. Where a face of the
    part is also a face of its hull (a box, a flat CAD face), hull samples lie on the solid's
    surface, between part samples: they are skipped when within ``surface_gap`` of the part, so
    a convex part measures 0 whatever its sampling density. A hull face spread over the surface of
    *another* part (two boxes of an L grouped into overlapping hulls) is further than that from
    the part's samples and still counts.
    """
    pts = _as_points(points)
    if len(pts) == 0:
        raise InputError("the part has no points")
    own_hull = hull is None
    if own_hull:
        hull = convex_hull(pts)
    rng = np.random.default_rng(seed)
    hs = _sample_hull_surface(hull, int(n_hull_samples), rng)
    d_hs = nearest_distance(hs, pts) if len(hs) else np.zeros(0)
    hb_part = _max_inside_depth(hull, pts, hull.index if own_hull else None)
    part_volume = hull.volume
    outside_fraction = 0.0
    if solid is None:
        hb_hull = float(d_hs.max(initial=0.0))
    else:
        if hull.volume > 0 and n_volume_samples > 0:
            vs = _sample_hull_interior(hull, int(n_volume_samples), rng)
            outside_fraction = float(1.0 - solid.contains(vs).mean())
            part_volume = hull.volume * (1.0 - outside_fraction)
        if surface_gap is None:
            surface_gap = GAP_SPACINGS * sample_spacing(pts)
        hb_hull = _max_outside(solid, hs, d_hs, surface_gap)
    terms = _concavity_terms(hb_part, hb_hull, hull.volume, part_volume, k)
    terms["outside_fraction"] = outside_fraction
    return terms if return_terms else terms["concavity"]


# ------------------------------------------------------------------------------ evaluation
def mesh_concavity(
    vertices,
    faces,
    *,
    k: float = K_CONCAVITY,
    n_samples: int = 20000,
    seed: int = 0,
    volume: float | None = None,
    return_terms: bool = False,
):
    """CoACD's concavity of a closed, outward triangle mesh (v, 3) / (f, 3).

    ``Hb`` is the two-way Hausdorff distance between ``n_samples`` samples of the mesh's surface
    and ``n_samples`` samples of its convex hull's surface, each sample measured to the *other
    surface* (as CoACD does): mesh samples to the hull's boundary by the facet planes (exact),
    hull samples to the mesh's triangles (Embree). ``Rv`` uses the exact volumes (``volume``
    overrides the mesh's signed volume).
    """
    v = _as_points(vertices, "vertices")
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        raise InputError("the mesh has no faces")
    rng = np.random.default_rng(seed)
    tri = v[f]
    if volume is None:
        volume = float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)
    hull = convex_hull(v[np.unique(f)])
    sp = _sample_triangles(tri, int(n_samples), rng)[0]
    sh = _sample_hull_surface(hull, int(n_samples), rng)
    hb_part = _max_inside_depth(hull, sp)
    hb_hull = _lipschitz_max(sh, _distance_fn(v, f))
    terms = _concavity_terms(hb_part, hb_hull, hull.volume, volume, k)
    return terms if return_terms else terms["concavity"]


def _hull_of(item) -> np.ndarray:
    """(m, 3) float: the points whose hull a hull-like ``item`` is (Hull, mesh or points)."""
    if isinstance(item, Hull):
        return item.vertices
    if hasattr(item, "vertices"):
        return _as_points(np.asarray(item.vertices), "hull vertices")
    return _as_points(item, "hull points")


def _hull_points(hulls) -> list[np.ndarray]:
    """The (m_i, 3) float points of each hull-like item; InputError when there is no hull or a
    hull has no vertex."""
    raw = [_hull_of(h) for h in hulls]
    if not raw:
        raise InputError("no hulls to evaluate")
    if any(len(r) == 0 for r in raw):
        raise InputError("a hull has no vertices")
    return raw


def _closed_mesh(mesh, resolution: int):
    """(closed outward trimesh, how it was obtained) from any trimesh.Trimesh: the mesh itself
    when it already bounds a solid (watertight, consistently wound, parts disjoint or nested),
    else :func:`pointcvx.watertight.watertight_mesh`."""
    import trimesh

    from . import watertight
    from .io.mesh import clean_mesh

    cleaned = clean_mesh(mesh)
    as_solid = getattr(watertight, "closed_mesh_solid", None)
    if as_solid is not None:
        solid = as_solid(cleaned)
        if solid is not None:
            return trimesh.Trimesh(solid.vertices, solid.faces, process=False), "input (watertight)"
    elif (
        cleaned.is_watertight
        and cleaned.is_winding_consistent
        and len(cleaned.split(only_watertight=False)) == 1
    ):
        if cleaned.volume < 0:
            cleaned.invert()
        return cleaned, "input (watertight)"
    closed = watertight.watertight_mesh(cleaned, resolution=resolution)
    return closed, f"watertight_mesh(resolution={resolution})"


def _to_manifold(vertices: np.ndarray, faces: np.ndarray):
    import manifold3d as m3

    if hasattr(m3, "Mesh64"):  # manifold3d >= 3: double precision
        mesh = m3.Mesh64(
            np.ascontiguousarray(vertices, dtype=np.float64), np.ascontiguousarray(faces, dtype=np.uint64)
        )
    else:
        mesh = m3.Mesh(
            np.ascontiguousarray(vertices, dtype=np.float32), np.ascontiguousarray(faces, dtype=np.uint32)
        )
    return m3.Manifold(mesh)


def _pieces_manifold(mv, mf, hulls: list[Hull]):
    """Per hull: (vertices, faces, volume) of ``M ∩ hull`` or None when empty; raises
    RuntimeError when manifold3d rejects ``M``."""
    import manifold3d as m3

    solid = _to_manifold(mv, mf)
    if solid.status() != m3.Error.NoError or solid.is_empty():
        raise RuntimeError(f"manifold3d rejects the mesh ({solid.status().name})")
    out = []
    for h in hulls:
        if h.dim < 3 or not h.volume > 0:
            out.append(None)
            continue
        piece = solid ^ m3.Manifold.hull_points(np.ascontiguousarray(h.vertices, dtype=np.float64))
        if piece.is_empty() or not piece.volume() > 0:
            out.append(None)
            continue
        m = piece.to_mesh64() if hasattr(piece, "to_mesh64") else piece.to_mesh()
        out.append(
            (
                np.asarray(m.vert_properties)[:, :3].astype(np.float64),
                np.asarray(m.tri_verts, dtype=np.int64),
                float(piece.volume()),
            )
        )
    return out


def _piece_concavity_mc(solid, mv, mf, hull: Hull, n: int, seed: int, k: float) -> float | None:
    """Monte-Carlo concavity of ``M ∩ hull`` when exact booleans are unavailable: the piece's
    surface = samples of M's surface inside the hull + samples of the hull's surface inside M;
    its volume = V(hull) x the fraction of uniform hull samples inside M."""
    if hull.dim < 3 or not hull.volume > 0:
        return None
    rng = np.random.default_rng(seed)
    lo, hi = hull.bounds
    tri = mv[mf]
    near = np.all((tri.max(axis=1) >= lo) & (tri.min(axis=1) <= hi), axis=1)
    sm = _sample_triangles(tri[near], n, rng)[0]
    sm = sm[hull_contains(hull, sm)] if len(sm) else sm
    sh = _sample_hull_surface(hull, n, rng)
    vs = _sample_hull_interior(hull, n, rng)
    inside = solid.contains(np.concatenate([sh, vs]))
    surface = np.concatenate([sm, sh[inside[:n]]])
    frac = float(inside[n:].mean())
    if len(surface) < 4 or frac <= 0:
        return None
    conv = convex_hull(surface)
    hb_part = _max_inside_depth(conv, surface, conv.index)
    cs = _sample_hull_surface(conv, n, rng)
    hb_hull = float(nearest_distance(cs, surface).max())
    return max(hb_part, hb_hull, k * rv_term(conv.volume - hull.volume * frac))


def _union_surface_samples(hulls: list[Hull], n: int, rng: np.random.Generator) -> np.ndarray:
    """(about n, 3) float: uniform samples of the boundary of the union of hulls.

    Each hull's surface is sampled by area; a sample is dropped when it lies strictly inside
    another hull, when it lies on an interface (just outside it along its face normal is inside
    another hull: abutting hulls), or when it lies on the boundary of a hull of lower index
    facing the same way (coplanar faces shared by several hulls are sampled once).
    """
    areas = np.array([h.area for h in hulls])
    if not areas.sum() > 0:
        return np.concatenate([_sample_hull_surface(h, 1, rng) for h in hulls])
    scale = max(1.0, max(float(np.abs(h.vertices).max()) for h in hulls))
    on_tol, step = 10 * _FLOAT32_TOL * scale, 100 * _FLOAT32_TOL * scale

    def draw(m: int) -> np.ndarray:
        counts = rng.multinomial(m, areas / areas.sum())
        parts, owners, normals = [], [], []
        for i, (h, c) in enumerate(zip(hulls, counts, strict=True)):
            c = int(c)
            if h.dim >= 2 and h.area > 0:
                tri = h.triangles
                pts, face = _sample_triangles(tri, c, rng)
                nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
                nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
                normals.append(nrm[face])
            else:
                pts = _sample_hull_surface(h, c, rng)
                normals.append(np.zeros((c, 3)))
            parts.append(pts)
            owners.append(np.full(c, i))
        pts, owner, nrm = np.concatenate(parts), np.concatenate(owners), np.concatenate(normals)
        drop = np.zeros(len(pts), dtype=bool)
        for j, h in enumerate(hulls):
            if h.dim < 3:
                continue
            lo, hi = h.bounds
            near = np.all((pts >= lo - step) & (pts <= hi + step), axis=1)
            cand = np.flatnonzero((owner != j) & ~drop & near)
            if len(cand) == 0:
                continue
            sd = _signed_plane_distance(h, pts[cand], np.float32)
            out = _signed_plane_distance(h, pts[cand] + step * nrm[cand], np.float32)
            gone = (sd < -on_tol) | (out <= 0.0) | ((np.abs(sd) <= on_tol) & (owner[cand] > j))
            drop[cand[gone]] = True
        return pts[~drop]

    first = draw(n)
    kept = len(first) / n
    if kept >= 0.999 or len(first) == 0:
        return first
    more = draw(int(np.ceil(n / max(kept, 0.05) * 1.1)))
    return more[rng.permutation(len(more))[:n]] if len(more) > n else more


def _inside_any(hulls: list[Hull], points: np.ndarray, tol: float) -> np.ndarray:
    inside = np.zeros(len(points), dtype=bool)
    for h in hulls:
        lo, hi = h.bounds
        cand = np.flatnonzero(~inside & np.all((points >= lo - tol) & (points <= hi + tol), axis=1))
        if len(cand):
            sd = _signed_plane_distance(h, points[cand], np.float32)
            inside[cand[sd <= tol]] = True
    return inside


def evaluate(
    mesh,
    hulls,
    *,
    n_samples: int = 20000,
    seed: int = 0,
    k: float = K_CONCAVITY,
    n_volume_samples: int = 100000,
    coverage_tol: float = 0.01,
    watertight_resolution: int = 128,
) -> dict:
    """Score a convex decomposition the way the paper does (CoACD's metric).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The shape, in any units.
    hulls : sequence of Hull, trimesh.Trimesh or (m, 3) float
        The decomposition, in the shape's units; each item stands for the convex hull of its
        points.
    n_samples : int
        Surface samples per piece, per hull surface and per shape (paper: 20,000).
    seed : int
        Seeds every sampling; same input and seed, same result.
    k : float
        Weight of the volume term (0.3).
    n_volume_samples : int
        Uniform samples of the common bounding box for the volume IoU.
    coverage_tol : float
        Distance (in the [-1, 1]^3 frame) by which a surface sample may lie outside the hulls and
        still count as covered.
    watertight_resolution : int
        Resolution for :func:`pointcvx.watertight.watertight_mesh` when the mesh is not closed.

    Returns
    -------
    dict
        ``hulls`` (count), ``concavity`` (max over hulls), ``reconstruction`` (Chamfer),
        ``iou``, ``coverage``, ``per_hull_concavity`` (0.0 for empty pieces), ``empty_hulls``
        (indices whose piece is empty), ``pieces`` (how pieces were computed), ``shape`` (how the
        closed shape was obtained), ``seconds``.

    Protocol
    --------
    The shape is normalised to [-1, 1]^3 (bounding-box centre to the origin, half the longest side
    to 1) and the same transform is applied to the hulls. ``M`` is the shape itself when it is
    watertight and consistently wound, else ``watertight_mesh(mesh)``.

    * concavity = ``max_i Concavity(M ∩ hull_i)`` (:func:`mesh_concavity`; pieces by manifold3d
      boolean intersection, empty pieces skipped, ``Rv`` from exact volumes). Should manifold3d
      reject ``M``, pieces are estimated by Monte Carlo instead and ``pieces`` says so.
    * reconstruction = Chamfer distance between ``n_samples`` samples of ``M`` and ``n_samples``
      samples of the boundary of the union of hulls (each hull's surface minus what lies strictly
      inside another hull or on an interface between abutting hulls): the mean of the two
      directional mean nearest-neighbour Euclidean distances (CoACD-style). Being sample to
      sample, a perfect reconstruction scores about half the samples' spacing,
      ``0.5 sqrt(area / n_samples)``.
    * iou = ``V(M ∩ U) / V(M ∪ U)`` for the union ``U`` of hulls, by Monte Carlo over the common
      bounding box.
    * coverage = share of the samples of ``M`` inside ``U`` or within ``coverage_tol`` of it.
    """
    t0 = time.perf_counter()
    with _one_blas_thread():  # skinny (n x 3) @ (3 x f) products: BLAS threads only spin
        result = _evaluate(
            mesh, hulls, n_samples, seed, k, n_volume_samples, coverage_tol, watertight_resolution
        )
    result["seconds"] = time.perf_counter() - t0
    return result


def _one_blas_thread():
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - scikit-learn brings it
        return contextlib.nullcontext()
    return threadpool_limits(1, user_api="blas")


def _evaluate(mesh, hulls, n_samples, seed, k, n_volume_samples, coverage_tol, watertight_resolution):
    import trimesh

    from .cloud import Normalization
    from .solid import Solid

    if not isinstance(mesh, trimesh.Trimesh):
        raise InputError(f"expected a triangle mesh, got {type(mesh).__name__}")
    raw = _hull_points(hulls)
    norm = Normalization.to_unit_cube(np.asarray(mesh.vertices)[np.unique(np.asarray(mesh.faces))])
    unit = mesh.copy()
    unit.apply_transform(norm.as_matrix())
    closed, shape_note = _closed_mesh(unit, watertight_resolution)
    mv = np.asarray(closed.vertices, dtype=np.float64)
    mf = np.asarray(closed.faces, dtype=np.int64)
    hl = [convex_hull(norm.forward(r)) for r in raw]

    per_hull = np.zeros(len(hl))
    empty: list[int] = []
    solid = Solid(mv, mf)
    try:
        pieces = _pieces_manifold(mv, mf, hl)
        pieces_note = "manifold3d boolean intersection"
    except (RuntimeError, ImportError) as exc:
        log.warning("exact pieces unavailable (%s): Monte-Carlo estimate instead", exc)
        pieces = None
        pieces_note = f"monte-carlo estimate ({exc})"
    for i, h in enumerate(hl):
        if pieces is not None:
            c = None
            if pieces[i] is not None:
                pv, pf, vol = pieces[i]
                c = mesh_concavity(pv, pf, k=k, n_samples=n_samples, seed=seed + i, volume=vol)
        else:
            c = _piece_concavity_mc(solid, mv, mf, h, n_samples, seed + i, k)
        if c is None:
            empty.append(i)
        else:
            per_hull[i] = c

    from .io.mesh import sample_surface

    rng = np.random.default_rng(seed)
    sm = sample_surface(closed, int(n_samples), seed=seed)[0]
    su = _union_surface_samples(hl, int(n_samples), rng)
    reconstruction = chamfer_distance(sm, su)
    coverage = float(_inside_any(hl, sm, coverage_tol).mean())

    lo = np.minimum(mv.min(axis=0), np.min([h.bounds[0] for h in hl], axis=0))
    hi = np.maximum(mv.max(axis=0), np.max([h.bounds[1] for h in hl], axis=0))
    q = rng.uniform(lo, hi, size=(int(n_volume_samples), 3))
    in_m = solid.contains(q)
    in_u = _inside_any(hl, q, 0.0)
    union = int((in_m | in_u).sum())
    iou = float((in_m & in_u).sum() / union) if union else 0.0

    return {
        "hulls": len(hl),
        "concavity": float(per_hull.max()),
        "reconstruction": float(reconstruction),
        "iou": iou,
        "coverage": coverage,
        "per_hull_concavity": [float(c) for c in per_hull],
        "empty_hulls": empty,
        "pieces": pieces_note,
        "shape": shape_note,
    }


def evaluate_points(points, hulls, *, n_samples: int = 20000, seed: int = 0,
                    coverage_tol: float = 0.01) -> dict:
    """Score a decomposition of a shape known only as points (a splat or a scan).

    Without a closed surface there is no part volume, so only the surface terms are measured:
    both are taken after normalising ``points`` to [-1, 1]^3.

    Parameters
    ----------
    points : (n, 3) float
        The shape's surface points (e.g. the loaded splat centres), in the hulls' units.
    hulls : sequence of Hull, trimesh.Trimesh or (m, 3) float
    n_samples : int
        Points drawn from ``points`` and from the union of hull surfaces.
    seed : int
    coverage_tol : float
        Distance (normalised units) within which a point counts as inside a hull.

    Returns
    -------
    dict with ``hulls``, ``reconstruction`` (Chamfer distance between the points and the union
    of hull surfaces), ``coverage`` (fraction of points inside some hull) and ``outside_max`` (the
    largest distance from a point to the union, i.e. the worst uncovered point).
    """
    from .cloud import Normalization

    pts = _as_points(points)
    raw = _hull_points(hulls)
    norm = Normalization.to_unit_cube(pts)
    pts = norm.forward(pts)
    hl = [convex_hull(norm.forward(r)) for r in raw]
    rng = np.random.default_rng(seed)
    if len(pts) > n_samples:
        pts = pts[rng.choice(len(pts), int(n_samples), replace=False)]
    su = _union_surface_samples(hl, int(n_samples), rng)
    inside = _inside_any(hl, pts, coverage_tol)
    outside = nearest_distance(pts[~inside], su) if (~inside).any() else np.zeros(1)
    return {
        "hulls": len(hl),
        "reconstruction": chamfer_distance(pts, su),
        "coverage": float(inside.mean()),
        "outside_max": float(outside.max()),
    }


# ------------------------------------------------------------------------------------ files
def _obj_object_order(path: str) -> list[str]:
    names = []
    with open(path, errors="replace") as f:
        for line in f:
            m = re.match(r"o\s+(.+?)\s*$", line)
            if m:
                names.append(m.group(1))
    return names


def _components(mesh) -> list[np.ndarray]:
    """Vertex arrays of the closed bodies of ``mesh``: faces are connected through edges that
    exactly two faces share, so hulls touching at a corner or along an edge stay apart. A
    triangle soup (STL) is welded first."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if len(mesh.vertices) == 3 * len(mesh.faces):
        mesh = mesh.copy()
        mesh.merge_vertices()
    faces = np.asarray(mesh.faces, dtype=np.int64)
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, inverse, counts = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    owner = np.repeat(np.arange(len(faces)), 3)
    shared = counts[inverse] == 2
    order = np.argsort(inverse[shared], kind="stable")
    pairs = owner[shared][order].reshape(-1, 2)
    nf = len(faces)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(nf, nf))
    n, label = connected_components(graph, directed=False)
    return [verts[np.unique(faces[label == c])] for c in range(n)]


def load_hulls(path: str | os.PathLike) -> list[np.ndarray]:
    """Read a decomposition file: a list of (m, 3) float vertex arrays, one per hull.

    OBJ with ``o`` objects (CoACD, V-HACD): one hull per object, in file order. Any other mesh
    file (or an OBJ without objects): one hull per connected component.
    """
    import warnings

    import trimesh

    from .io.files import check_readable

    p = check_readable(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if p.suffix.lower() == ".obj":
                loaded = trimesh.load(
                    str(p), force="scene", process=False, split_objects=True, group_material=False
                )
            else:
                loaded = trimesh.load(str(p), force="scene", process=False)
    except (ValueError, IndexError, KeyError, TypeError, OSError, EOFError, AttributeError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"{p}: cannot read the hulls ({msg})") from None
    geoms = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh) and len(g.faces)]
    if not geoms:
        raise InputError(f"{p}: the hulls file holds no triangles")
    if len(geoms) > 1:
        order = _obj_object_order(str(p)) if p.suffix.lower() == ".obj" else []
        rank = {name: i for i, name in enumerate(order)}
        geoms.sort(key=lambda g: rank.get(g.metadata.get("name", ""), len(rank)))
        return [np.asarray(g.vertices, dtype=np.float64)[np.unique(g.faces)] for g in geoms]
    return _components(geoms[0])


def evaluate_files(mesh_path: str | os.PathLike, hulls_path: str | os.PathLike, **options) -> dict:
    """:func:`evaluate` on a mesh file and a hulls file (see :func:`load_hulls`); ``options`` are
    :func:`evaluate`'s keywords. The result also names both files."""
    from .io.mesh import read_mesh
    from .io.sniff import detect

    found = detect(mesh_path)
    if found.modality not in ("mesh",):
        raise InputError(f"{mesh_path}: evaluation needs a mesh, this is a {found.modality} file")
    mesh = read_mesh(mesh_path, found.format)
    result = evaluate(mesh, load_hulls(hulls_path), **options)
    result["mesh"] = str(mesh_path)
    result["hulls_file"] = str(hulls_path)
    return result
