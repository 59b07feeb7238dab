"""The route from an :class:`~pointcvx.cloud.OrientedCloud` to its solid, with a small cache of the
last results so that the stages asking for the same cloud's solid share one."""

from __future__ import annotations

import hashlib
import logging
from collections import OrderedDict
from typing import Any

import numpy as np

from .cloud import solid_from_cloud
from .mesh import closed_mesh_solid, watertight_mesh
from .raycast import Solid

log = logging.getLogger(__name__)

#: The last few solids, oldest first, keyed by :func:`_digest` of their input and resolution.
_CACHE: OrderedDict[str, Solid] = OrderedDict()
_CACHE_SIZE = 8


def _digest(*arrays: np.ndarray, extra: str = "") -> str:
    """Hex digest of ``extra`` and the dtype, shape and bytes of each of ``arrays``."""
    h = hashlib.blake2b(extra.encode(), digest_size=16)
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.data)
    return h.hexdigest()


def solid_for(cloud: Any, resolution: int | None = None, cache: bool = True) -> Solid:
    """The solid of an :class:`~pointcvx.cloud.OrientedCloud`, by the best route for its input.

    - mesh or CAD cloud whose mesh is already a valid closed surface (:func:`closed_mesh_solid`):
      the mesh itself, exact;
    - mesh or CAD cloud with an open or messy mesh: :func:`watertight_mesh` (default 128);
    - splats, scans, points: :func:`solid_from_cloud` (default resolution 96).

    Deterministic; with ``cache``, the last few results are kept, keyed by a digest of the
    arrays and the resolution, so stages asking for the same cloud's solid share one (do not
    modify the returned Solid's arrays).
    """
    mesh = getattr(cloud, "mesh", None)
    use_mesh = mesh is not None and getattr(cloud, "modality", "mesh") in ("mesh", "cad")
    if use_mesh:
        arrays = (np.asarray(mesh.vertices), np.asarray(mesh.faces))
    else:
        arrays = (np.asarray(cloud.points), np.asarray(cloud.normals))
    key = _digest(*arrays, extra=f"{use_mesh}:{resolution}") if cache else ""
    if cache and key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    solid = closed_mesh_solid(mesh) if use_mesh else None
    if solid is not None:
        route = "closed mesh"
    elif use_mesh:
        solid = Solid.from_trimesh(watertight_mesh(mesh, resolution or 128))
        route = "watertight_mesh"
    else:
        solid = solid_from_cloud(cloud.points, cloud.normals, resolution or 96)
        route = "solid_from_cloud"
    log.debug("solid_for: %s, %d faces, volume %.4g", route, len(solid.faces), solid.volume)
    if cache:
        _CACHE[key] = solid
        while len(_CACHE) > _CACHE_SIZE:
            _CACHE.popitem(last=False)
    return solid
