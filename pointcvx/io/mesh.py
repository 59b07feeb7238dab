"""Meshes (OBJ, PLY, STL, OFF, GLB/GLTF) -> oriented clouds of area-weighted surface samples.

Real meshes are often open, multi-component or badly wound, so outward orientation is decided
per face by ray parity, which does not depend on the winding: a point just outside a closed
surface sees an even number of crossings along a ray, a point just inside an odd number. Faces of
one connected component follow the component's area-weighted vote; a face whose own evidence
strongly contradicts it is flipped alone. Watertight, consistently wound meshes skip the rays:
a positive signed volume settles their orientation.
"""

from __future__ import annotations

import logging
import os
import warnings

import numpy as np

from ..cloud import OrientedCloud, check_points
from ..errors import InputError, first_line
from ..options import LoadOptions
from .files import check_readable

log = logging.getLogger(__name__)

_TRIMESH_TYPE = {"obj": "obj", "ply-mesh": "ply", "stl": "stl", "off": "off", "glb": "glb", "gltf": "gltf"}


def read_mesh(path: str | os.PathLike, fmt: str):
    """Read a mesh file with trimesh; scenes are flattened with their node transforms applied.

    Returns a ``trimesh.Trimesh`` in the file's units; raises :class:`InputError` when the file
    cannot be parsed or holds no triangles.
    """
    import trimesh

    p = check_readable(path)
    file_type = _TRIMESH_TYPE.get(fmt, fmt)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            loaded = trimesh.load(str(p), file_type=file_type, force="mesh", process=False)
    except (ValueError, IndexError, KeyError, TypeError, OSError, EOFError, AttributeError) as exc:
        msg = first_line(exc)
        raise InputError(f"{p}: cannot read {file_type.upper()} mesh ({msg})") from None
    if isinstance(loaded, list):
        loaded = trimesh.util.concatenate(loaded)
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise InputError(f"{p}: the {file_type.upper()} file holds no triangles")
    return loaded


def clean_mesh(mesh):
    """A copy of ``mesh`` with merged vertices and no degenerate or unused parts.

    Raises :class:`InputError` when vertices are NaN/inf or nothing with area remains.
    """
    import trimesh

    vertices = check_points(np.asarray(mesh.vertices, dtype=np.float64), "mesh vertices")
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError("mesh faces reference missing vertices")
    out = trimesh.Trimesh(vertices, faces, process=False)
    out.merge_vertices(merge_tex=True, merge_norm=True)
    keep = out.nondegenerate_faces(height=1e-12 * max(float(out.scale), 1e-300))
    keep &= out.area_faces > 0
    out.update_faces(keep)
    out.update_faces(out.unique_faces())
    out.remove_unreferenced_vertices()
    if len(out.faces) == 0 or out.area <= 0:
        raise InputError("the mesh has no triangle with area: all faces are degenerate")
    return out


