"""Convex hulls as arrays: the :class:`Polytope` kit of the decomposition and the evaluation.

A :class:`Polytope` is a convex polytope as arrays: outward triangles and outward plane equations
``n . x + d <= 0`` inside. Degenerate input (fewer than 4 points, coplanar or collinear points)
gives a flat polytope of volume 0 rather than an error, so no stage can crash on a thin part.
The public hull type of a result is :class:`pointcvx.result.ConvexHull`; this one is geometry.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..cloud import check_points
from ..errors import InputError, first_line

log = logging.getLogger(__name__)

_CHUNK = 1 << 21  # entries of a (points x planes) block evaluated at once
_FLOAT32_TOL = 1e-6  # plane tests in float32: "strictly inside" means deeper than this (relative)

@dataclass(eq=False)
class Polytope:
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
            f"Polytope(dim={self.dim}, vertices={len(self.vertices)}, faces={len(self.faces)}, "
            f"volume={self.volume:.6g}, area={self.area:.6g})"
        )


def triangle_areas(tri: np.ndarray) -> np.ndarray:
    """(f,) float: areas of (f, 3, 3) triangles."""
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def plane_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def _solid_hull(points: np.ndarray, options: str | None) -> Polytope:
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
    return Polytope(vertices, faces, eq, float(qh.volume), float(qh.area), 3, used)


def _flat_hull(points: np.ndarray, center: np.ndarray, normal: np.ndarray) -> Polytope:
    """The hull of points lying (about) on the plane through ``center`` with unit ``normal``."""
    from scipy.spatial import ConvexHull, QhullError

    u, v = plane_basis(normal)
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
    area = float(triangle_areas(poly[fan]).sum())
    return Polytope(poly, faces, eq, 0.0, 2.0 * area, 2, ring)


def _line_hull(points: np.ndarray) -> Polytope:
    """The hull of collinear (or identical) points: a segment (or a point)."""
    center = points.mean(axis=0)
    centered = points - center
    _, _, vt = np.linalg.svd(centered, full_matrices=False)
    axis = vt[0]
    t = centered @ axis
    ends = np.array([int(np.argmin(t)), int(np.argmax(t))])
    lo, hi = points[ends[0]], points[ends[1]]
    length = float(t.max() - t.min())
    u, v = plane_basis(axis)
    if length <= 0.0:
        vertices, ends = points[:1].copy(), ends[:1] * 0
        eq = _box_planes(vertices[0], np.eye(3), np.zeros(3))
        dim = 0
    else:
        vertices = np.stack([lo, hi])
        eq = _box_planes((lo + hi) / 2, np.stack([axis, u, v]), np.array([length / 2, 0.0, 0.0]))
        dim = 1
    return Polytope(vertices, np.zeros((0, 3), np.int64), eq, 0.0, 0.0, dim, ends)


#: Points whose SVD first tells a solid hull from a flat or collinear one (:func:`convex_hull`).
FLAT_PROBE = 1000


def convex_hull(points) -> Polytope:
    """The convex hull of (n, 3) ``points`` as a :class:`Polytope`; never fails on degenerate input.

    Qhull first; if it refuses (precision trouble on nearly flat input) qhull again with joggled
    input (``QJ``). Coplanar points (within 1e-9 of the extent) give a flat hull, collinear ones a
    segment, identical ones a point, all of volume 0. Raises :class:`InputError` only for empty or
    non-finite input.
    """
    from scipy.spatial import QhullError

    pts = check_points(points, allow_empty=True)
    if len(pts) == 0:
        raise InputError("no points to take the convex hull of")
    extent = float((pts.max(axis=0) - pts.min(axis=0)).max())
    if extent <= 0.0:
        return _line_hull(pts)
    center = pts.mean(axis=0)

    def spread(stride: int):
        """Singular values and axes of every ``stride``-th point (centred, unit extent), and
        the tolerance under which a singular value counts as flat."""
        sub = pts[::stride] - center
        _, sv, vt = np.linalg.svd(sub / extent, full_matrices=False)
        return sv, vt, 1e-9 * np.sqrt(len(sub))

    # A subsample that spans three dimensions proves the points do; only one that looks flat
    # (or a hull qhull refuses) needs the SVD of the points' usual sample (every point up to
    # 20,000): at 10,000 points that SVD cost as much as the rest of the check.
    probe, full = max(1, len(pts) // FLAT_PROBE), max(1, len(pts) // 20000)
    sv, vt, flat_tol = spread(probe)
    if (len(pts) < 4 or sv[2] <= flat_tol) and probe != full:
        probe = full
        sv, vt, flat_tol = spread(full)
    if len(pts) < 4 or sv[2] <= flat_tol:
        if sv[1] <= flat_tol:
            return _line_hull(pts)
        return _flat_hull(pts, center, vt[2])
    for options in (None, "QJ"):
        try:
            return _solid_hull(pts, options)
        except QhullError as exc:
            log.debug("qhull failed with options %s: %s", options, first_line(exc))
    return _flat_hull(pts, center, (vt if probe == full else spread(full)[1])[2])


def signed_plane_distance(hull: Polytope, points: np.ndarray, dtype=np.float64) -> np.ndarray:
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


def max_inside_depth(hull: Polytope, points: np.ndarray, skip: np.ndarray | None = None) -> float:
    """max over (n, 3) ``points`` inside ``hull`` of their distance to its boundary (0 if none).

    Same value as ``distance_to_hull_boundary(hull, points).max()`` for points inside, without
    the full (points x planes) product: over 8192 points by :func:`lipschitz_max`; otherwise an
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
        return float(max(0.0, -signed_plane_distance(hull, points).min()))
    if len(points) > 8192:  # the depth is 1-Lipschitz: bound most points by a few exact ones
        return lipschitz_max(points, lambda q: np.maximum(-signed_plane_distance(hull, q), 0.0), 16)
    centers = hull.triangles.mean(axis=1)
    kk = min(2, len(centers))
    tree = cKDTree(centers, leafsize=32, balanced_tree=False, compact_nodes=False)
    idx = tree.query(points, k=kk)[1].reshape(len(points), kk)
    cand = eq[idx]  # (n, kk, 4) (faces and equations are row-aligned for solid hulls)
    sd = np.einsum("nkj,nj->nk", cand[..., :3], points) + cand[..., 3]
    big = eq[np.argsort(-triangle_areas(hull.triangles))[:16]]
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


