"""Every loading option in one place, with the defaults the loaders use.

The CLI maps its flags onto these fields, and ``pointcvx.load(path, **fields)`` accepts them as
keyword arguments.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from ..errors import InputError


@dataclass(frozen=True)
class LoadOptions:
    """Options of :func:`pointcvx.io.load`.

    Common
        n_points: cap on the output point count (meshes and CAD: how many surface samples);
            None keeps every point of point inputs and samples ``mesh_points`` on meshes.
        seed: seed of every random choice (same seed, same cloud).
        normalize: put the cloud in [-1, 1]^3 (the transform is kept on the cloud).
    Meshes and CAD
        mesh_points: surface samples drawn when ``n_points`` is None.
        orient_rays: rays per offset point for the outward test of mesh faces.
    Splats
        min_opacity: drop Gaussians whose decoded opacity (sigmoid) is below this.
        floater_ratio: drop connected clusters of Gaussians holding less than this share of the
            total (0 disables).
        samples_per_gaussian: points drawn per Gaussian from its ellipsoid (1: the centre only).
    Scans (and splat centres)
        outlier_neighbors, outlier_std: statistical outlier removal (0 neighbours disables).
        voxel_size: voxel down-sampling in input units (None disables).
        normal_neighbors: neighbours used to estimate normals.
    CAD
        cad_mesh_size: target element size relative to the part's diagonal.
    """

    n_points: int | None = None
    seed: int = 0
    normalize: bool = True
    mesh_points: int = 20000
    orient_rays: int = 8
    min_opacity: float = 0.1
    floater_ratio: float = 0.01
    samples_per_gaussian: int = 1
    outlier_neighbors: int = 20
    outlier_std: float = 2.5
    voxel_size: float | None = None
    normal_neighbors: int = 24
    cad_mesh_size: float = 0.01

    def __post_init__(self) -> None:
        if self.n_points is not None and self.n_points < 4:
            raise InputError(f"n_points must be at least 4, got {self.n_points}")
        if self.mesh_points < 4:
            raise InputError(f"mesh_points must be at least 4, got {self.mesh_points}")
        if not 0.0 <= self.min_opacity < 1.0:
            raise InputError(f"min_opacity must be in [0, 1), got {self.min_opacity}")
        if not 0.0 <= self.floater_ratio < 0.5:
            raise InputError(f"floater_ratio must be in [0, 0.5), got {self.floater_ratio}")
        if self.samples_per_gaussian < 1:
            raise InputError("samples_per_gaussian must be at least 1")
        if self.voxel_size is not None and not self.voxel_size > 0:
            raise InputError(f"voxel_size must be positive, got {self.voxel_size}")
        if self.normal_neighbors < 3:
            raise InputError("normal_neighbors must be at least 3")
        if not 0.0 < self.cad_mesh_size <= 1.0:
            raise InputError("cad_mesh_size must be in (0, 1]")

    @classmethod
    def from_kwargs(cls, **kwargs) -> LoadOptions:
        """Build from keyword arguments, rejecting unknown names with a clear message."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(kwargs) - names)
        if unknown:
            raise TypeError(f"unknown load option(s): {', '.join(unknown)}; known: {sorted(names)}")
        return cls(**kwargs)
