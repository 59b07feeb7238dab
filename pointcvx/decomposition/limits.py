"""Per-hull limits of physics engines, and conservative hull simplification.

Engines cap the size of one convex collider. A hull over the cap is replaced by a coarser convex
polytope that still CONTAINS it, so every point of its part keeps collision coverage and the only
cost is some added volume:

1. the candidate planes are the hull's own facet planes plus the 26 directions of a k-DOP, each
   pushed out to touch the hull (``d = max_v n . v``), so every one of them keeps the hull inside;
2. starting from a bounding box (a bounding tetrahedron for budgets under 8 vertices), planes are
   added greedily: the 32 candidates that cut deepest into the current polytope are scored
   exactly (vertices after the cut: those kept plus one per edge crossed; volume cut off), and
   the one removing the most volume per vertex it adds is taken (with others whose cuts are far
   from it, in one step), as long as the polytope stays within the vertex budget;
3. the polytope's vertices (half-space intersection) are triangulated, less any vertex within
   1e-6 (relative) of a hull edge (sliver triangles, whose planes rounding can tilt); if rounding
   or that leaves any original vertex outside a triangle's plane, the polytope is scaled about the
   hull's centre just enough to take it back in.

Counting faces: hulls are written as triangle meshes, so ``max_faces`` counts TRIANGLES, which is
the conservative reading of PhysX's "polygons" (a cooked PhysX hull merges coplanar triangles
into polygons, so it never has more polygons than our triangles). A closed convex triangle mesh
with ``v`` vertices has ``2 v - 4`` triangles, so a triangle cap ``t`` is a vertex budget of
``(t + 4) // 2``. Flat hulls (zero volume, both sides written) have ``2 (v - 2)`` triangles.
Pure numpy/scipy; deterministic (no randomness, ties broken by index).
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .hull import convex_hull, plane_basis

log = logging.getLogger(__name__)

# Per convex collider. PhysX (CPU cooking): 255 vertices, 255 polygons; PhysX GPU (Isaac Sim/Lab):
# 64 vertices, 64 polygons; Newton: 64 vertices; Unity MeshCollider(convex): 255 triangles.
# MuJoCo and Bullet take hulls of any size.
#: Keyed by :data:`pointcvx.options.ENGINE_TARGETS` (the names the option accepts).
TARGETS: dict[str, dict[str, int | None]] = {
    "mujoco": {"max_vertices": None, "max_faces": None},
    "bullet": {"max_vertices": None, "max_faces": None},
    "physx": {"max_vertices": 255, "max_faces": 255},
    "physx-gpu": {"max_vertices": 64, "max_faces": 64},
    "newton": {"max_vertices": 64, "max_faces": None},
    "unity": {"max_vertices": None, "max_faces": 255},
}

_BATCH = 8  # most planes added in one greedy step (with caps apart)
_CANDIDATES = 32  # deepest candidate planes scored exactly per greedy step
_DEDUP = 1e-10  # vertices closer than this (relative to the hull's size) are one vertex
_SLIVER = 1e-6  # a vertex closer than this to a hull edge (relative) is dropped


@dataclass(frozen=True)
class HullLimits:
    """Caps on one convex hull.

    Attributes
    ----------
    max_vertices : int or None
    max_faces : int or None
        Triangles of the written mesh (the conservative reading of "polygons").
    target : str or None
        The engine preset these came from, if any.
    """

    max_vertices: int | None = None
    max_faces: int | None = None
    target: str | None = None

    @property
    def active(self) -> bool:
        return self.max_vertices is not None or self.max_faces is not None

    def vertex_budget(self, dim: int = 3) -> int | None:
        """Most vertices a closed hull of dimension ``dim`` (3 solid, 2 flat) may have."""
        caps = [] if self.max_vertices is None else [self.max_vertices]
        if self.max_faces is not None:
            caps.append((self.max_faces + 4) // 2 if dim == 3 else self.max_faces // 2 + 2)
        return min(caps) if caps else None

    def allows(self, vertices: np.ndarray, faces: np.ndarray) -> bool:
        """Whether a hull of (v, 3) ``vertices`` and (f, 3) ``faces`` is within the caps."""
        return ((self.max_vertices is None or len(vertices) <= self.max_vertices)
                and (self.max_faces is None or len(faces) <= self.max_faces))

    def as_dict(self) -> dict:
        return {"target": self.target, "max_vertices": self.max_vertices,
                "max_faces": self.max_faces, "faces_counted_as": "triangles"}


def hull_limits(target: str | None = None, max_vertices: int | None = None,
                max_faces: int | None = None) -> HullLimits:
    """The caps of engine ``target`` (see :data:`TARGETS`), tightened by explicit caps."""
    preset = {"max_vertices": None, "max_faces": None}
    if target is not None:
        key = str(target).lower()
        if key not in TARGETS:
            raise InputError(f"unknown engine target {target!r}; expected one of {', '.join(TARGETS)}")
        preset, target = TARGETS[key], key
    caps = {}
    for name, value, least in (("max_vertices", max_vertices, 4), ("max_faces", max_faces, 4)):
        if value is not None and (int(value) != value or value < least):
            raise InputError(f"{name} must be an integer of at least {least}, got {value}")
        given = [v for v in (preset[name], None if value is None else int(value)) if v is not None]
        caps[name] = min(given) if given else None
    return HullLimits(caps["max_vertices"], caps["max_faces"], target)


def simplify_hull(vertices: np.ndarray, faces: np.ndarray,
                  limits: HullLimits) -> tuple[np.ndarray, np.ndarray, float]:
    """A hull within ``limits`` that contains the given one.

    Parameters
    ----------
    vertices : (v, 3) float
    faces : (f, 3) int, wound outward.
    limits : HullLimits

    Returns
    -------
    vertices : (v', 3) float64
    faces : (f', 3) int64, wound outward (flat hulls: both sides).
    added_volume : float
        Volume of the result minus the hull's (0.0 when the hull was already within the caps).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if not limits.active or limits.allows(vertices, faces):
        return vertices, faces, 0.0
    hull = convex_hull(vertices)
    if hull.dim < 2:  # a segment or a point: two vertices, no faces
        return hull.vertices, hull.faces, 0.0
    budget = limits.vertex_budget(hull.dim)
    if hull.dim == 2:  # zero volume before and after
        out_v, out_f = _reduce_flat(hull.vertices, hull.equations[0, :3], budget)
        added = 0.0
    else:
        out_v, out_f = _reduce_solid(hull.vertices, budget)
        added = mesh_volume(out_v, out_f) - mesh_volume(vertices, faces)
    log.debug("hull of %d vertices -> %d (budget %d), added volume %.3g", len(vertices),
              len(out_v), budget, added)
    return out_v, out_f, float(added)


def mesh_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume of a closed mesh: (v, 3) float ``vertices``, (f, 3) int ``faces``."""
    if len(faces) == 0:
        return 0.0
    tri = np.asarray(vertices, dtype=np.float64)[faces]
    return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)


def outside_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n,) float: how far each of (n, 3) ``points`` lies outside the planes of the (f, 3)
    triangles of a closed convex mesh (<= 0 inside; the exact distance to the boundary, negated,
    inside)."""
    tri = np.asarray(vertices, dtype=np.float64)[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normal, axis=1)
    keep = length > 0
    normal = normal[keep] / length[keep, None]
    offset = np.einsum("ij,ij->i", normal, tri[keep, 0])
    return (np.asarray(points, dtype=np.float64) @ normal.T - offset).max(axis=1)


# ---------------------------------------------------------------------------------- solid hulls
def _dop_directions(dim: int) -> np.ndarray:
    """(k, dim) float: unit directions of a k-DOP (26 in 3D, 8 in 2D)."""
    dirs = np.array([d for d in itertools.product((-1.0, 0.0, 1.0), repeat=dim) if any(d)])
    return dirs / np.linalg.norm(dirs, axis=1, keepdims=True)


def _start_directions(dim: int, budget: int) -> np.ndarray:
    """(k, dim) float: directions of the first bounding polytope (a box, or a simplex when the
    budget is too small for a box)."""
    if budget >= 2 ** dim:
        return np.concatenate([np.eye(dim), -np.eye(dim)])
    if dim == 3:
        d = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=np.float64)
    else:
        a = np.deg2rad([90.0, 210.0, 330.0])
        d = np.stack([np.cos(a), np.sin(a)], axis=1)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _unique_directions(normals: np.ndarray) -> np.ndarray:
    """(k, dim) float: unit ``normals`` with (near-)duplicates dropped, first kept."""
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    _, first = np.unique(np.round(normals, 9), axis=0, return_index=True)
    return normals[np.sort(first)]


@dataclass
class _Polytope:
    """A bounded convex polytope in 2 or 3 dimensions, both ways round.

    Attributes
    ----------
    planes : (p, dim + 1) float
        Rows ``[n, d]``: the polytope is ``{x : n . x <= d}``.
    vertices : (v, dim) float
    edges : (e, 2) int
        Pairs of ``vertices`` joined by an edge (they share dim - 1 planes).
    simplices : (f, dim) int
        The boundary split into triangles (segments in 2D), wound outward.
    volume : float
        Volume (area in 2D).
    """

    planes: np.ndarray
    vertices: np.ndarray
    edges: np.ndarray
    simplices: np.ndarray
    volume: float


def _polytope(planes: np.ndarray) -> _Polytope:
    """The polytope of (p, dim + 1) rows ``[n, d]``, which must hold the origin strictly inside."""
    from scipy.spatial import ConvexHull, HalfspaceIntersection

    dim = planes.shape[1] - 1
    halfspaces = np.concatenate([planes[:, :dim], -planes[:, dim:]], axis=1)
    hs = HalfspaceIntersection(halfspaces, np.zeros(dim))
    pts = hs.intersections
    _, first, inverse = np.unique(np.round(pts / _DEDUP), axis=0, return_index=True,
                                  return_inverse=True)
    order = np.argsort(first, kind="stable")  # vertices in the order qhull found them
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    vertices = pts[first[order]]
    incidence = np.zeros((len(vertices), len(planes)), dtype=np.int32)
    owner = rank[inverse.ravel()]
    facets = hs.dual_facets
    if all(len(f) == dim for f in facets):  # simplicial (qhull's default): one array operation
        incidence[owner[:, None], np.asarray(facets, dtype=np.int64)] = 1
    else:
        for i, facet in enumerate(facets):
            incidence[owner[i], facet] = 1
    shared = incidence @ incidence.T
    a, b = np.nonzero(np.triu(shared >= dim - 1, k=1))
    qh = ConvexHull(vertices)
    simplices = np.asarray(qh.simplices, dtype=np.int64)
    if dim == 3:
        tri = vertices[simplices]
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    else:
        seg = vertices[simplices[:, 1]] - vertices[simplices[:, 0]]
        normal = np.stack([seg[:, 1], -seg[:, 0]], axis=1)
    wrong = np.einsum("ij,ij->i", normal, qh.equations[:, :dim]) < 0
    simplices[wrong] = simplices[wrong][:, ::-1]
    return _Polytope(planes, vertices, np.stack([a, b], axis=1), simplices, float(qh.volume))


def _cap_volumes(poly: _Polytope, planes: np.ndarray) -> np.ndarray:
    """(k,) float: the volume (area in 2D) of ``poly`` beyond each of (k, dim + 1) ``planes``.

    The boundary pieces beyond a plane, with the cut face (which lies on the plane and so adds
    nothing), close the cap; their signed volumes about a point of the plane add up to its volume.
    """
    dim = planes.shape[1] - 1
    cell = poly.vertices[poly.simplices]  # (f, dim, dim)
    n, d = planes[:, :dim], planes[:, dim]
    origin = n * d[:, None]  # (k, dim): a point on each plane
    s = np.einsum("fcj,kj->kfc", cell, n) - d[:, None, None]  # (k, f, dim) signed distances
    x = cell[None] - origin[:, None, None, :]  # (k, f, dim, dim), about the plane's point
    up = s > 0
    count = up.sum(axis=2)

    def vol(*corners):  # signed volume (area) of the simplex of the corners and the origin
        if dim == 2:
            p, q = corners
            return (p[..., 0] * q[..., 1] - p[..., 1] * q[..., 0]) / 2.0
        p, q, r = corners
        return np.einsum("...j,...j->...", p, np.cross(q, r)) / 6.0

    def cut(p, q, sp, sq):  # where the segment p -> q crosses the plane
        t = (sp / np.where(sp != sq, sp - sq, 1.0))[..., None]
        return p + t * (q - p)

    full = np.where(count == dim, vol(*[x[..., i, :] for i in range(dim)]), 0.0)
    if dim == 2:
        lone = np.argmax(up, axis=2)  # the one end beyond the plane
        a = np.take_along_axis(x, lone[..., None, None], axis=2)[..., 0, :]
        b = np.take_along_axis(x, (1 - lone)[..., None, None], axis=2)[..., 0, :]
        sa = np.take_along_axis(s, lone[..., None], axis=2)[..., 0]
        sb = np.take_along_axis(s, (1 - lone)[..., None], axis=2)[..., 0]
        piece = np.where(lone[..., None, None] == 0, np.stack([a, cut(a, b, sa, sb)], -2),
                         np.stack([cut(b, a, sb, sa), a], -2))
        part = np.where(count == 1, vol(piece[..., 0, :], piece[..., 1, :]), 0.0)
        return (full + part).sum(axis=1)
    pick = np.where(count == 1, np.argmax(up, axis=2), np.argmin(up, axis=2))  # the lone corner
    idx = [(pick + k) % 3 for k in range(3)]  # cyclic, keeps the winding
    a, b, c = (np.take_along_axis(x, i[..., None, None], axis=2)[..., 0, :] for i in idx)
    sa, sb, sc = (np.take_along_axis(s, i[..., None], axis=2)[..., 0] for i in idx)
    one = vol(a, cut(a, b, sa, sb), cut(a, c, sa, sc))  # only a beyond
    qab, qca = cut(a, b, sa, sb), cut(c, a, sc, sa)
    two = vol(b, c, qca) + vol(b, qca, qab)  # b and c beyond, a not
    part = np.where(count == 1, one, 0.0) + np.where(count == 2, two, 0.0)
    return (full + part).sum(axis=1)


def _vertex_counts(poly: _Polytope, planes: np.ndarray, tol: float = 1e-12) -> np.ndarray:
    """(k,) int: vertices of ``poly`` cut by each of (k, dim + 1) ``planes``: those kept plus one
    per edge crossing the plane."""
    dim = planes.shape[1] - 1
    s = poly.vertices @ planes[:, :dim].T - planes[:, dim]  # (v, k)
    kept = (s <= tol).sum(axis=0)
    su, sv = s[poly.edges[:, 0]], s[poly.edges[:, 1]]
    crossing = ((su > tol) & (sv < -tol)) | ((sv > tol) & (su < -tol))
    return kept + crossing.sum(axis=0)


def _greedy_planes(points: np.ndarray, normals: np.ndarray, budget: int) -> np.ndarray:
    """(k, dim) float vertices of a polytope with at most ``budget`` vertices containing the
    (n, dim) ``points`` (centred on the origin, unit size), bounded by planes whose normals come
    from the (c, dim) candidate ``normals``."""
    dim = points.shape[1]
    start = _start_directions(dim, budget)
    cand = _unique_directions(np.concatenate([normals, _dop_directions(dim)]))
    cand_planes = np.concatenate([cand, (points @ cand.T).max(axis=0)[:, None]], axis=1)
    poly = _polytope(np.concatenate([start, (points @ start.T).max(axis=0)[:, None]], axis=1))
    rejected = np.zeros(len(cand), dtype=bool)
    while True:
        depth = (poly.vertices @ cand_planes[:, :dim].T).max(axis=0) - cand_planes[:, dim]
        depth[rejected | (depth <= 1e-9)] = -np.inf
        order = np.argsort(-depth, kind="stable")[:_CANDIDATES]
        order = order[np.isfinite(depth[order])]
        if len(order) == 0:
            return poly.vertices
        counts = _vertex_counts(poly, cand_planes[order])
        gain = _cap_volumes(poly, cand_planes[order]) / np.maximum(1, counts - len(poly.vertices))
        gain[counts > budget] = -np.inf
        if not np.isfinite(gain).any():
            return poly.vertices
        picked = _batch(poly, cand_planes[order], counts, gain, budget)
        trial = _polytope(np.concatenate([poly.planes, cand_planes[order[picked]]]))
        if len(trial.vertices) > budget and len(picked) > 1:  # caps interacted: take the best alone
            picked = picked[:1]
            trial = _polytope(np.concatenate([poly.planes, cand_planes[order[picked]]]))
        rejected[order[picked]] = True  # used, or (if the count was off) not usable
        if len(trial.vertices) <= budget:
            poly = trial


def _batch(poly: _Polytope, planes: np.ndarray, counts: np.ndarray, gain: np.ndarray,
           budget: int) -> np.ndarray:
    """(b,) int: rows of (k, dim + 1) ``planes`` to add at once: the best by ``gain``, then others
    whose caps are far from the ones taken (no vertex beyond them on or next to a taken cap, so
    counts and volumes add up), as long as the ``budget`` allows and their gain is at least a
    quarter of the best's."""
    dim = planes.shape[1] - 1
    beyond = (poly.vertices @ planes[:, :dim].T - planes[:, dim]) > 1e-12  # (v, k)
    nv = len(poly.vertices)
    ring = np.zeros((nv, nv), dtype=bool)
    ring[poly.edges[:, 0], poly.edges[:, 1]] = ring[poly.edges[:, 1], poly.edges[:, 0]] = True
    ring |= np.eye(nv, dtype=bool)
    ranked = np.argsort(-gain, kind="stable")
    picked = [int(ranked[0])]
    total = int(counts[ranked[0]])
    blocked = ring[beyond[:, ranked[0]]].any(axis=0)
    for c in ranked[1:_BATCH * 4]:
        if len(picked) >= _BATCH or not gain[c] >= 0.25 * gain[ranked[0]]:
            break
        extra = int(counts[c]) - nv
        if beyond[:, c].any() and not (blocked & beyond[:, c]).any() and total + extra <= budget:
            picked.append(int(c))
            total += extra
            blocked |= ring[beyond[:, c]].any(axis=0)
    return np.array(picked, dtype=np.int64)


def _contain(out: np.ndarray, faces: np.ndarray, points: np.ndarray, center: np.ndarray) -> np.ndarray:
    """(k, 3) ``out`` scaled about ``center`` just enough that every one of the (n, 3) ``points``
    is inside the planes of its (f, 3) ``faces`` (a guard against rounding)."""
    for _ in range(8):
        excess = float(outside_distance(points, out, faces).max())
        if excess <= 0.0:
            return out
        reach = float(-outside_distance(center[None], out, faces)[0])  # inscribed distance
        factor = 1.0 + 2.0 * excess / max(reach, 1e-300) + 1e-15
        out = center + (out - center) * factor
    return out


def _reduce_solid(vertices: np.ndarray, budget: int) -> tuple[np.ndarray, np.ndarray]:
    """A solid hull of at most ``budget`` vertices containing (v, 3) ``vertices``."""
    center = vertices.mean(axis=0)
    scale = float(np.abs(vertices - center).max())
    local = (vertices - center) / scale
    hull = convex_hull(local)
    tri = _without_slivers(_greedy_planes(local, hull.equations[:, :3], budget))
    return _contain(tri.vertices * scale + center, tri.faces, vertices, center), tri.faces


def _without_slivers(vertices: np.ndarray, tol: float = _SLIVER):
    """The hull (:class:`~pointcvx.decomposition.hull.Polytope`) of (v, 3) ``vertices`` (unit size) less the
    vertices within ``tol`` of a hull edge (the apex of a sliver triangle, or one of two near
    duplicates): they add nothing but triangles whose planes rounding can tilt. What this loses
    (at most ``tol``) the final containment step gives back."""
    for _ in range(16):
        hull = convex_hull(vertices)
        tri = hull.vertices[hull.faces]
        edge = np.linalg.norm(tri - np.roll(tri, -1, axis=1), axis=2)  # edge k: corner k -> k + 1
        longest = np.argmax(edge, axis=1)
        double_area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        height = double_area / edge[np.arange(len(tri)), longest]
        thin = height < tol
        if not thin.any():
            return hull
        apex = hull.faces[np.flatnonzero(thin), (longest[thin] + 2) % 3]
        keep = np.ones(len(hull.vertices), dtype=bool)
        keep[apex] = False
        vertices = hull.vertices[keep]
    return hull


def _reduce_flat(vertices: np.ndarray, normal: np.ndarray, budget: int) -> tuple[np.ndarray, np.ndarray]:
    """A flat polygon of at most ``budget`` corners containing the (v, 3) ``vertices`` lying on the
    plane with unit ``normal``; faces on both sides."""
    center = vertices.mean(axis=0)
    u, v = plane_basis(normal / np.linalg.norm(normal))
    uv = np.stack([(vertices - center) @ u, (vertices - center) @ v], axis=1)
    scale = float(np.abs(uv).max())
    local = uv / scale
    edges = np.roll(local, -1, axis=0) - local  # ``vertices`` of a flat Hull run counter-clockwise
    ring = _greedy_planes(local, np.stack([edges[:, 1], -edges[:, 0]], axis=1), budget)
    ring = ring[np.argsort(np.arctan2(ring[:, 1], ring[:, 0]), kind="stable")]
    while len(ring) > 3:  # drop corners within _SLIVER of the chord of their neighbours
        prev, after = np.roll(ring, 1, axis=0), np.roll(ring, -1, axis=0)
        chord = after - prev
        cross = chord[:, 0] * (ring - prev)[:, 1] - chord[:, 1] * (ring - prev)[:, 0]
        offset = np.abs(cross) / np.maximum(np.linalg.norm(chord, axis=1), 1e-300)
        worst = int(np.argmin(offset))
        if offset[worst] >= _SLIVER:
            break
        ring = np.delete(ring, worst, axis=0)
    ring = ring * scale
    # grow by the largest in-plane excess, a guard against rounding
    e = np.roll(ring, -1, axis=0) - ring
    out_n = np.stack([e[:, 1], -e[:, 0]], axis=1)
    out_n /= np.linalg.norm(out_n, axis=1, keepdims=True)
    excess = float((uv @ out_n.T - np.einsum("ij,ij->i", out_n, ring)).max())
    if excess > 0:
        reach = float(np.einsum("ij,ij->i", out_n, ring).min())
        ring = ring * (1.0 + 2.0 * excess / reach + 1e-15)
    m = len(ring)
    fan = np.stack([np.zeros(m - 2, np.int64), np.arange(1, m - 1), np.arange(2, m)], axis=1)
    poly = center + ring[:, :1] * u + ring[:, 1:] * v
    return poly, np.concatenate([fan, fan[:, ::-1]])
