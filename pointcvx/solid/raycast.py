"""A solid: the inside of a closed triangle surface, queried with Embree ray casting.

Every stage that needs an inside (convex pairs, the volume term of concavity, metrics) goes through
:class:`Solid`. Meshes give one directly or through watertight conversion (:mod:`pointcvx.solid.mesh`),
point clouds (splats, scans) through a reconstructed proxy surface (:mod:`pointcvx.solid.cloud`), so
every modality works the same way.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..embree import raycasting_scene

#: (3, 3) float: three fixed, non-axis-aligned unit directions for the inside vote of
#: :meth:`Solid.contains` (axis-aligned rays graze CAD faces).
VOTE_DIRECTIONS = np.array(
    [[0.5773, 0.5774, 0.5774], [-0.7071, 0.1, 0.7], [0.12, -0.98, 0.157]], dtype=np.float64
)
VOTE_DIRECTIONS /= np.linalg.norm(VOTE_DIRECTIONS, axis=1, keepdims=True)


@dataclass(eq=False)
class Solid:
    """The region enclosed by a closed triangle mesh.

    Attributes
    ----------
    vertices : (v, 3) float64
    faces : (f, 3) int64, wound outward.
    """

    vertices: np.ndarray
    faces: np.ndarray
    _scene: object = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int64)

    @classmethod
    def from_trimesh(cls, mesh) -> Solid:
        """Wrap a closed ``trimesh.Trimesh`` (close one with :func:`pointcvx.solid.watertight_mesh` first)."""
        return cls(np.asarray(mesh.vertices), np.asarray(mesh.faces))

    def to_trimesh(self):
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)

    @property
    def scene(self):
        """The open3d RaycastingScene over the triangles (built once, lazily)."""
        if self._scene is None:
            self._scene = raycasting_scene(self.vertices, self.faces)
        return self._scene

    def __getstate__(self):  # RaycastingScene does not pickle; rebuild it where it is needed
        state = self.__dict__.copy()
        state["_scene"] = None
        return state

    @property
    def volume(self) -> float:
        """Enclosed volume (divergence theorem over the outward-wound triangles)."""
        tri = self.vertices[self.faces]
        return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def _rays(self, origins: np.ndarray, dirs: np.ndarray):
        from ..syslibs import import_open3d
        o3d = import_open3d()

        rays = np.empty((len(origins), 6), np.float32)  # straight to float32: no float64 copy
        rays[:, :3] = origins
        rays[:, 3:] = dirs
        return o3d.core.Tensor(rays)

    def contains(self, points: np.ndarray, chunk: int = 1 << 20) -> np.ndarray:
        """(n,) bool: inside by ray parity, majority of three directions (robust to grazing rays).

        The third ray is cast only where the first two disagree.
        """
        points = np.asarray(points, dtype=np.float64)
        out = np.empty(len(points), dtype=bool)
        for s in range(0, len(points), chunk):
            p = points[s : s + chunk]
            a, b = (self._odd_hits(p, d) for d in VOTE_DIRECTIONS[:2])
            inside = a & b
            split = np.flatnonzero(a != b)
            if len(split):
                inside[split] = self._odd_hits(p[split], VOTE_DIRECTIONS[2])
            out[s : s + chunk] = inside
        return out

    def _odd_hits(self, points: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """(n,) bool: whether a ray from each of (n, 3) ``points`` along ``direction`` crosses the
        surface an odd number of times."""
        hits = self.scene.count_intersections(self._rays(points, np.broadcast_to(direction, points.shape)))
        return hits.numpy() % 2 == 1

    def first_hit(self, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """(n,) float: distance along each unit direction to the first surface hit (inf if none)."""
        origins = np.asarray(origins, dtype=np.float64)
        dirs = np.asarray(dirs, dtype=np.float64)
        if len(origins) == 0:
            return np.zeros(0)
        ans = self.scene.cast_rays(self._rays(origins, dirs))
        return ans["t_hit"].numpy().astype(np.float64)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) float: unsigned distance to the surface."""
        from ..syslibs import import_open3d
        o3d = import_open3d()

        q = o3d.core.Tensor(np.asarray(points, dtype=np.float32))
        return self.scene.compute_distance(q).numpy().astype(np.float64)