def _random_directions(n: int, rng: np.random.Generator) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def inside_fraction(mesh, points: np.ndarray, n_rays: int = 8, seed: int = 0) -> np.ndarray:
    """(m,) float in [0, 1]: share of ``n_rays`` random rays from each of (m, 3) ``points`` that
    cross ``mesh`` an odd number of times (1 deep inside a closed surface, 0 outside).

    Independent of face winding; uses Embree through open3d's RaycastingScene.
    """
    from ..syslibs import import_open3d
    o3d = import_open3d()

    from ..embree import raycasting_scene

    scene = raycasting_scene(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    rng = np.random.default_rng(seed)
    m = len(points)
    origins = np.repeat(points.astype(np.float32), n_rays, axis=0)
    dirs = _random_directions(m * n_rays, rng).astype(np.float32)
    rays = o3d.core.Tensor(np.concatenate([origins, dirs], axis=1))
    hits = scene.count_intersections(rays).numpy().reshape(m, n_rays)
    return (hits % 2 == 1).mean(axis=1)


def face_outward_scores(mesh, n_rays: int = 8, seed: int = 0) -> np.ndarray:
    """(f,) float in [-1, 1]: positive where a face normal points out of the solid.

    Score = inside share just behind the face minus inside share just in front of it. Near 0 for
    faces of open sheets, where both sides are outside.
    """
    centers = np.asarray(mesh.triangles_center)
    normals = np.asarray(mesh.face_normals)
    # Offset a little, relative to the face's own size and the mesh's scale.
    delta = np.minimum(np.sqrt(mesh.area_faces) * 0.05, 1e-3 * float(mesh.scale))[:, None]
    delta = np.maximum(delta, 1e-7 * float(mesh.scale))
    both = np.concatenate([centers - delta * normals, centers + delta * normals])
    frac = inside_fraction(mesh, both, n_rays=n_rays, seed=seed)
    f = len(centers)
    return frac[:f] - frac[f:]


def winding_signs(mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Make the winding of neighbouring faces agree, without changing the mesh.

    Returns
    -------
    sign : (f,) float of +-1
        Multiply (i.e. reverse faces where -1) to make each connected piece consistently wound.
    labels : (f,) int
        Connected piece (through shared edges) of each face.
    conflicted : (f,) bool
        Faces in pieces that cannot be wound consistently (non-orientable or non-manifold).
    """
    from .orient import propagate_signs

    faces = np.asarray(mesh.faces)
    adj = np.asarray(mesh.face_adjacency)
    if len(adj) == 0:
        f = len(faces)
        return np.ones(f), np.arange(f), np.zeros(f, dtype=bool)
    edge = np.asarray(mesh.face_adjacency_edges)

    def forward(face_ids: np.ndarray) -> np.ndarray:
        tri = faces[face_ids]
        pa = np.argmax(tri == edge[:, :1], axis=1)
        pb = np.argmax(tri == edge[:, 1:], axis=1)
        return (pb - pa) % 3 == 1

    # Neighbours agree when they traverse their shared edge in opposite directions.
    relative = np.where(forward(adj[:, 0]) != forward(adj[:, 1]), 1.0, -1.0)
    sign, labels = propagate_signs(len(faces), adj, relative)
    broken = relative * sign[adj[:, 0]] * sign[adj[:, 1]] < 0
    conflicted = np.isin(labels, labels[adj[broken, 0]])
    return sign, labels, conflicted


def orient_outward(mesh, n_rays: int = 8, seed: int = 0) -> tuple[object, int, str]:
    """Return (mesh with outward face normals, number of faces flipped, method used).

    Each connected piece is wound consistently, then turned by its area-weighted ray-parity
    vote. In pieces that cannot be wound consistently, faces whose own rays say strongly that
    they point inward are flipped alone. The input mesh is not modified.
    """
    import trimesh

    if mesh.is_watertight and mesh.is_winding_consistent:
        out = mesh.copy()
        if out.volume < 0:
            out.invert()
            return out, len(out.faces), "signed volume (watertight)"
        return out, 0, "signed volume (watertight)"
    sign, labels, conflicted = winding_signs(mesh)
    faces = np.asarray(mesh.faces).copy()
    wound = trimesh.Trimesh(np.asarray(mesh.vertices), _flip(faces, sign < 0), process=False)
    scores = face_outward_scores(wound, n_rays=n_rays, seed=seed)
    vote = np.bincount(labels, weights=wound.area_faces * scores)
    turn = np.where(vote[labels] < 0, -1.0, 1.0)
    turn[conflicted & (scores * turn <= -0.75)] *= -1.0
    total = sign * turn
    out = trimesh.Trimesh(np.asarray(mesh.vertices), _flip(faces, total < 0), process=False)
    return out, int((total < 0).sum()), f"ray parity ({n_rays} rays per side)"


def _flip(faces: np.ndarray, which: np.ndarray) -> np.ndarray:
    out = faces.copy()
    out[which] = out[which][:, ::-1]
    return out


def sample_surface(mesh, n_points: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) float area-weighted random surface points and (n,) int their faces, seeded."""
    rng = np.random.default_rng(seed)
    area = np.asarray(mesh.area_faces, dtype=np.float64)
    face = rng.choice(len(area), size=n_points, p=area / area.sum())
    r1, r2 = rng.random((2, n_points))
    s1 = np.sqrt(r1)
    w = np.stack([1.0 - s1, s1 * (1.0 - r2), s1 * r2], axis=1)  # uniform barycentric
    tri = np.asarray(mesh.triangles)[face]
    points = np.einsum("nk,nkj->nj", w, tri)
    return points, face


def cloud_from_mesh(
    mesh,
    n_points: int = 20000,
    seed: int = 0,
    orient_rays: int = 8,
    modality: str = "mesh",
    info: dict | None = None,
) -> OrientedCloud:
    """Oriented cloud of ``n_points`` area-weighted samples of ``mesh`` (a trimesh.Trimesh or
    Scene), with outward normals; the cleaned, outward-wound mesh is kept on the cloud."""
    import trimesh

    if isinstance(mesh, trimesh.Scene):
        mesh = mesh.to_geometry() if hasattr(mesh, "to_geometry") else mesh.dump(concatenate=True)
    if not isinstance(mesh, trimesh.Trimesh):
        raise InputError(f"expected a triangle mesh, got {type(mesh).__name__}")
    n_faces_in = len(mesh.faces)
    cleaned = clean_mesh(mesh)
    oriented, n_flipped, method = orient_outward(cleaned, n_rays=orient_rays, seed=seed)
    points, face = sample_surface(oriented, n_points, seed=seed)
    normals = np.asarray(oriented.face_normals)[face]
    details = dict(info or {})
    details.update(
        faces=n_faces_in,
        faces_used=len(oriented.faces),
        vertices=len(oriented.vertices),
        watertight=bool(oriented.is_watertight),
        components=int(
            trimesh.graph.connected_component_labels(
                oriented.face_adjacency, node_count=len(oriented.faces)
            ).max()
            + 1
        ),
        normals=f"face normals, outward by {method}",
        faces_flipped=n_flipped,
    )
    return OrientedCloud(
        points, normals, modality=modality, mesh=oriented, face_index=face, info=details
    )


def load_mesh_file(path: str | os.PathLike, fmt: str, opts: LoadOptions) -> OrientedCloud:
    """Loader for the ``mesh`` modality (see :func:`pointcvx.io.load`)."""
    mesh = read_mesh(path, fmt)
    n = opts.n_points if opts.n_points is not None else opts.mesh_points
    try:
        return cloud_from_mesh(mesh, n_points=n, seed=opts.seed, orient_rays=opts.orient_rays)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
