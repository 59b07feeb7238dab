"""The keyword arguments each method's worker run receives: the baselines' fixed settings, the
ranges their matched-granularity search covers, and pointcvx's settings."""

from __future__ import annotations

from .options import BenchOptions

COACD_THRESHOLD = 0.1
"""CoACD's fixed setting (the paper's)."""
COACD_RANGE = (0.01, 1.0)
"""Interval of CoACD's ``threshold`` in the matched search (centred on the fixed setting)."""
VHACD_RESOLUTION = 1_000_000
"""V-HACD 2.x voxel resolution (the paper's)."""
VHACD_CONCAVITY = 0.001  # pybullet.vhacd's default
"""V-HACD 2.x fixed concavity."""
VHACD_RANGE = (1e-5, 0.1)
"""Interval of V-HACD's ``concavity`` in the matched search (centred on the fixed setting)."""
VHACDX_MAX_HULLS = 64  # vhacdx.compute_vhacd's defaults
"""vhacdx (V-HACD 4.x) fixed hull budget."""
VHACDX_RESOLUTION = 400_000
"""vhacdx voxel resolution."""

PARAM_NAMES = {"pointcvx": "threshold", "coacd": "threshold", "vhacd": "concavity",
               "vhacdx": "maxConvexHulls"}
"""The parameter each method's rows record (the ``param_name`` column)."""


def param_name(method: str) -> str:
    """The name of ``method``'s recorded parameter (see :data:`PARAM_NAMES`)."""
    return PARAM_NAMES[method]


def pointcvx_params(opts: BenchOptions, threshold: float) -> dict:
    """:func:`pointcvx.decompose` keyword arguments: every decomposition and loading option."""
    return {**opts.decompose.as_dict(), **opts.load.as_dict(), "threshold": float(threshold)}


def vhacd_params(opts: BenchOptions, concavity: float) -> dict:
    """``pybullet.vhacd`` keyword arguments."""
    res = opts.vhacd_resolution or VHACD_RESOLUTION
    return {"resolution": int(res), "concavity": float(concavity)}


def vhacdx_params(opts: BenchOptions, max_hulls: int) -> dict:
    """``vhacdx.compute_vhacd`` keyword arguments."""
    res = opts.vhacd_resolution or VHACDX_RESOLUTION
    return {"maxConvexHulls": int(max_hulls), "resolution": int(res)}


def coacd_params(opts: BenchOptions, threshold: float) -> dict:
    """``coacd.run_coacd`` keyword arguments (seeded with the benchmark's seed)."""
    return {"threshold": float(threshold), "seed": opts.seed}


def fixed_params(opts: BenchOptions, method: str) -> tuple[float, dict]:
    """(the recorded parameter, the keyword arguments) of a baseline's fixed setting."""
    if method == "coacd":
        return COACD_THRESHOLD, coacd_params(opts, COACD_THRESHOLD)
    if method == "vhacd":
        return VHACD_CONCAVITY, vhacd_params(opts, VHACD_CONCAVITY)
    return VHACDX_MAX_HULLS, vhacdx_params(opts, VHACDX_MAX_HULLS)
