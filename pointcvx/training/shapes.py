"""Procedural non-convex solids for training: unions and differences of primitives.

A shape is built from 2-6 primitives (boxes, cylinders, capsules, spheres, tori) at random poses
and scales, combined with exact manifold3d booleans, so every result is watertight and wound
outward. Each new primitive is centred on a point of the current surface, so unions stay
connected and differences carve dents, notches and holes into the solid instead of missing it.
Results are normalised so their bounding box fits 0.9 of [-1, 1]^3 (the release convention:
centre at the origin, longest side 1.8). Deterministic per generator state.
"""

from __future__ import annotations

import logging

import numpy as np

log = logging.getLogger(__name__)

#: Primitive kinds and their draw probabilities.
PRIMITIVES = ("box", "cylinder", "capsule", "sphere", "torus")
_KIND_P = np.array([0.3, 0.2, 0.15, 0.15, 0.2])
#: Segments around circles (cheap but round enough at 128^3).
SEGMENTS = 32
#: Half of the longest bounding-box side after normalisation.
EXTENT = 0.9


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """(3, 3) float rotation matrix uniform on SO(3) (QR of a Gaussian matrix, sign-fixed)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def primitive(kind: str, size: np.ndarray):
    """A manifold3d ``Manifold`` of the given kind centred at the origin.

    ``size`` (3,) float: box side lengths; for cylinder and capsule (radius, -, length); for sphere
    the radius is ``size[0]``; for a torus (major radius, tube radius ratio, -).
    """
    import manifold3d as m3d

    a, b, c = (float(s) for s in size)
    if kind == "box":
        return m3d.Manifold.cube((a, b, c), center=True)
    if kind == "cylinder":
        return m3d.Manifold.cylinder(c, a, circular_segments=SEGMENTS, center=True)
    if kind == "capsule":
        ends = [m3d.Manifold.sphere(a, SEGMENTS).translate((0.0, 0.0, z)) for z in (-c / 2, c / 2)]
        return m3d.Manifold.batch_hull(ends)
    if kind == "sphere":
        return m3d.Manifold.sphere(a, SEGMENTS)
    if kind == "torus":
        tube = a * b
        section = m3d.CrossSection.circle(tube, SEGMENTS // 2).translate((a, 0.0))
        return m3d.Manifold.revolve(section, SEGMENTS)
    raise ValueError(f"unknown primitive {kind!r}")


def _random_primitive(rng: np.random.Generator, scale: float):
    """A random primitive of overall size about ``scale``, randomly rotated (at the origin)."""
    kind = PRIMITIVES[int(rng.choice(len(PRIMITIVES), p=_KIND_P))]
    if kind == "box":
        size = scale * rng.uniform(0.3, 1.0, size=3)
    elif kind in ("cylinder", "capsule"):
        size = np.array([scale * rng.uniform(0.12, 0.35), 0.0, scale * rng.uniform(0.5, 1.2)])
    elif kind == "sphere":
        size = np.array([scale * rng.uniform(0.25, 0.5), 0.0, 0.0])
    else:
        size = np.array([scale * rng.uniform(0.3, 0.5), rng.uniform(0.2, 0.45), 0.0])
    rot = random_rotation(rng)
    affine = np.concatenate([rot, np.zeros((3, 1))], axis=1)
    return kind, primitive(kind, size).transform(affine.tolist())


def to_trimesh(manifold):
    """``trimesh.Trimesh`` of a manifold3d ``Manifold`` (positions only)."""
    import trimesh

    mesh = manifold.to_mesh()
    vertices = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    return trimesh.Trimesh(vertices, faces, process=False)


def normalize_mesh(mesh, extent: float = EXTENT):
    """``mesh`` (trimesh.Trimesh) copied, bbox centred at the origin, longest side ``2 * extent``."""
    lo, hi = mesh.bounds
    longest = float((hi - lo).max())
    if not np.isfinite(longest) or longest <= 0:
        raise ValueError("the mesh has no extent")
    out = mesh.copy()
    out.vertices = (np.asarray(mesh.vertices) - (lo + hi) / 2.0) * (2.0 * extent / longest)
    return out


def _surface_point(manifold, rng: np.random.Generator) -> np.ndarray:
    """(3,) float: a random vertex of the manifold's mesh (a point on its surface)."""
    verts = np.asarray(manifold.to_mesh().vert_properties)[:, :3]
    return verts[int(rng.integers(len(verts)))].astype(np.float64)


def _build(rng: np.random.Generator, n_parts: int):
    """One attempt: (Manifold, list of (kind, op)). May be empty or degenerate."""
    kind, shape = _random_primitive(rng, rng.uniform(0.8, 1.2))
    recipe = [(kind, "base")]
    for _ in range(n_parts - 1):
        kind, part = _random_primitive(rng, rng.uniform(0.4, 0.9))
        at = _surface_point(shape, rng) + rng.normal(scale=0.05, size=3)
        part = part.translate(at.tolist())
        if rng.random() < 0.55:
            shape, op = shape + part, "union"
        else:
            shape, op = shape - part, "difference"
        recipe.append((kind, op))
        if shape.is_empty():
            break
    return shape, recipe


def _largest_component(manifold):
    parts = manifold.decompose()
    if len(parts) <= 1:
        return manifold
    return max(parts, key=lambda p: p.volume())


def random_solid(rng: np.random.Generator, max_tries: int = 20, max_hull_ratio: float = 0.97):
    """A random non-convex solid (``trimesh.Trimesh``): watertight, outward-wound, normalised.

    2-6 primitives combined by unions and differences (module docstring). Degenerate results
    (empty, split into tiny pieces, or almost no volume relative to their bounding box) are
    rejected, and so are nearly convex ones (volume above ``max_hull_ratio`` of the convex
    hull's; 1 disables the test); rejected shapes are drawn again from the same generator, so
    the result is deterministic per generator state. Disconnected results keep their largest piece.

    Returns
    -------
    trimesh.Trimesh
        Bounding box centred at the origin with longest side 1.8.
    """
    for attempt in range(max_tries):
        n_parts = int(rng.integers(2, 7))
        shape, recipe = _build(rng, n_parts)
        if shape.is_empty():
            continue
        shape = _largest_component(shape)
        lo_hi = np.asarray(shape.bounding_box(), dtype=np.float64)
        span = lo_hi[3:] - lo_hi[:3]
        if span.min() < 0.05 * span.max():  # a sliver
            continue
        if shape.volume() < 0.03 * float(np.prod(span)):
            continue
        mesh = to_trimesh(shape)
        if len(mesh.faces) < 8 or not mesh.is_watertight:
            continue
        if max_hull_ratio < 1.0 and mesh.volume > max_hull_ratio * mesh.convex_hull.volume:
            continue
        log.debug("random_solid: attempt %d, %s", attempt, recipe)
        return normalize_mesh(mesh)
    raise RuntimeError(f"random_solid: no valid shape in {max_tries} tries")
