"""The oriented point cloud: the one type every loader produces and every later stage consumes.

Plain data: it imports no loader (:mod:`pointcvx.io` builds clouds from files, arrays, trimesh
and open3d geometry; :func:`pointcvx.io.save_cloud` writes one).

Coordinates are float64 numpy arrays. A cloud remembers the similarity transform that took the
input's units to its current coordinates (:class:`Normalization`), so results computed in the
normalised frame ([-1, 1]^3, as the benchmark judges shapes) can be mapped back to the input's
units exactly.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import InputError, first_line

MODALITIES = ("mesh", "cad", "splat", "scan", "points")


@dataclass(frozen=True)
class Normalization:
    """Similarity transform ``y = (x - center) / scale`` from input units ``x`` to cloud coords ``y``.

    Attributes
    ----------
    center : (3,) float
        Point of the input frame that maps to the origin.
    scale : float
        Input length that maps to 1 (half the longest bounding-box side for [-1, 1]^3).
    """

    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scale: float = 1.0

    @classmethod
    def identity(cls) -> Normalization:
        return cls(np.zeros(3), 1.0)

    @classmethod
    def to_unit_cube(cls, points: np.ndarray) -> Normalization:
        """The transform putting the bounding box of ``points`` (n, 3) in [-1, 1]^3.

        The box centre goes to the origin and half its longest side to 1 (CoACD's convention).
        """
        points = np.asarray(points, dtype=np.float64)
        lo, hi = points.min(axis=0), points.max(axis=0)
        half = float((hi - lo).max()) / 2.0
        if not np.isfinite(half) or half <= 0.0:
            raise InputError("all points are identical: the shape has no extent")
        return cls((lo + hi) / 2.0, half)

    @property
    def is_identity(self) -> bool:
        return bool(np.all(self.center == 0.0) and self.scale == 1.0)

    def forward(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) input units -> (n, 3) cloud coordinates."""
        return (np.asarray(points, dtype=np.float64) - self.center) / self.scale

    def inverse(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) cloud coordinates -> (n, 3) input units."""
        return np.asarray(points, dtype=np.float64) * self.scale + self.center

    def then(self, other: Normalization) -> Normalization:
        """The composition: apply ``self`` first, then ``other``."""
        return Normalization(self.center + self.scale * other.center, self.scale * other.scale)

    def as_matrix(self) -> np.ndarray:
        """(4, 4) float homogeneous matrix of :meth:`forward`."""
        m = np.eye(4)
        m[:3, :3] /= self.scale
        m[:3, 3] = -self.center / self.scale
        return m


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


#: Largest coordinate magnitude accepted (any unit). Beyond it float64 cannot hold the detail of a
#: real shape anyway, squared distances head for overflow, and trimesh's vertex-merge grid (1e-8
#: steps counted in int64) overflows near 9e10.
MAX_COORDINATE = 1e10


def check_points(points: Any, what: str = "points", allow_empty: bool = False) -> np.ndarray:
    """Validate and return ``points`` as (n, 3) float64; raise :class:`InputError` otherwise.

    Real numbers only (integer or float arrays: not bool, complex, object or strings), finite and
    within :data:`MAX_COORDINATE` of the origin.
    """
    try:
        arr = np.asarray(points)
    except (TypeError, ValueError) as exc:  # ragged nested lists
        raise InputError(f"{what} are not an (n, 3) array of numbers: {first_line(exc)}") from None
    if arr.dtype.kind not in "iuf":
        kind = {"b": "bool", "c": "complex", "O": "object", "U": "string", "S": "bytes"}.get(
            arr.dtype.kind, str(arr.dtype))
        raise InputError(f"{what} must be real numbers (an (n, 3) float array), got a {kind} array")
    pts = arr.astype(np.float64, copy=False)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"{what} must have shape (n, 3), got {pts.shape}")
    if len(pts) == 0 and not allow_empty:
        raise InputError(f"no {what}: the input is empty")
    if len(pts) == 0 or np.abs(pts).max() <= MAX_COORDINATE:  # one pass: NaN compares False
        return pts
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        raise InputError(f"{int(bad.sum())} of {len(pts)} {what} have NaN or infinite coordinates")
    far = np.abs(pts).max(axis=1) > MAX_COORDINATE
    raise InputError(f"{int(far.sum())} of {len(pts)} {what} lie beyond {MAX_COORDINATE:g} from the "
                     f"origin, more than pointcvx handles in any unit: rescale the input")


def check_extent(points: np.ndarray) -> None:
    """Raise :class:`InputError` when (n, 3) ``points`` are all identical, collinear or too few.

    Coplanar input (a flat sheet) is allowed: it is a valid, if thin, shape.
    """
    if len(points) < 4:
        raise InputError(f"only {len(points)} points: at least 4 are needed for a 3D shape")
    span = points.max(axis=0) - points.min(axis=0)
    size = float(span.max())
    if size <= 0.0:
        raise InputError("all points are identical: the shape has no extent")
    centered = (points - points.mean(axis=0)) / size
    sv = np.linalg.svd(centered[:: max(1, len(points) // 100000)], compute_uv=False)
    if sv[1] <= 1e-9 * max(sv[0], 1e-300) * np.sqrt(len(centered)):
        raise InputError("all points are collinear: the shape has no area")


@dataclass(eq=False)
class OrientedCloud:
    """Surface points with unit outward normals, plus what is known about where they came from.

    Attributes
    ----------
    points : (n, 3) float64
        Surface samples, in cloud coordinates (see ``normalization``).
    normals : (n, 3) float64
        Unit normals pointing out of the solid.
    colors : (n, 3) float32 in [0, 1], optional
    weights : (n,) float64, optional
        Per-point importance (splats: opacity x size; otherwise None).
    modality : str
        One of ``mesh``, ``cad``, ``splat``, ``scan``, ``points``.
    normalization : Normalization
        Transform from the input's units to ``points``; ``normalization.inverse`` maps back.
    mesh : trimesh.Trimesh, optional
        For mesh and CAD inputs: the mesh, in the same coordinates as ``points``.
    face_index : (n,) int64, optional
        For mesh inputs: the face of ``mesh`` each point was sampled on.
    info : dict
        Provenance for people: source path, format, counts, how normals were obtained, what was
        filtered. Plain JSON-able values.
    removed : (m, 3) float64, optional
        Points that isolation removed (support plane, clutter; :mod:`pointcvx.scene`), in the
        same coordinates as ``points``: not part of the shape, kept for pictures.
    """

    points: np.ndarray
    normals: np.ndarray
    colors: np.ndarray | None = None
    weights: np.ndarray | None = None
    modality: str = "points"
    normalization: Normalization = field(default_factory=Normalization.identity)
    mesh: Any = None
    face_index: np.ndarray | None = None
    info: dict = field(default_factory=dict)
    removed: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.points = check_points(self.points)
        n = len(self.points)
        normals = np.asarray(self.normals, dtype=np.float64)
        if normals.shape != (n, 3):
            raise InputError(f"normals must have shape ({n}, 3), got {normals.shape}")
        if not np.isfinite(normals).all():
            raise InputError("normals contain NaN or infinite values")
        lengths = np.linalg.norm(normals, axis=1)
        if (lengths <= 1e-12).any():
            raise InputError(f"{int((lengths <= 1e-12).sum())} normals have zero length")
        self.normals = normals / lengths[:, None]
        if self.colors is not None:
            self.colors = np.asarray(self.colors, dtype=np.float32)
            if self.colors.shape != (n, 3):
                raise InputError(f"colors must have shape ({n}, 3), got {self.colors.shape}")
        if self.weights is not None:
            self.weights = np.asarray(self.weights, dtype=np.float64)
            if self.weights.shape != (n,):
                raise InputError(f"weights must have shape ({n},), got {self.weights.shape}")
        if self.face_index is not None:
            self.face_index = np.asarray(self.face_index, dtype=np.int64)
            if self.face_index.shape != (n,):
                raise InputError(f"face_index must have shape ({n},)")
        if self.modality not in MODALITIES:
            raise InputError(f"unknown modality {self.modality!r}; expected one of {MODALITIES}")

    def __len__(self) -> int:
        return len(self.points)

    def __repr__(self) -> str:
        lo, hi = self.bounds
        return (
            f"OrientedCloud({len(self)} points, modality={self.modality!r}, "
            f"bounds={np.round(lo, 4).tolist()}..{np.round(hi, 4).tolist()}, "
            f"mesh={'yes' if self.mesh is not None else 'no'})"
        )

    # ------------------------------------------------------------------ geometry helpers
    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """((3,), (3,)) float: the axis-aligned bounding box of ``points``."""
        return self.points.min(axis=0), self.points.max(axis=0)

    def replace(self, **changes: Any) -> OrientedCloud:
        """A copy with some fields replaced (arrays are shared, not copied)."""
        changes.setdefault("info", dict(self.info))
        return dataclasses.replace(self, **changes)

    def subset(self, index: np.ndarray) -> OrientedCloud:
        """The cloud restricted to ``index`` ((m,) int or (n,) bool)."""
        idx = np.asarray(index)

        def take(a):
            return None if a is None else a[idx]

        return self.replace(
            points=self.points[idx],
            normals=self.normals[idx],
            colors=take(self.colors),
            weights=take(self.weights),
            face_index=take(self.face_index),
        )

    def transformed(self, t: Normalization) -> OrientedCloud:
        """Apply ``t`` to the points (and mesh); the result remembers the composed transform."""
        mesh = None
        if self.mesh is not None:
            mesh = self.mesh.copy()
            mesh.apply_transform(t.as_matrix())
        removed = None if self.removed is None else t.forward(self.removed)
        return self.replace(
            points=t.forward(self.points), mesh=mesh, normalization=self.normalization.then(t),
            removed=removed,
        )

    def normalized(self) -> OrientedCloud:
        """The cloud scaled into [-1, 1]^3: the bounding box of the mesh (when there is one) or of
        the points gets its centre at 0 and half its longest side at 1."""
        ref = self.points if self.mesh is None else np.asarray(self.mesh.vertices)
        return self.transformed(Normalization.to_unit_cube(ref))

    def in_input_units(self) -> OrientedCloud:
        """The cloud mapped back to the input's original units."""
        n = self.normalization
        back = Normalization(-n.center / n.scale, 1.0 / n.scale)
        out = self.transformed(back)
        out.normalization = Normalization.identity()
        return out

    def resample(self, n_points: int, seed: int = 0) -> OrientedCloud:
        """At most ``n_points`` points, chosen deterministically from ``seed``.

        Fewer points: a seeded random subset (sorted, so order follows the input). More points
        than the cloud has: the cloud is returned unchanged (no duplicates are invented).
        """
        if n_points <= 0:
            raise InputError(f"the point count must be positive, got {n_points}")
        if n_points >= len(self):
            return self
        rng = np.random.default_rng(seed)
        idx = np.sort(rng.choice(len(self), size=n_points, replace=False))
        out = self.subset(idx)
        out.info["resampled_from"] = len(self)
        return out

    # ------------------------------------------------------------------ conversions
    def to_open3d(self) -> Any:
        """An ``open3d.geometry.PointCloud`` with points, normals and colours."""
        from .syslibs import import_open3d
        o3d = import_open3d()

        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self.points))
        pc.normals = o3d.utility.Vector3dVector(self.normals)
        if self.colors is not None:
            pc.colors = o3d.utility.Vector3dVector(self.colors.astype(np.float64))
        return pc

    def to_trimesh(self) -> Any:
        """A ``trimesh.PointCloud`` (normals kept in ``metadata['normals']``)."""
        import trimesh

        colors = None
        if self.colors is not None:
            colors = np.clip(np.round(self.colors * 255), 0, 255).astype(np.uint8)
        pc = trimesh.PointCloud(self.points.copy(), colors=colors)
        pc.metadata["normals"] = self.normals.copy()
        return pc

    def to_open3d_mesh(self) -> Any:
        """The kept mesh as an ``open3d.geometry.TriangleMesh`` (mesh and CAD inputs only)."""
        if self.mesh is None:
            raise InputError(f"this {self.modality} cloud has no mesh")
        from .syslibs import import_open3d
        o3d = import_open3d()

        m = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(np.asarray(self.mesh.vertices, dtype=np.float64)),
            o3d.utility.Vector3iVector(np.asarray(self.mesh.faces, dtype=np.int32)),
        )
        m.compute_vertex_normals()
        return m
