"""Meshes (OBJ, PLY, STL, OFF, GLB/GLTF) -> oriented clouds of area-weighted surface samples.

Real meshes are often open, multi-component or badly wound, so outward orientation is decided
per face by ray parity, which does not depend on the winding: a point just outside a closed
surface sees an even number of crossings along a ray, a point just inside an odd number. Faces of
one connected component follow the component's area-weighted vote; a face whose own evidence
strongly contradicts it is flipped alone. Watertight, consistently wound meshes skip the rays:
a positive signed volume settles their orientation.
"""

from __future__ import annotations

import io
import logging
import os
import re
import struct
import warnings

import numpy as np

from ..cloud import OrientedCloud, check_points
from ..errors import InputError, first_line
from ..options import LoadOptions
from .files import check_readable

log = logging.getLogger(__name__)

_TRIMESH_TYPE = {"obj": "obj", "ply-mesh": "ply", "stl": "stl", "off": "off", "glb": "glb", "gltf": "gltf"}
# What trimesh raises on files it cannot parse (AssertionError: the glTF reader's size checks).
_PARSE_ERRORS = (ValueError, IndexError, KeyError, TypeError, OSError, EOFError, AttributeError,
                 AssertionError, RecursionError, UnicodeDecodeError, struct.error)
#: Not a plain OFF (:func:`plain_off`): a comment, a line break of ``str.splitlines`` that
#: ``bytes.splitlines`` does not know, or any byte beyond ASCII.
_NOT_PLAIN = re.compile(rb"[#\x0b\x0c\x1c-\x1e\x80-\xff]")
_OBJ_ZERO = re.compile(rb"[ \t][-+]?0+(?=[/ \t\r\n]|$)")


def check_obj_indices(p, data: bytes) -> None:
    """:class:`InputError` naming the line of the first OBJ face with a vertex index 0 (OBJ counts
    from 1, and trimesh would read 0 as -1, the last vertex)."""
    for m in _OBJ_ZERO.finditer(data):
        start = data.rfind(b"\n", 0, m.start()) + 1
        if data[start:m.start() + 1].lstrip()[:2] in (b"f ", b"f\t"):
            line = data.count(b"\n", 0, start) + 1
            raise InputError(f"{p}: corrupted OBJ: line {line} has a face with vertex index 0 "
                             "(OBJ indices start at 1)")


def check_off_counts(p, data: bytes) -> None:
    """:class:`InputError` when an OFF header declares more vertices and faces than its text can hold
    (each needs at least 6 bytes: ``0 0 0`` and a newline)."""
    lines = [ln.split(b"#", 1)[0] for ln in data[:4096].splitlines()]
    words = b" ".join(ln for ln in lines if ln.strip()).split()[:4]
    if len(words) >= 3 and words[0].endswith(b"OFF") and words[1].isdigit() and words[2].isdigit():
        vertices, faces = int(words[1]), int(words[2])
        if 6 * (vertices + faces) > len(data):
            raise InputError(f"{p}: truncated or corrupted OFF: the header declares {vertices} vertices and "
                             f"{faces} faces, the file has {len(data)} bytes")


def plain_off(data: bytes) -> tuple[np.ndarray, np.ndarray] | None:
    """((v, 3) float64 vertices, (f, 3) int64 faces) of an OFF file's bytes when it is the
    plain kind (``OFF`` header, no comments or colours, three coordinates per vertex line and
    triangles only, as every OFF of vhacd61 and dev/ is), parsed by numpy's C text reader;
    None for anything else, which trimesh reads. The same arrays as trimesh's reader (its
    Python loop over the lines took 0.25 s of loading ``bunny.off``, 35k vertices; this
    0.04 s)."""
    if _NOT_PLAIN.search(data):
        return None
    lines = [ln for ln in data.splitlines() if ln.strip()]
    if not lines:
        return None
    head = lines[0].split()
    if head == [b"OFF"] and len(lines) > 1:
        counts, start = lines[1].split(), 2
    elif len(head) == 4 and head[0] == b"OFF":
        counts, start = head[1:], 1
    else:
        return None
    if len(counts) != 3 or not all(c.isdigit() for c in counts):
        return None
    n_vertices, n_faces = int(counts[0]), int(counts[1])
    if n_vertices < 3 or n_faces < 1 or len(lines) != start + n_vertices + n_faces:
        return None
    try:  # loadtxt refuses rows of another width: each line holds exactly what is asked
        vertices = np.loadtxt(io.BytesIO(b"\n".join(lines[start:start + n_vertices])),
                              dtype=np.float64, ndmin=2)
        faces = np.loadtxt(io.BytesIO(b"\n".join(lines[start + n_vertices:])), dtype=np.int64, ndmin=2)
    except ValueError:
        return None
    if vertices.shape != (n_vertices, 3) or faces.shape != (n_faces, 4) or np.any(faces[:, 0] != 3):
        return None
    faces = np.ascontiguousarray(faces[:, 1:])
    if faces.min() < 0 or faces.max() >= n_vertices:
        return None  # trimesh names the error
    return vertices, faces


