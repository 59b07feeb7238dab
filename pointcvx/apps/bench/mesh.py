"""The one mesh every method decomposes: a shape's mesh normalised to [-1, 1]^3, as
:func:`pointcvx.evaluate.evaluate` normalises it, and written where the workers read it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...cloud import Normalization
from ...errors import InputError


def prepare_mesh(path: str, modality: str, fmt: str, seed: int):
    """The shape's mesh (only the vertices its faces use) normalised to [-1, 1]^3, as a
    ``trimesh.Trimesh``. CAD parts are tessellated by :func:`pointcvx.load`."""
    import trimesh

    if modality == "mesh":
        from ...io.mesh import read_mesh

        mesh = read_mesh(path, fmt)
    else:
        from ...io import load

        mesh = load(path, normalize=False, seed=seed).mesh
        if mesh is None:
            raise InputError(f"{path}: the {modality} loader returned no mesh")
    faces = np.asarray(mesh.faces, dtype=np.int64)
    used, inverse = np.unique(faces, return_inverse=True)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)[used]
    if not np.isfinite(vertices).all():
        raise InputError(f"{path}: the mesh has non-finite vertices")
    norm = Normalization.to_unit_cube(vertices)
    return trimesh.Trimesh(norm.forward(vertices), inverse.reshape(-1, 3), process=False)


def write_mesh_obj(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Write (n, 3) float ``vertices`` and (m, 3) int ``faces`` (0-based) as a plain OBJ."""
    with open(path, "w") as f:
        np.savetxt(f, vertices, fmt="v %.9g %.9g %.9g")
        np.savetxt(f, faces + 1, fmt="f %d %d %d")
