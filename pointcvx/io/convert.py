"""In-memory inputs -> :class:`~pointcvx.cloud.OrientedCloud`: numpy arrays, trimesh and open3d
geometry (:func:`pointcvx.io.as_cloud` takes any of them, or a path)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..cloud import OrientedCloud, check_extent, check_points
from ..errors import InputError


def from_numpy(points: Any, normals: Any = None, colors: Any = None, *, modality: str = "points",
               **scan_options: Any) -> OrientedCloud:
    """A cloud of (n, 3) ``points`` with (n, 3) ``normals``; without normals they are estimated
    and oriented as for a scan (:func:`pointcvx.io.scan.cloud_from_points`, which takes
    ``scan_options``)."""
    pts = check_points(points)
    check_extent(pts)
    if colors is not None:
        colors = check_points(colors, "colors")
    if normals is None:
        from .scan import cloud_from_points

        return cloud_from_points(pts, colors=colors, modality=modality, **scan_options)
    normals = check_points(normals, "normals")
    return OrientedCloud(pts, normals, colors=colors, modality=modality, info={"normals": "given"})


def from_trimesh(mesh: Any, n_points: int = 20000, seed: int = 0, **options: Any) -> OrientedCloud:
    """Sample a ``trimesh.Trimesh`` (or Scene) into an oriented cloud (:mod:`pointcvx.io.mesh`)."""
    from .mesh import cloud_from_mesh

    return cloud_from_mesh(mesh, n_points=n_points, seed=seed, **options)


def from_open3d(geometry: Any, n_points: int = 20000, seed: int = 0, **options: Any) -> OrientedCloud:
    """A cloud from an ``open3d.geometry.PointCloud`` or ``TriangleMesh``.

    A point cloud keeps its points and normals if it has normals (their signs are made
    consistent); without normals it is cleaned and its normals estimated as a scan. A triangle
    mesh is sampled like any mesh.
    """
    from ..syslibs import import_open3d

    o3d = import_open3d()
    if isinstance(geometry, o3d.geometry.TriangleMesh):
        import trimesh

        mesh = trimesh.Trimesh(np.asarray(geometry.vertices), np.asarray(geometry.triangles), process=False)
        return from_trimesh(mesh, n_points=n_points, seed=seed, **options)
    if isinstance(geometry, o3d.geometry.PointCloud):
        from .scan import cloud_from_points

        pts = np.asarray(geometry.points)
        colors = np.asarray(geometry.colors) if geometry.has_colors() else None
        normals = np.asarray(geometry.normals) if geometry.has_normals() else None
        if normals is not None:  # a cloud with normals is taken as clean unless told otherwise
            options.setdefault("outlier_neighbors", 0)
        return cloud_from_points(pts, normals=normals, colors=colors, n_points=n_points,
                                 seed=seed, modality="points", **options)
    raise InputError(f"cannot build a cloud from {type(geometry).__name__}")