def read_mesh(path: str | os.PathLike, fmt: str):
    """Read a mesh file with trimesh; scenes are flattened with their node transforms applied.

    The declared structure is checked first (OBJ face indices, OFF counts, glTF sizes and URIs,
    see :mod:`pointcvx.io.gltf`); materials are not read (no texture or ``mtllib`` is opened).
    Returns a ``trimesh.Trimesh`` in the file's units; raises :class:`InputError` when the file
    cannot be parsed or holds no triangles.
    """
    import trimesh

    p = check_readable(path)
    file_type = _TRIMESH_TYPE.get(fmt, fmt)
    if fmt in ("obj", "off"):
        data = p.read_bytes()
        (check_obj_indices if fmt == "obj" else check_off_counts)(p, data)
        plain = plain_off(data) if fmt == "off" else None
        if plain is not None:
            return trimesh.Trimesh(*plain, process=False, metadata={"name": p.name, "node": p.name})
    elif fmt in ("glb", "gltf"):
        from .gltf import check_gltf

        check_gltf(p, fmt)
    kwargs = {"skip_materials": True} if fmt in ("obj", "glb", "gltf") else {}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            loaded = trimesh.load(str(p), file_type=file_type, force="mesh", process=False, **kwargs)
    except _PARSE_ERRORS as exc:
        msg = first_line(exc, typed=not str(exc).strip() or isinstance(exc, (AssertionError, KeyError)))
        raise InputError(f"{p}: cannot read {file_type.upper()} mesh ({msg})") from None
    if isinstance(loaded, list):
        loaded = trimesh.util.concatenate(loaded)
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise InputError(f"{p}: the {file_type.upper()} file holds no triangles")
    return loaded


def clean_mesh(mesh):
    """A copy of ``mesh`` with merged vertices and no degenerate or unused parts.

    Vertices that no face uses are dropped whatever their coordinates; :class:`InputError` when a
    face uses a NaN/inf vertex (or one beyond :data:`~pointcvx.cloud.MAX_COORDINATE`), or
    nothing with area remains. ``mesh.metadata["non_finite_dropped"]`` counts the unused
    non-finite vertices dropped.
    """
    import trimesh

    vertices = np.asarray(mesh.vertices)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError("mesh faces reference missing vertices")
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.ravel()] = True
    bad = ~np.isfinite(vertices).all(axis=1)
    dropped = int((bad & ~used).sum())
    if dropped:
        keep = ~(bad & ~used)
        remap = np.cumsum(keep) - 1
        vertices, faces = vertices[keep], remap[faces]
    vertices = check_points(vertices, "mesh vertices used by faces")
    out = trimesh.Trimesh(vertices, faces, process=False)
    out.merge_vertices(merge_tex=True, merge_norm=True)
    keep = out.nondegenerate_faces(height=1e-12 * max(float(out.scale), 1e-300))
    keep &= out.area_faces > 0
    out.update_faces(keep)
    out.update_faces(out.unique_faces())
    out.remove_unreferenced_vertices()
    if len(out.faces) == 0 or out.area <= 0:
        raise InputError("the mesh has no triangle with area: all faces are degenerate")
    if dropped:
        out.metadata["non_finite_dropped"] = dropped
    return out


