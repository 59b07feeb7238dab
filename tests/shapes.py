"""Analytic test solids with known decompositions (watertight, outward, built with manifold3d)."""

from __future__ import annotations

import numpy as np
import trimesh


def _union(boxes: list[tuple[list[float], list[float]]]) -> trimesh.Trimesh:
    import manifold3d as m3d

    solid = None
    for lo, hi in boxes:
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        b = m3d.Manifold.cube(list(hi - lo)).translate(list(lo))
        solid = b if solid is None else solid + b
    mesh = solid.to_mesh()
    return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts))


def l_block() -> trimesh.Trimesh:
    """An L: a 2x1x1 bar and a 1x1x1 cube on one end (two convex pieces)."""
    return _union([([0, 0, 0], [2, 1, 1]), ([0, 0, 1], [1, 1, 2])])


def u_block() -> trimesh.Trimesh:
    """A U: a 3x1x1 base and two 1x1x2 posts (three convex pieces)."""
    return _union([([0, 0, 0], [3, 1, 1]), ([0, 0, 1], [1, 1, 3]), ([2, 0, 1], [3, 1, 3])])


def two_boxes() -> trimesh.Trimesh:
    """Two unit cubes 1 apart (two components)."""
    a = trimesh.creation.box(extents=[1, 1, 1])
    b = trimesh.creation.box(extents=[1, 1, 1])
    b.apply_translation([2.0, 0, 0])
    return trimesh.util.concatenate([a, b])


def torus() -> trimesh.Trimesh:
    return trimesh.creation.torus(major_radius=1.0, minor_radius=0.3, major_sections=48,
                                  minor_sections=16)


def pocket_block() -> trimesh.Trimesh:
    """A 2x2x1 block with a 1x1x0.4 pocket sunk into the middle of its top (floor at z = 0.6)."""
    import manifold3d as m3d

    block = m3d.Manifold.cube([2.0, 2.0, 1.0])
    pocket = m3d.Manifold.cube([1.0, 1.0, 0.5]).translate([0.5, 0.5, 0.6])
    mesh = (block - pocket).to_mesh()
    return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts))
