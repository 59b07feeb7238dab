"""Solid: the inside of every modality, as a closed triangle surface queried by ray casting.

- :mod:`.raycast`: :class:`Solid`, the closed surface and its inside/outside queries (Embree);
- :mod:`.mesh`: mesh -> solid, the mesh itself when already closed, else :func:`watertight_mesh`;
- :mod:`.cloud`: cloud -> solid, a proxy surface reconstructed from oriented points (splats,
  scans);
- :mod:`.grid`: the voxel grid kit both share (dilations, flood fill, marching cubes);
- :mod:`.route`: :func:`solid_for`, the route per :class:`~pointcvx.cloud.OrientedCloud`.

All of it is deterministic: the same input gives the same solid.
"""

from ..embree import raycasting_scene
from .cloud import (
    CLOUD_CLOSING,
    LEAK_SHARE,
    WINDING_SURE,
    dipole_cells,
    solid_from_cloud,
    surface_from_cloud,
    winding_number,
)
from .mesh import CLOSE_HOLES, SHEET_LEVEL_VOXELS, closed_mesh_solid, watertight_mesh
from .raycast import VOTE_DIRECTIONS, Solid
from .route import solid_for

__all__ = [
    "CLOSE_HOLES",
    "CLOUD_CLOSING",
    "LEAK_SHARE",
    "SHEET_LEVEL_VOXELS",
    "VOTE_DIRECTIONS",
    "WINDING_SURE",
    "Solid",
    "closed_mesh_solid",
    "dipole_cells",
    "raycasting_scene",
    "solid_for",
    "solid_from_cloud",
    "surface_from_cloud",
    "watertight_mesh",
    "winding_number",
]