def _random_directions(n: int, rng: np.random.Generator) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def crossings(mesh, points: np.ndarray, n_rays: int = 8, seed: int = 0) -> np.ndarray:
    """(m, n_rays) int: how many times each of ``n_rays`` random rays from each of (m, 3)
    ``points`` crosses ``mesh`` (Embree through open3d's RaycastingScene)."""
    from ..syslibs import import_open3d
    o3d = import_open3d()

    from ..embree import raycasting_scene

    scene = raycasting_scene(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    rng = np.random.default_rng(seed)
    m = len(points)
    origins = np.repeat(points.astype(np.float32), n_rays, axis=0)
    dirs = _random_directions(m * n_rays, rng).astype(np.float32)
    rays = o3d.core.Tensor(np.concatenate([origins, dirs], axis=1))
    return scene.count_intersections(rays).numpy().reshape(m, n_rays)


def inside_fraction(mesh, points: np.ndarray, n_rays: int = 8, seed: int = 0) -> np.ndarray:
    """(m,) float in [0, 1]: share of ``n_rays`` random rays from each of (m, 3) ``points`` that
    cross ``mesh`` an odd number of times (1 deep inside a closed surface, 0 outside).

    Independent of face winding; uses Embree through open3d's RaycastingScene.
    """
    return (crossings(mesh, points, n_rays, seed) % 2 == 1).mean(axis=1)


def side_points(mesh, faces: np.ndarray | None = None) -> np.ndarray:
    """(2m, 3) float: points just behind, then just in front of, the centres of ``faces`` ((m,)
    int, default all), offset along the normal a little, relative to the face's own size and the
    mesh's scale."""
    centers = np.asarray(mesh.triangles_center)
    normals = np.asarray(mesh.face_normals)
    delta = np.minimum(np.sqrt(mesh.area_faces) * 0.05, 1e-3 * float(mesh.scale))[:, None]
    delta = np.maximum(delta, 1e-7 * float(mesh.scale))
    if faces is not None:
        centers, normals, delta = centers[faces], normals[faces], delta[faces]
    return np.concatenate([centers - delta * normals, centers + delta * normals])


def face_outward_scores(mesh, n_rays: int = 8, seed: int = 0, faces: np.ndarray | None = None) -> np.ndarray:
    """(f,) float in [-1, 1] (or (m,) for the (m,) int ``faces`` given): positive where a face
    normal points out of the solid.

    Score = inside share just behind the face minus inside share just in front of it. Near 0 for
    faces of open sheets, where both sides are outside.
    """
    frac = inside_fraction(mesh, side_points(mesh, faces), n_rays=n_rays, seed=seed)
    f = len(frac) // 2
    return frac[:f] - frac[f:]


#: The outward test casts rays from at most this many faces; larger meshes vote with a seeded
#: uniform sample of their faces.
ORIENT_FACES = 400_000
#: Ray-mesh crossings the outward test may count in all. A ray crosses a real surface a few
#: times, one through a soup of overlapping triangles hundreds of times, and the cost follows
#: the crossings: the sample shrinks to stay within this, as measured on ORIENT_PILOT faces.
ORIENT_CROSSINGS = 10_000_000
ORIENT_PILOT = 512


def scored_faces(mesh, n_rays: int, seed: int, labels: np.ndarray | None = None) -> np.ndarray | None:
    """(m,) int sorted faces the outward test scores, or None for all of them: a seeded sample
    when the mesh has more than :data:`ORIENT_FACES` faces or its rays would cross it more than
    :data:`ORIENT_CROSSINGS` times in all (estimated from a pilot of :data:`ORIENT_PILOT` faces).

    With ``labels`` ((f,) int piece of each face) the sample goes round the pieces: every piece
    gets its first face before any gets a second, so small pieces vote too.
    """
    f = len(mesh.faces)
    pilot = np.random.default_rng([seed, 1]).choice(f, min(f, ORIENT_PILOT), replace=False)
    per_face = crossings(mesh, side_points(mesh, pilot), n_rays, seed).sum() / max(len(pilot), 1)
    m = min(f, ORIENT_FACES, max(ORIENT_PILOT, int(ORIENT_CROSSINGS / max(per_face, 1e-9))))
    if m >= f:
        return None
    rng = np.random.default_rng([seed, 2])
    if labels is None:
        return np.sort(rng.choice(f, m, replace=False))
    return round_the_pieces(np.arange(f), labels, m, rng)


def round_the_pieces(faces: np.ndarray, labels: np.ndarray, m: int, rng: np.random.Generator) -> np.ndarray:
    """(m,) int sorted: a seeded sample of the (k,) int ``faces`` ((k,) int ``labels``, their
    pieces) that goes round the pieces: every piece gets its first face before any gets a
    second, so small pieces vote too."""
    k = len(faces)
    grouped = np.argsort(labels, kind="stable")
    grouped = grouped[np.lexsort((rng.random(k), labels[grouped]))]  # by piece, random within
    first = np.searchsorted(labels[grouped], labels[grouped])
    rank = np.arange(k) - first  # 0 for each piece's first face in that order, 1 for its second...
    return np.sort(faces[grouped[np.lexsort((rng.random(k), rank))[:m]]])


#: Faces of consistently wound pieces whose outward scores vote on their pieces' sides; a larger
#: mesh's votes come from a seeded sample of them round the pieces (:func:`vote_sample`). A
#: piece's area-weighted vote does not need 100,000 faces, and the rays cost 1-3 s of loading
#: such a mesh. Of the 16 meshes of vhacd61 and dev/ over 20,000 faces that are not watertight,
#: 10 came out face for face the same and 6 differ in 1 to 55 of 45,000-125,000 faces: single
#: faces whose own rays sit near the flip threshold (the rays follow the sample).
ORIENT_VOTE_FACES = 20_000


def vote_sample(sample: np.ndarray | None, labels: np.ndarray, conflicted: np.ndarray,
                seed: int) -> np.ndarray | None:
    """The faces the outward test scores: ``sample`` (None for all, see :func:`scored_faces`)
    with the faces of consistently wound pieces thinned to :data:`ORIENT_VOTE_FACES`. Faces of
    conflicted pieces ((f,) bool ``conflicted``) stay: each decides its own side by its score."""
    faces = np.arange(len(labels)) if sample is None else sample
    free = faces[~conflicted[faces]]
    if len(free) <= ORIENT_VOTE_FACES:
        return sample
    keep = round_the_pieces(free, labels[free], ORIENT_VOTE_FACES, np.random.default_rng([seed, 3]))
    return np.sort(np.concatenate([keep, faces[conflicted[faces]]]))


def piece_volumes(mesh, labels: np.ndarray) -> np.ndarray:
    """(pieces,) float: signed volume of each piece's faces seen from the mesh's vertex centroid
    (positive when they face away from it): the vote of pieces with no scored face."""
    tri = np.asarray(mesh.triangles) - np.asarray(mesh.vertices).mean(axis=0)
    vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2]))
    return np.bincount(labels, weights=vol)


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
    they point inward are flipped alone. The work is bounded (:func:`scored_faces`): on very
    large meshes, and on soups of overlapping triangles that every ray crosses hundreds of
    times, a seeded sample of faces votes; and consistently wound pieces vote with at most
    :data:`ORIENT_VOTE_FACES` of their faces (:func:`vote_sample`). The input mesh is not modified.
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
    sample = vote_sample(scored_faces(wound, n_rays, seed, labels), labels, conflicted, seed)
    method = f"ray parity ({n_rays} rays per side)"
    if sample is None:
        scores = face_outward_scores(wound, n_rays=n_rays, seed=seed)
        vote = np.bincount(labels, weights=wound.area_faces * scores)
    else:  # bounded work: a seeded sample votes; pieces it misses go by their signed volume
        scores = np.zeros(len(faces))
        scores[sample] = face_outward_scores(wound, n_rays=n_rays, seed=seed, faces=sample)
        vote = np.bincount(labels, weights=wound.area_faces * scores)
        missed = np.bincount(labels[sample], minlength=len(vote)) == 0
        vote[missed] = piece_volumes(wound, labels)[missed]
        method = f"ray parity ({n_rays} rays per side, from {len(sample)} of {len(faces)} faces)"
        log.info("outward test on a sample of %d of %d faces (bounded work)", len(sample), len(faces))
    turn = np.where(vote[labels] < 0, -1.0, 1.0)
    turn[conflicted & (scores * turn <= -0.75)] *= -1.0
    total = sign * turn
    out = trimesh.Trimesh(np.asarray(mesh.vertices), _flip(faces, total < 0), process=False)
    return out, int((total < 0).sum()), method


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
    if cleaned.metadata.get("non_finite_dropped"):
        details["non_finite_dropped"] = int(cleaned.metadata["non_finite_dropped"])
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