def hull_contains(hull: Polytope, points, tol: float = 1e-9, dtype=np.float64) -> np.ndarray:
    """(n,) bool: which (n, 3) ``points`` are inside ``hull`` or within ``tol`` outside its planes.

    A negative ``tol`` asks for points strictly inside, at least ``-tol`` from every facet plane.
    ``dtype=np.float32`` (half the time) for a ``tol`` far above float32's error of about 1e-6.
    """
    pts = check_points(points, allow_empty=True)
    return signed_plane_distance(hull, pts, dtype) <= tol


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = b - a
    den = float(d @ d)
    t = np.zeros(len(points)) if den <= 0 else np.clip((points - a) @ d / den, 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * d), axis=1)


def triangle_distance_fn(vertices: np.ndarray, faces: np.ndarray):
    """A function (n, 3) points -> (n,) unsigned distance to a triangle soup (Embree, float32)."""
    from ..syslibs import import_open3d
    o3d = import_open3d()

    from ..embree import raycasting_scene

    scene = raycasting_scene(vertices, faces)

    def distance(points: np.ndarray) -> np.ndarray:
        q = o3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float32))
        return scene.compute_distance(q).numpy().astype(np.float64)

    return distance


def triangle_distance(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n,) float: unsigned distance from (n, 3) ``points`` to a triangle soup (Embree, float32)."""
    return triangle_distance_fn(vertices, faces)(points)


def lipschitz_max(points: np.ndarray, fn, stride: int = 8) -> float:
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


def distance_to_hull_boundary(hull: Polytope, points) -> np.ndarray:
    """(n,) float: unsigned distance from (n, 3) ``points`` to the boundary of ``hull``.

    Points inside: ``min_j -(n_j . p + d_j)`` over the facet planes (exact for a convex solid).
    Points outside: the exact distance to the hull's triangles (Embree, float32 precision), or to
    the segment / point of a degenerate hull.
    """
    pts = check_points(points, allow_empty=True)
    sd = signed_plane_distance(hull, pts)
    dist = np.maximum(-sd, 0.0)
    if hull.dim < 3:
        dist[:] = 0.0
    scale = float(np.abs(hull.vertices).max()) if len(hull.vertices) else 1.0
    outside = sd > 1e-12 * max(scale, 1.0)
    if outside.any():
        q = pts[outside]
        if hull.dim >= 2:
            dist[outside] = triangle_distance(hull.vertices, hull.faces, q)
        else:
            dist[outside] = _segment_distance(q, hull.vertices[0], hull.vertices[-1])
    return dist


def sample_triangles(tri: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) float area-weighted uniform samples of (f, 3, 3) triangles and (n,) int their faces."""
    area = triangle_areas(tri)
    total = area.sum()
    if n <= 0 or len(tri) == 0 or not total > 0:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    face = rng.choice(len(tri), size=n, p=area / total)
    r1, r2 = rng.random((2, n))
    s1 = np.sqrt(r1)
    w = np.stack([1.0 - s1, s1 * (1.0 - r2), s1 * r2], axis=1)
    return np.einsum("nk,nkj->nj", w, tri[face]), face


def sample_hull_surface(hull: Polytope, n: int, seed: np.random.Generator | int = 0) -> np.ndarray:
    """(n, 3) float: area-weighted uniform samples of the hull's boundary, from ``seed`` (a
    seed, or a generator to draw from).

    Degenerate hulls: uniform on the polygon (flat), on the segment, or the point repeated.
    """
    rng = np.random.default_rng(seed)  # a generator passes through unchanged
    n = int(n)
    if n <= 0:
        return np.zeros((0, 3))
    if hull.dim >= 2 and hull.area > 0:
        return sample_triangles(hull.triangles, n, rng)[0]
    a, b = hull.vertices[0], hull.vertices[-1]
    return a + rng.random(n)[:, None] * (b - a)


def sample_hull_interior(hull: Polytope, n: int, seed: np.random.Generator | int = 0) -> np.ndarray:
    """(n, 3) float: uniform samples of the hull's volume (fan of tetrahedra from the vertex
    mean, no rejection), from ``seed`` (a seed, or a generator to draw from). Hulls of volume 0 give surface
    samples."""
    rng = np.random.default_rng(seed)  # a generator passes through unchanged
    n = int(n)
    if n <= 0:
        return np.zeros((0, 3))
    if hull.dim < 3 or not hull.volume > 0:
        return sample_hull_surface(hull, n, rng)
    apex = hull.vertices.mean(axis=0)  # interior: the hull is convex
    tri = hull.triangles - apex
    vol = np.abs(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])))
    tet = rng.choice(len(tri), size=n, p=vol / vol.sum())
    w = -np.log(1.0 - rng.random((n, 4)))  # Dirichlet(1, 1, 1, 1): uniform in a tetrahedron
    w /= w.sum(axis=1, keepdims=True)
    return apex + np.einsum("nk,nkj->nj", w[:, 1:], tri[tet])
