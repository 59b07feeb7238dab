"""Embree ray-casting scenes over triangle soups (through open3d): the ray-query primitive of the
mesh loader's outward test, the solids and the hull distances."""

from __future__ import annotations

import numpy as np


def raycasting_scene(vertices: np.ndarray, faces: np.ndarray):
    """An open3d ``RaycastingScene`` (Embree) over (v, 3) vertices and (f, 3) faces."""
    from .syslibs import import_open3d

    o3d = import_open3d()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32)),
        o3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.uint32)),
    )
    return scene
