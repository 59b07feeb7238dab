"""The paper's evaluation protocol (CoACD's metric) of a decomposition against its shape.

:func:`evaluate`: concavity of every ``M ∩ hull_i`` with exact booleans (manifold3d), Chamfer
reconstruction error, volume IoU and surface coverage of the union of hulls, in the [-1, 1]^3
frame of the shape. :func:`evaluate_points` scores hulls against a point cloud (splats and scans,
which have no closed surface); :func:`evaluate_files` reads both from disk
(``pointcvx evaluate``).
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import time

import numpy as np

from .cloud import check_points
from .decomposition.concavity import K_CONCAVITY, chamfer_distance, concavity_terms, nearest_distance, rv_term
from .decomposition.hull import (
    Polytope,
    convex_hull,
    hull_contains,
    lipschitz_max,
    max_inside_depth,
    sample_hull_interior,
    sample_hull_surface,
    sample_triangles,
    signed_plane_distance,
    triangle_distance_fn,
)
from .errors import InputError, first_line

log = logging.getLogger(__name__)

_FLOAT32_TOL = 1e-6  # plane tests in float32: "strictly inside" means deeper than this (relative)


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
    v = check_points(vertices, "vertices", allow_empty=True)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        raise InputError("the mesh has no faces")
    rng = np.random.default_rng(seed)
    tri = v[f]
    if volume is None:
        volume = float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)
    hull = convex_hull(v[np.unique(f)])
    sp = sample_triangles(tri, int(n_samples), rng)[0]
    sh = sample_hull_surface(hull, int(n_samples), rng)
    hb_part = max_inside_depth(hull, sp)
    hb_hull = lipschitz_max(sh, triangle_distance_fn(v, f))
    terms = concavity_terms(hb_part, hb_hull, hull.volume, volume, k)
    return terms if return_terms else terms["concavity"]


def _hull_of(item) -> np.ndarray:
    """(m, 3) float: the points whose hull a hull-like ``item`` is (Polytope, mesh or points)."""
    if isinstance(item, Polytope):
        return item.vertices
    if hasattr(item, "vertices"):
        return check_points(np.asarray(item.vertices), "hull vertices", allow_empty=True)
    return check_points(item, "hull points", allow_empty=True)


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
    else :func:`pointcvx.solid.watertight_mesh`."""
    import trimesh

    from .io.mesh import clean_mesh
    from .solid import closed_mesh_solid, watertight_mesh

    cleaned = clean_mesh(mesh)
    solid = closed_mesh_solid(cleaned)
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
    closed = watertight_mesh(cleaned, resolution=resolution)
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


def _pieces_manifold(mv, mf, hulls: list[Polytope]):
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


def _piece_concavity_mc(solid, mv, mf, hull: Polytope, n: int, seed: int, k: float) -> float | None:
    """Monte-Carlo concavity of ``M ∩ hull`` when exact booleans are unavailable: the piece's
    surface = samples of M's surface inside the hull + samples of the hull's surface inside M;
    its volume = V(hull) x the fraction of uniform hull samples inside M."""
    if hull.dim < 3 or not hull.volume > 0:
        return None
    rng = np.random.default_rng(seed)
    lo, hi = hull.bounds
    tri = mv[mf]
    near = np.all((tri.max(axis=1) >= lo) & (tri.min(axis=1) <= hi), axis=1)
    sm = sample_triangles(tri[near], n, rng)[0]
    sm = sm[hull_contains(hull, sm)] if len(sm) else sm
    sh = sample_hull_surface(hull, n, rng)
    vs = sample_hull_interior(hull, n, rng)
    inside = solid.contains(np.concatenate([sh, vs]))
    surface = np.concatenate([sm, sh[inside[:n]]])
    frac = float(inside[n:].mean())
    if len(surface) < 4 or frac <= 0:
        return None
    conv = convex_hull(surface)
    hb_part = max_inside_depth(conv, surface, conv.index)
    cs = sample_hull_surface(conv, n, rng)
    hb_hull = float(nearest_distance(cs, surface).max())
    return max(hb_part, hb_hull, k * rv_term(conv.volume - hull.volume * frac))


def union_surface_samples(hulls: list[Polytope], n: int, rng: np.random.Generator) -> np.ndarray:
    """(about n, 3) float: uniform samples of the boundary of the union of hulls.

    Each hull's surface is sampled by area; a sample is dropped when it lies strictly inside
    another hull, when it lies on an interface (just outside it along its face normal is inside
    another hull: abutting hulls), or when it lies on the boundary of a hull of lower index
    facing the same way (coplanar faces shared by several hulls are sampled once).
    """
    areas = np.array([h.area for h in hulls])
    if not areas.sum() > 0:
        return np.concatenate([sample_hull_surface(h, 1, rng) for h in hulls])
    scale = max(1.0, max(float(np.abs(h.vertices).max()) for h in hulls))
    on_tol, step = 10 * _FLOAT32_TOL * scale, 100 * _FLOAT32_TOL * scale

    def draw(m: int) -> np.ndarray:
        counts = rng.multinomial(m, areas / areas.sum())
        parts, owners, normals = [], [], []
        for i, (h, c) in enumerate(zip(hulls, counts, strict=True)):
            c = int(c)
            if h.dim >= 2 and h.area > 0:
                tri = h.triangles
                pts, face = sample_triangles(tri, c, rng)
                nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
                nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
                normals.append(nrm[face])
            else:
                pts = sample_hull_surface(h, c, rng)
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
            sd = signed_plane_distance(h, pts[cand], np.float32)
            out = signed_plane_distance(h, pts[cand] + step * nrm[cand], np.float32)
            gone = (sd < -on_tol) | (out <= 0.0) | ((np.abs(sd) <= on_tol) & (owner[cand] > j))
            drop[cand[gone]] = True
        return pts[~drop]

    first = draw(n)
    kept = len(first) / n
    if kept >= 0.999 or len(first) == 0:
        return first
    more = draw(int(np.ceil(n / max(kept, 0.05) * 1.1)))
    return more[rng.permutation(len(more))[:n]] if len(more) > n else more


def _inside_any(hulls: list[Polytope], points: np.ndarray, tol: float) -> np.ndarray:
    inside = np.zeros(len(points), dtype=bool)
    for h in hulls:
        lo, hi = h.bounds
        cand = np.flatnonzero(~inside & np.all((points >= lo - tol) & (points <= hi + tol), axis=1))
        if len(cand):
            sd = signed_plane_distance(h, points[cand], np.float32)
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
    hulls : sequence of Polytope, trimesh.Trimesh or (m, 3) float
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
        Resolution for :func:`pointcvx.solid.watertight_mesh` when the mesh is not closed.

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
    su = union_surface_samples(hl, int(n_samples), rng)
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
    hulls : sequence of Polytope, trimesh.Trimesh or (m, 3) float
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

    pts = check_points(points, allow_empty=True)
    raw = _hull_points(hulls)
    norm = Normalization.to_unit_cube(pts)
    pts = norm.forward(pts)
    hl = [convex_hull(norm.forward(r)) for r in raw]
    rng = np.random.default_rng(seed)
    if len(pts) > n_samples:
        pts = pts[rng.choice(len(pts), int(n_samples), replace=False)]
    su = union_surface_samples(hl, int(n_samples), rng)
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
        msg = first_line(exc)
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
