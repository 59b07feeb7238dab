"""Loaders: any supported file or in-memory geometry -> :class:`pointcvx.cloud.OrientedCloud`.

The format is sniffed from the content (:func:`detect`); each modality has its own module:
``mesh`` (OBJ, PLY, STL, OFF, GLB/GLTF), ``splat`` (INRIA PLY, compressed PLY, SPZ, .splat),
``scan`` (PLY points, PCD, XYZ/PTS, LAS) and ``cad`` (STEP, IGES through gmsh). Every loader
returns a cloud in the input's units; :func:`load` then checks it, normalises it to [-1, 1]^3
(keeping the transform) and caps the point count, all seeded. :mod:`.convert` builds clouds from
numpy, trimesh and open3d objects; :func:`save_cloud` writes one as a PLY.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from typing import Any

import numpy as np

from ..cloud import OrientedCloud, check_extent
from ..errors import InputError
from ..options import LoadOptions
from ..scene import isolate_cloud
from .convert import from_numpy, from_open3d, from_trimesh
from .sniff import Detected, detect

log = logging.getLogger(__name__)

__all__ = ["Detected", "LoadOptions", "as_cloud", "detect", "finalize", "from_numpy", "from_open3d",
           "from_trimesh", "load", "save_cloud"]


def _loader(modality: str):
    if modality == "mesh":
        from .mesh import load_mesh_file as fn
    elif modality == "splat":
        from .splat import load_splat_file as fn
    elif modality == "scan":
        from .scan import load_scan_file as fn
    elif modality == "cad":
        from .cad import load_cad_file as fn
    else:  # pragma: no cover - detect() only returns the four above
        raise ValueError(modality)
    return fn


def finalize(cloud: OrientedCloud, opts: LoadOptions) -> OrientedCloud:
    """Common post-processing: isolation of the object (splats and scans by default, once per
    cloud; :func:`pointcvx.scene.isolate_cloud`), degeneracy check, seeded point cap, [-1, 1]^3
    normalisation."""
    if "isolation" not in cloud.info:
        cloud = isolate_cloud(cloud, opts.isolate, opts.crop, seed=opts.seed,
                              close_bases=opts.close_bases == "on")
    check_extent(cloud.points)
    if opts.n_points is not None:
        cloud = cloud.resample(opts.n_points, seed=opts.seed)
    if opts.normalize:
        cloud = cloud.normalized()
    return cloud


#: A second read thins to this much more than the first read's isolation share asks for.
READ_AGAIN_MARGIN = 1.25


def _wider_budget(cloud: OrientedCloud, opts: LoadOptions) -> LoadOptions | None:
    """Options for a second read of a scan that was thinned to ``PRESAMPLE_FACTOR`` times the
    point budget before isolation and whose object(s) came out short of the budget (a room's
    depth frame is mostly floor and walls): thinned less, by the share isolation kept, so the
    object(s) get the whole budget (at most the whole input). None when the first read will do."""
    read = cloud.info.get("presampled_from")
    budget = opts.n_points
    if not read or budget is None or "isolation" not in cloud.info:
        return None
    kept = cloud.info["isolation"]["kept"]  # the read's own points (closed bases not counted)
    if kept >= budget:
        return None
    from .scan import PRESAMPLE_FACTOR

    share = kept / (PRESAMPLE_FACTOR * budget)  # of the thinned points, the object(s)'
    need = int(np.ceil(READ_AGAIN_MARGIN * budget / max(share, 1e-9) / PRESAMPLE_FACTOR))
    return dataclasses.replace(opts, n_points=min(need, int(np.ceil(read / PRESAMPLE_FACTOR))))


def load(path: str | os.PathLike, options: LoadOptions | None = None, **kwargs) -> OrientedCloud:
    """Load any supported file as an oriented cloud.

    Parameters
    ----------
    path : str or PathLike
    options : LoadOptions, optional
        All options at once; or pass them as keyword arguments (``n_points=20000, seed=1``).

    Returns
    -------
    OrientedCloud
        Normalised to [-1, 1]^3 unless ``normalize=False``; ``cloud.info`` says what was done.

    Raises
    ------
    pointcvx.InputError
        Missing, empty, truncated, corrupted, non-finite or degenerate input.
    pointcvx.UnknownFormatError
        Content that matches no supported format.
    pointcvx.MissingExtraError
        A format needing an optional extra that is not installed (STEP without ``[cad]``).
    """
    if options is not None and kwargs:
        raise TypeError("pass either options or keyword arguments, not both")
    opts = options if options is not None else LoadOptions.from_kwargs(**kwargs)
    if not isinstance(path, (str, bytes)) and not hasattr(path, "__fspath__"):
        raise InputError(f"load takes a file path, not a {type(path).__name__}; pass arrays, "
                         "trimesh or open3d objects to pointcvx.decompose (or pointcvx.pipeline.as_cloud)")
    t0 = time.perf_counter()
    try:
        # Hostile values (NaN, overflow) are what the loaders' checks are for: numpy's warnings
        # about them would only be noise on the user's terminal.
        with np.errstate(all="ignore"):
            found = detect(path)
            log.debug("%s: detected %s (%s)", path, found.format, found.modality)
            cloud = finalize(_loader(found.modality)(path, found.format, opts), opts)
            wider = _wider_budget(cloud, opts)
            if wider is not None:  # isolation left the object(s) short of the budget
                first = len(cloud)
                cloud = finalize(_loader(found.modality)(path, found.format, wider), opts)
                cloud.info["read_again"] = {"kept_first": first, "budget": wider.n_points}
    except InputError as exc:  # name the file in checks that only know the arrays
        if str(path) in str(exc):
            raise
        raise type(exc)(f"{path}: {exc}") from None
    cloud.info.setdefault("source", str(path))
    cloud.info["format"] = found.format
    cloud.info["points"] = len(cloud)
    cloud.info["load_seconds"] = round(time.perf_counter() - t0, 3)
    return cloud


def save_cloud(cloud: OrientedCloud, path: str | os.PathLike) -> None:
    """Write points, normals (and colours) of ``cloud`` as a binary PLY, atomically, in the
    cloud's coordinates (``cloud.in_input_units()`` for the input's)."""
    from .ply import write_cloud_ply

    write_cloud_ply(path, cloud.points, cloud.normals, cloud.colors)


def as_cloud(x: Any, options: LoadOptions | None = None, **kwargs: Any) -> OrientedCloud:
    """Turn a path, (n, 3) array, (points, normals) tuple, open3d geometry, trimesh or
    OrientedCloud into a cloud finished by the load options (checked, capped, normalised):
    ``options``, or the same as keyword arguments (``n_points=20000, seed=1``)."""
    if options is not None and kwargs:
        raise TypeError("pass either options or keyword arguments, not both")
    opts = options if options is not None else LoadOptions.from_kwargs(**kwargs)
    if isinstance(x, OrientedCloud):
        return finalize(x, opts)
    if isinstance(x, (str, bytes)) or hasattr(x, "__fspath__"):
        return load(os.fsdecode(x) if isinstance(x, bytes) else x, opts)
    n_mesh = opts.n_points or opts.mesh_points
    if isinstance(x, (np.ndarray, list)):
        return finalize(from_numpy(x), opts)
    if type(x).__module__.startswith("trimesh"):
        return finalize(from_trimesh(x, n_points=n_mesh, seed=opts.seed), opts)
    if type(x).__module__.startswith("open3d"):
        return finalize(from_open3d(x, n_points=n_mesh, seed=opts.seed), opts)
    if isinstance(x, tuple) and len(x) == 2:
        return finalize(from_numpy(x[0], x[1]), opts)
    raise InputError(f"cannot decompose a {type(x).__name__}: pass a path, an (n, 3) array, "
                     "(points, normals), an open3d geometry, a trimesh or an OrientedCloud")
