"""Gaussian splats (INRIA PLY, PlayCanvas compressed PLY, Niantic SPZ, antimatter15 .splat) -> clouds.

Each format has its codec module (:mod:`.inria`, :mod:`.compressed`, :mod:`.spz`,
:mod:`.dotsplat`); every decoder returns the plain dict of arrays described in :mod:`.gaussians`.
:func:`load_splat_file` turns it into an :class:`~pointcvx.cloud.OrientedCloud`: it drops
non-finite, nearly transparent and floating Gaussians and statistical outliers
(:mod:`.filters`, :mod:`pointcvx.io.outliers`); takes as normal the shortest axis of the local
Gaussian mixture (a trained splat flattens onto the surface it models, but single Gaussians are
often badly turned, so each is mixed with its neighbours, see :func:`mixture_normals`); makes the
normals consistent and outward (sign propagation, then votes of the directions each point is seen
from, see :func:`orient_by_visibility`); and optionally draws several surface samples per Gaussian.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from ...cloud import MAX_COORDINATE, OrientedCloud
from ...errors import InputError
from ...options import LoadOptions
from ..orient import knn, orient_normals
from ..outliers import outlier_mask
from .compressed import CHUNK_SIZE, decode_compressed_ply, read_compressed_ply
from .dotsplat import decode_dot_splat, read_dot_splat, write_dot_splat
from .filters import (
    MAX_SCALE_RATIO,
    finite_mask,
    floater_mask,
    gaussian_weights,
    opacity_mask,
    range_mask,
    scale_mask,
)
from .gaussians import (
    SH_C0,
    gaussian_normals,
    matrix_quaternion,
    mixture_normals,
    normalize_quaternions,
    quaternion_matrices,
    quaternion_product,
    sample_gaussians,
)
from .inria import decode_inria_ply, read_inria_ply, write_inria_ply
from .spz import (
    MAX_SPZ_POINTS,
    SPZ_COLOR_SCALE,
    SPZ_COORDINATE_EXTENSION,
    axes_change,
    decode_spz,
    read_spz,
    to_ply_axes,
    write_spz,
)
from .visibility import (
    ORIENT_NEIGHBORS,
    VISIBILITY_VIEWS,
    first_layer,
    orient_by_visibility,
    view_directions,
    visibility_votes,
)

log = logging.getLogger(__name__)

__all__ = [
    "CHUNK_SIZE", "MAX_SPZ_POINTS", "MIXTURE_NEIGHBORS", "NORMALS_NOTE", "ORIENT_NEIGHBORS", "SH_C0",
    "SPZ_COLOR_SCALE", "SPZ_COORDINATE_EXTENSION", "VISIBILITY_VIEWS", "WORK_FACTOR", "WORK_MIN",
    "axes_change", "decode_compressed_ply", "decode_dot_splat", "decode_inria_ply", "decode_splat",
    "decode_spz", "finite_mask", "first_layer", "floater_mask", "gaussian_normals", "gaussian_weights",
    "load_splat_file", "matrix_quaternion", "mixture_normals", "normalize_quaternions", "opacity_mask",
    "orient_by_visibility", "quaternion_matrices", "quaternion_product", "range_mask", "read_compressed_ply",
    "read_dot_splat", "read_inria_ply", "read_spz", "sample_gaussians", "to_ply_axes", "view_directions",
    "scale_mask", "visibility_votes", "working_budget", "write_dot_splat", "write_inria_ply", "write_spz",
]

#: Neighbours mixed with each Gaussian to find its normal (0: its own shortest axis only).
MIXTURE_NEIGHBORS = 16
# With a point budget (n_points) and one point per Gaussian, at most this many Gaussians times the
# budget (and at least WORK_MIN) go through filtering and normal estimation: the cloud is a
# uniform subset of them anyway, and normals from a uniform subset are as good.
WORK_FACTOR = 10
WORK_MIN = 200_000
NORMALS_NOTE = (f"smallest axis of the local Gaussian mixture (each Gaussian + {MIXTURE_NEIGHBORS} "
                "neighbours), oriented (MST propagation + hull vote, then visibility votes from "
                f"{VISIBILITY_VIEWS} directions)")


def _subset(g: dict[str, np.ndarray], keep: np.ndarray) -> dict[str, np.ndarray]:
    """The Gaussians of decoder dict ``g`` selected by ``keep``, an (n,) bool mask or (m,) int indices."""
    return {k: v[keep] for k, v in g.items()}


_DECODERS = {
    "ply-splat": decode_inria_ply,
    "ply-splat-compressed": decode_compressed_ply,
    "spz": decode_spz,
    "splat": decode_dot_splat,
}


def decode_splat(path: str | os.PathLike, fmt: str) -> tuple[dict[str, np.ndarray], dict]:
    """Decode ``path`` of format ``fmt`` (``ply-splat``, ``ply-splat-compressed``, ``spz``,
    ``splat``); returns the decoder dict and ``{"format_detail": str, "sh_degree": int}``."""
    try:
        decoder = _DECODERS[fmt]
    except KeyError:
        raise InputError(f"{path}: {fmt!r} is not a splat format; known: {sorted(_DECODERS)}") from None
    return decoder(path)


def working_budget(opts: LoadOptions) -> int | None:
    """How many Gaussians a load with ``opts`` needs at most (None: all of them).

    With a point budget ``n_points``, one point per Gaussian and no voxel grid, the output is a
    uniform random subset of the Gaussians, so a uniform subset of ``max(WORK_FACTOR * n_points,
    WORK_MIN)`` of them carries the same information: loading a 1M-Gaussian splat then costs what
    a 200k one does.
    """
    if opts.n_points is None or opts.samples_per_gaussian > 1 or opts.voxel_size is not None:
        return None
    return max(WORK_FACTOR * int(opts.n_points), WORK_MIN)


def load_splat_file(path: str | os.PathLike, fmt: str, opts: LoadOptions) -> OrientedCloud:
    """Load a splat file as an oriented cloud of Gaussian centres (or samples), in input units.

    Steps, each counted in ``cloud.info``: drop non-finite Gaussians, those centred beyond
    :data:`~pointcvx.cloud.MAX_COORDINATE` (``dropped_out_of_range``), those larger than the
    whole splat (:func:`scale_mask`, ``dropped_huge_scales``, with a warning: a log-scale of 80
    is a trained splat's corruption, not a surface), those with opacity below
    ``opts.min_opacity``; keep a uniform subset of at most :func:`working_budget` of the rest
    (``gaussians_used``); drop floater clusters holding less than ``opts.floater_ratio`` of the rest
    (:func:`floater_mask`) and statistical outliers (``opts.outlier_neighbors``,
    ``opts.outlier_std``, :func:`pointcvx.io.outliers.outlier_mask`). Normals:
    :func:`mixture_normals` of each Gaussian and its ``MIXTURE_NEIGHBORS`` nearest, signed by
    :func:`pointcvx.io.orient.orient_normals` and corrected by :func:`orient_by_visibility`;
    normals stored in the file (INRIA writes zeros) are not used. With
    ``opts.samples_per_gaussian > 1`` each Gaussian adds tangent-plane samples
    (:func:`sample_gaussians`). With ``opts.voxel_size`` one point per voxel is kept, the heaviest.

    ``weights`` are the Gaussian's opacity x geometric mean scale (:func:`gaussian_weights`),
    split evenly among the points drawn from it. ``colors`` are the SH DC colours.

    Raises :class:`InputError` for truncated or corrupted files and when no Gaussian survives
    the filters.
    """
    p = Path(path)
    g, meta = decode_splat(p, fmt)
    total = len(g["centers"])
    if total == 0:
        raise InputError(f"{p}: the splat holds no Gaussians")
    info: dict = {"format_detail": meta["format_detail"], "gaussians": total,
                  "sh_degree": int(meta["sh_degree"])}

    ok = finite_mask(g)
    info["dropped_nonfinite"] = int((~ok).sum())
    g = _subset(g, ok)
    ok = range_mask(g)
    if not ok.all():
        info["dropped_out_of_range"] = int((~ok).sum())
        g = _subset(g, ok)
    ok = scale_mask(g)
    if not ok.all():
        info["dropped_huge_scales"] = int((~ok).sum())  # warned about once the load succeeds
        g = _subset(g, ok)
    ok = opacity_mask(g, opts.min_opacity)
    info["dropped_low_opacity"] = int((~ok).sum())
    g = _subset(g, ok)
    if len(g["centers"]) == 0:
        raise InputError(
            f"{p}: no Gaussian is left after filtering: all {total} are non-finite, beyond "
            f"{MAX_COORDINATE:g}, larger than the splat, or have opacity below "
            f"min_opacity={opts.min_opacity}"
        )
    budget = working_budget(opts)
    if budget is not None and len(g["centers"]) > budget:
        keep = np.sort(np.random.default_rng(opts.seed).choice(len(g["centers"]), budget, replace=False))
        info["gaussians_used"] = budget
        g = _subset(g, keep)
    ok = floater_mask(g["centers"], opts.floater_ratio)
    info["dropped_floaters"] = int((~ok).sum())
    g = _subset(g, ok)
    ok = ~outlier_mask(g["centers"], opts.outlier_neighbors, opts.outlier_std)
    info["dropped_outliers"] = int((~ok).sum())
    g = _subset(g, ok)
    n = len(g["centers"])
    if n < 4:
        raise InputError(f"{p}: only {n} of {total} Gaussians are left after filtering")

    axes = gaussian_normals(g["scales"], g["rotations"])
    near = knn(g["centers"], max(MIXTURE_NEIGHBORS, ORIENT_NEIGHBORS, 4))
    raw = mixture_normals(g["centers"], g["scales"], g["rotations"], g["opacity"], MIXTURE_NEIGHBORS,
                          neighbors=near[1])
    normals, _ = orient_normals(g["centers"], raw, k=ORIENT_NEIGHBORS)
    normals, changed = orient_by_visibility(g["centers"], normals, neighbors=near)
    info["normals_changed_by_visibility"] = changed
    flipped = int((np.einsum("ij,ij->i", normals, raw) < 0).sum())
    info["normals"] = NORMALS_NOTE
    info["normals_flipped"] = flipped
    info["normals_along_own_axis"] = round(float((np.abs((axes * normals).sum(axis=1)) > 0.9).mean()), 4)

    weights = gaussian_weights(g)
    points, normals, source = sample_gaussians(g, normals, opts.samples_per_gaussian, opts.seed)
    per_source = np.bincount(source, minlength=n)
    weights = weights[source] / per_source[source]
    colors = g["colors"][source]
    if opts.samples_per_gaussian > 1:
        info["samples_per_gaussian"] = int(opts.samples_per_gaussian)
    if opts.voxel_size is not None:
        keys = np.floor(points / opts.voxel_size).astype(np.int64)
        order = np.lexsort((-weights,) + tuple(keys.T[::-1]))
        _, first = np.unique(keys[order], axis=0, return_index=True)
        keep = np.sort(order[first])
        info["dropped_voxel"] = int(len(points) - len(keep))
        points, normals, colors, weights = points[keep], normals[keep], colors[keep], weights[keep]
    for warning in meta.get("warnings", ()):
        log.warning("%s: %s", p, warning)
    if info.get("dropped_huge_scales"):
        log.warning("%s: dropped %d Gaussians larger than the whole splat (scale above %g x the "
                    "diagonal of its centres)", p, info["dropped_huge_scales"], MAX_SCALE_RATIO)
    log.debug("%s: %d Gaussians -> %d points (%s)", p, total, len(points), info)
    return OrientedCloud(points, normals, colors=colors, weights=weights, modality="splat", info=info)
