"""Hulls as mesh files: OBJ text (one object per hull), binary STL, GLB/GLTF scenes."""

from __future__ import annotations

import numpy as np


def obj_text(hulls, names: list[str] | None = None, digits: int = 17, header: bool = True) -> str:
    """Wavefront OBJ text with one ``o`` object per hull (1-based global indices).

    ``hulls``: a sequence of ((v, 3) float vertices, (f, 3) int faces) pairs; ``names``: the
    objects' names (default ``hull_NNN``); ``digits``: significant digits of the coordinates (the
    default 17 keeps every float64 exactly, so a hull read back still contains what it contained).
    """
    names = names if names is not None else [f"hull_{i:03d}" for i in range(len(hulls))]
    lines = ["# pointcvx convex decomposition", f"# hulls {len(hulls)}"] if header else []
    offset = 1
    for name, (vertices, faces) in zip(names, hulls, strict=True):
        lines.append(f"o {name}")
        lines.extend(f"v {x:.{digits}g} {y:.{digits}g} {z:.{digits}g}"
                     for x, y, z in np.asarray(vertices, dtype=np.float64))
        lines.extend(f"f {a + offset} {b + offset} {c + offset}"
                     for a, b, c in np.asarray(faces, dtype=np.int64))
        offset += len(vertices)
    return "\n".join(lines) + "\n"


def mesh_obj_text(vertices: np.ndarray, faces: np.ndarray, name: str = "mesh") -> str:
    """OBJ text of one mesh, (v, 3) float ``vertices`` and (f, 3) int ``faces``, at full float
    precision (17 digits) and without the decomposition header."""
    return obj_text([(vertices, faces)], names=[name], header=False)


def stl_bytes(vertices: np.ndarray, faces: np.ndarray, name: str = "pointcvx") -> bytes:
    """Binary STL of (v, 3) float ``vertices`` and (f, 3) int ``faces`` (float32, as STL stores)."""
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
    record = np.dtype([("normal", "<f4", 3), ("tri", "<f4", (3, 3)), ("attr", "<u2")])
    data = np.zeros(len(tri), dtype=record)
    data["normal"], data["tri"] = normal, tri
    header = name.encode("ascii", "replace")[:80].ljust(80, b" ")
    return header + np.uint32(len(tri)).tobytes() + data.tobytes()


def scene_bytes(hulls, file_type: str = "glb", names: list[str] | None = None) -> bytes:
    """A GLB or GLTF (buffers embedded) scene with one node per hull (``names``, default
    ``hull_NNN``).

    ``hulls``: a sequence of ((v, 3) float vertices, (f, 3) int faces) pairs.
    """
    import trimesh

    scene = trimesh.Scene()
    names = names if names is not None else [f"hull_{i:03d}" for i in range(len(hulls))]
    for name, (vertices, faces) in zip(names, hulls, strict=True):
        mesh = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(faces), process=False)
        scene.add_geometry(mesh, node_name=name, geom_name=name)
    if file_type == "glb":
        return scene.export(file_type="glb")
    files = trimesh.exchange.gltf.export_gltf(scene, embed_buffers=True)
    return files["model.gltf"]
