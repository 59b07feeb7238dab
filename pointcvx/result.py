"""The one result type: a convex decomposition, plain numpy at the boundary."""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .cloud import OrientedCloud
from .errors import OutputError
from .io.files import atomic_path

log = logging.getLogger(__name__)


@dataclass(eq=False)
class ConvexHull:
    """One convex piece, in the input's units.

    Attributes
    ----------
    vertices : (v, 3) float64
    faces : (f, 3) int64, wound outward.
    concavity : float
        Concavity of the part it covers, in the normalised [-1, 1]^3 frame.
    points : int
        How many cloud points the part holds.
    """

    vertices: np.ndarray
    faces: np.ndarray
    concavity: float
    points: int

    @property
    def volume(self) -> float:
        tri = self.vertices[self.faces]
        return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)

    def to_trimesh(self):
        import trimesh

        return trimesh.Trimesh(self.vertices.copy(), self.faces.copy(), process=False)


@dataclass(eq=False)
class Decomposition:
    """A convex decomposition of one shape.

    Attributes
    ----------
    hulls : list of ConvexHull
        In the input's units; every cloud point lies in the hull of its part.
    labels : (n,) int64
        Hull index of each point of ``cloud``.
    cloud : OrientedCloud
        The points that were decomposed (normalised frame; ``cloud.normalization`` maps back).
    features : (n, k) float32
        The features used for splitting.
    tree : list of dict
        The split tree (id, parent, children, points, concavity), root first.
    timings : dict of str -> float
        Seconds per stage.
    params : dict
        Every setting that produced the result, seed included.
    """

    hulls: list[ConvexHull]
    labels: np.ndarray
    cloud: OrientedCloud
    features: np.ndarray
    tree: list[dict]
    timings: dict[str, float]
    params: dict[str, Any]
    _decomposer: Any = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.hulls)

    def __repr__(self) -> str:
        return (f"Decomposition({len(self.hulls)} hulls, max concavity {self.max_concavity:.4f}, "
                f"{self.timings.get('total', 0.0):.2f} s)")

    @property
    def seed(self) -> int:
        return int(self.params.get("seed", 0))

    @property
    def concavity(self) -> np.ndarray:
        """(h,) float: concavity of each hull's part (normalised frame)."""
        return np.array([h.concavity for h in self.hulls], dtype=np.float64)

    @property
    def max_concavity(self) -> float:
        return float(self.concavity.max()) if self.hulls else 0.0

    def summary(self) -> dict[str, Any]:
        """The numbers people check: hull count, concavity, time."""
        return {
            "hulls": len(self.hulls),
            "max_concavity": round(self.max_concavity, 5),
            "mean_concavity": round(float(self.concavity.mean()), 5) if self.hulls else 0.0,
            "points": int(len(self.labels)),
            "hull_vertices": int(sum(len(h.vertices) for h in self.hulls)),
            "seconds": round(float(self.timings.get("total", 0.0)), 3),
        }

    # ------------------------------------------------------------------ re-cutting
    def recut(self, threshold: float | None = None, max_hulls: int | None = None,
              merge: bool | None = None) -> Decomposition:
        """The same features and split tree cut at another threshold or hull count.

        Splits already made are reused; deeper ones are computed on demand. Nothing about the
        features is recomputed.
        """
        from .pipeline import cut_decomposition

        if self._decomposer is None:
            raise OutputError("this decomposition no longer holds its split tree (it was loaded "
                              "from disk); decompose again to re-cut it")
        params = dict(self.params)
        if threshold is not None:
            params["threshold"] = float(threshold)
        if max_hulls is not None:
            params["max_hulls"] = int(max_hulls)
        if merge is not None:
            params["merge"] = bool(merge)
        return cut_decomposition(self._decomposer, self.cloud, self.features, params,
                                 dict(self.timings))

    # ------------------------------------------------------------------ conversions
    def to_trimesh(self):
        """A ``trimesh.Scene`` with one geometry per hull (``hull_000``, ...)."""
        import trimesh

        scene = trimesh.Scene()
        for i, h in enumerate(self.hulls):
            scene.add_geometry(h.to_trimesh(), node_name=f"hull_{i:03d}", geom_name=f"hull_{i:03d}")
        return scene

    def to_open3d(self) -> list:
        """A list of ``open3d.geometry.TriangleMesh``, one per hull, with vertex normals."""
        import open3d as o3d

        out = []
        for h in self.hulls:
            m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(h.vertices),
                                          o3d.utility.Vector3iVector(h.faces.astype(np.int32)))
            m.compute_vertex_normals()
            out.append(m)
        return out

    # ------------------------------------------------------------------ export
    def export(self, path: str | os.PathLike, *, overwrite: bool = False,
               per_hull: bool = False) -> list[Path]:
        """Write the hulls; return the files written.

        ``path`` ending in ``.obj``: one OBJ with an ``o hull_NNN`` object per hull. With
        ``per_hull=True``, a ``path`` that is a directory or has no suffix: one ``hull_NNN.obj``
        per hull in that directory; a ``path`` ending in ``.stl``: one ``hull_NNN.stl`` per hull
        in the directory named by its stem. Writes are
        atomic; existing files are kept unless ``overwrite``.
        """
        target = Path(path)
        suffix = target.suffix.lower()
        if per_hull or target.is_dir() or suffix in ("", ".stl"):
            ext = ".obj"
            folder = target
            if suffix in (".obj", ".stl"):
                ext, folder = suffix, target.with_suffix("")
            folder.mkdir(parents=True, exist_ok=True)
            paths = [folder / f"hull_{i:03d}{ext}" for i in range(len(self.hulls))]
            clash = [p for p in paths if p.exists()] if not overwrite else []
            if clash:
                raise OutputError(f"{clash[0]}: exists; pass overwrite to replace it")
            for p, h in zip(paths, self.hulls, strict=True):
                with atomic_path(p, overwrite=True) as tmp:
                    if ext == ".stl":
                        h.to_trimesh().export(tmp, file_type="stl")
                    else:
                        tmp.write_text(obj_text([(h.vertices, h.faces)]))
            return paths
        if suffix != ".obj":
            raise OutputError(f"{target}: unsupported output format {suffix!r} (use .obj, or a "
                              "directory for one file per hull)")
        with atomic_path(target, overwrite=overwrite) as tmp:
            tmp.write_text(obj_text([(h.vertices, h.faces) for h in self.hulls]))
        return [target]


def obj_text(hulls) -> str:
    """Wavefront OBJ text with one ``o hull_NNN`` object per hull (1-based global indices).

    ``hulls``: a sequence of ((v, 3) float vertices, (f, 3) int faces) pairs.
    """
    lines = ["# pointcvx convex decomposition", f"# hulls {len(hulls)}"]
    offset = 1
    for i, (vertices, faces) in enumerate(hulls):
        lines.append(f"o hull_{i:03d}")
        lines.extend(f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertices)
        lines.extend(f"f {a + offset} {b + offset} {c + offset}" for a, b, c in faces)
        offset += len(vertices)
    return "\n".join(lines) + "\n"
