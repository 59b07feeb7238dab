"""The single entry point: anything -> :class:`~pointcvx.result.Decomposition`.

load -> oriented cloud -> solid -> features -> recursive split (+ merge) -> hulls.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import math
import os
import pickle
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from .cloud import OrientedCloud
from .errors import InputError, PointcvxError
from .io import LoadOptions, finalize, load
from .result import ConvexHull, Decomposition

log = logging.getLogger(__name__)

FEATURE_METHODS = ("auto", "optimize", "model")
#: Modalities whose default feature source is the bundled model: where it measured on par with
#: per-shape optimisation (fewer hulls, each winning one of concavity and reconstruction by a
#: few per cent) in about half the time (splats, docs/model.md). Meshes, CAD parts and scans keep
#: per-shape optimisation until a model beats it there too.
MODEL_MODALITIES = ("splat",)

Progress = Callable[[str, int, int], None]
"""progress(stage, done, total): stage is "features" or "split"."""


def as_cloud(x: Any, *, n_points: int = 20000, seed: int = 0, **load_options: Any) -> OrientedCloud:
    """Turn a path, (n, 3) array, (points, normals) tuple, open3d geometry, trimesh or
    OrientedCloud into a normalised oriented cloud of at most ``n_points`` points."""
    opts = LoadOptions.from_kwargs(n_points=n_points, seed=seed, **load_options)
    if isinstance(x, OrientedCloud):
        return finalize(x, opts)
    if isinstance(x, (str, bytes)) or hasattr(x, "__fspath__"):
        return load(x, opts)
    if isinstance(x, (np.ndarray, list)):
        return finalize(OrientedCloud.from_arrays(np.asarray(x, dtype=np.float64)), opts)
    if type(x).__module__.startswith("trimesh"):
        return finalize(OrientedCloud.from_trimesh(x, n_points=opts.n_points or opts.mesh_points,
                                                   seed=seed), opts)
    if type(x).__module__.startswith("open3d"):
        return finalize(OrientedCloud.from_open3d(x, n_points=opts.n_points or opts.mesh_points,
                                                  seed=seed), opts)
    if isinstance(x, tuple) and len(x) == 2:
        return finalize(OrientedCloud.from_arrays(np.asarray(x[0], dtype=np.float64),
                                                  np.asarray(x[1], dtype=np.float64)), opts)
    raise InputError(f"cannot decompose a {type(x).__name__}: pass a path, an (n, 3) array, "
                     "(points, normals), an open3d geometry, a trimesh or an OrientedCloud")


# Per-shape optimisation sees one shape only: many anchors with fewer candidates each generalise
# better across its surface than the paper's 1024 x 1024 (measured on held-out pairs).
SINGLE_SHAPE_TRIPLETS = {"pool_size": 8192, "n_anchors": 4096, "n_candidates": 256,
                         "n_hard": 64, "n_uniform": 64}


BUNDLED_MODEL = Path(__file__).parent / "data" / "model_small.pt"


#: Suggested ``subsurface`` depth of :func:`decompose` for splats with a sub-surface layer
#: (a fraction of half the longest side of the bounds: 0.05 in the normalised frame, half the
#: default threshold).
SUBSURFACE_DEPTH = 0.05


def check_subsurface(depth: float | None) -> None:
    """Raise :class:`InputError` unless ``depth`` (``decompose(subsurface=...)``) is None or a
    positive finite number."""
    if depth is not None and not (depth > 0 and math.isfinite(depth)):
        raise InputError(f"subsurface depth must be positive, got {depth}")


def subsurface_points(points: np.ndarray, solid, depth: float = SUBSURFACE_DEPTH) -> np.ndarray:
    """(n,) bool: which of (n, 3) ``points`` lie deeper than ``depth`` inside ``solid``.

    A trained 3D Gaussian splat keeps Gaussians under its surface (the dev donut: about 1,800
    of its 20,000 working centres 0.05-0.1 below it). A part's hull contains them, but the
    concavity measure would read their distance to the hull's surface as concavity, so a part
    would have to split until a hull face passes near each of them (the donut: 44 hulls with
    the bundled model; 17 with them left out of the measure).

    The walls of a fold that the solid closed (cloud solids close folds up to about four voxels
    wide, ``watertight.CLOUD_CLOSING``) read as deep too: on 30 synthetic splats without a
    sub-surface layer, leaving them out of the measure put one more shape over the threshold
    (docs/decomposition.md). Hence :func:`decompose` does this only when asked.

    ``depth`` is a fraction of half the longest side of the points' bounds.
    """
    pts = np.asarray(points, dtype=np.float64)
    limit = depth * 0.5 * float(np.ptp(pts, axis=0).max())
    deep = solid.contains(pts)
    deep[deep] = solid.distance(pts[deep]) > limit
    return deep


def bundled_model_path() -> Path | None:
    """The model shipped inside the package, if this build has one."""
    return BUNDLED_MODEL if BUNDLED_MODEL.is_file() else None


@functools.lru_cache(maxsize=4)
def _cached_model(path: str, mtime_ns: int, size: int):
    """The network of checkpoint ``path``, loaded once per process (keyed by the file's mtime and
    size too, so a rewritten checkpoint is read again): decomposing many shapes in a loop does
    not reload it."""
    from .model.source import load_model

    return load_model(path)


def load_cached_model(model: str | os.PathLike | None = None):
    """The feed-forward network of checkpoint ``model`` (default: the bundled one), loaded once
    per process and reused by every later :func:`decompose` call (long-lived batch workers load it
    when they start).

    Raises
    ------
    PointcvxError
        No ``model`` given and this build ships none.
    InputError
        ``model`` is missing or not a pointcvx checkpoint.
    """
    path = Path(model) if model is not None else bundled_model_path()
    if path is None:
        raise PointcvxError("this build ships no feed-forward model yet: train one with "
                            "`pointcvx train` and pass --model PATH, or use --features optimize")
    if not path.is_file():
        raise InputError(f"{path}: no such model checkpoint")
    try:
        stat = path.stat()
        return _cached_model(str(path.resolve()), stat.st_mtime_ns, stat.st_size)
    except (KeyError, RuntimeError, ValueError, EOFError, pickle.UnpicklingError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"{path}: not a pointcvx model checkpoint ({first[:120]})") from None


#: Modules that :func:`decompose` imports lazily, the libraries among them (optional ones too).
LAZY_MODULES = (
    "open3d", "trimesh", "manifold3d", "scipy.ndimage", "scipy.sparse.csgraph", "scipy.spatial",
    "skimage.measure", "sklearn.cluster", "pointcvx.export", "pointcvx.io.mesh", "pointcvx.io.scan",
    "pointcvx.io.splat", "pointcvx.solid", "pointcvx.metrics", "pointcvx.recursive", "pointcvx.watertight",
)


def resolve_features(features: str, modality: str, model: str | os.PathLike | None = None) -> str:
    """The feature source that ``features`` means for a cloud of ``modality``: "optimize" and
    "model" are themselves; "auto" is the model for the modalities of :data:`MODEL_MODALITIES`
    (splats) when there is one (``model``, or the bundled one), per-shape optimisation otherwise."""
    if features not in FEATURE_METHODS:
        raise InputError(f"unknown feature method {features!r}; expected one of {FEATURE_METHODS}")
    if features != "auto":
        return features
    if modality in MODEL_MODALITIES and (model is not None or bundled_model_path() is not None):
        return "model"
    return "optimize"


def preload(features: str = "auto", model: str | os.PathLike | None = None) -> None:
    """Import what :func:`decompose` imports lazily (optional libraries that are not installed are
    skipped) and, for ``features="model"`` (or "auto" with a model available), load the network
    of ``model`` (default: the bundled one) into the per-process cache: what a long-running
    process (``pointcvx batch`` workers, ``pointcvx bench`` workers) does once before its first
    shape."""
    import importlib

    uses = {"optimize": ("pointcvx.features.field",), "model": ("pointcvx.model.source",),
            "auto": ("pointcvx.features.field", "pointcvx.model.source")}[features]
    for name in LAZY_MODULES + uses:
        with contextlib.suppress(ImportError):
            importlib.import_module(name)
    if features == "model" or (features == "auto" and (model is not None or bundled_model_path())):
        load_cached_model(model)


def compute_features(cloud: OrientedCloud, solid, *, method: str = "auto", seed: int = 0,
                     steps: int = 300, model: str | os.PathLike | None = None, views: int = 1,
                     progress: Progress | None = None):
    """Return (feature source, (n, k) float32 features of ``cloud.points``).

    ``method="model"`` runs the feed-forward network from ``model`` (a checkpoint written by
    ``pointcvx train``), or the bundled one; "auto" picks by the cloud's modality
    (:func:`resolve_features`).
    """
    method = resolve_features(method, cloud.modality, model)
    if method == "model":
        from .model.source import ModelFeatureSource

        net = load_cached_model(model)
        source = ModelFeatureSource(net, cloud.points, cloud.normals, views=views)
        return source, source.features(cloud.points)
    from .features import sample_triplets
    from .features.field import optimize_field

    triplets = sample_triplets(solid, cloud.points, cloud.normals, seed=seed, **SINGLE_SHAPE_TRIPLETS)
    report = None if progress is None else (lambda step, loss: progress("features", step + 1, steps))
    source = optimize_field(triplets, steps=steps, seed=seed, progress=report)
    return source, source.features(cloud.points)


def decompose(
    x: Any,
    *,
    threshold: float = 0.1,
    max_hulls: int = 64,
    features: str = "auto",
    model: str | os.PathLike | None = None,
    views: int = 1,
    merge: bool = True,
    split: str = "auto",
    blend: float = 1.0,
    n_points: int = 20000,
    seed: int = 0,
    target: str | None = None,
    max_hull_vertices: int | None = None,
    subsurface: float | None = None,
    progress: Progress | None = None,
    **load_options: Any,
) -> Decomposition:
    """Split a shape into convex hulls.

    Parameters
    ----------
    x : path, (n, 3) array, (points, normals), open3d geometry, trimesh or OrientedCloud
        The shape: a mesh, a CAD part, a splat or a scan (see :func:`pointcvx.load`).
    threshold : float
        Stop splitting a part once its concavity is at most this (normalised [-1, 1]^3 frame;
        CoACD's setting in the paper is 0.1).
    max_hulls : int
        Never make more hulls than this.
    features : {"auto", "optimize", "model"}
        Where convex-aware features come from: optimised for this shape, or a feed-forward model.
        "auto" (the default) uses the model on splats, where it measured on par in about half
        the time, and optimisation on every other input (:func:`resolve_features`); the
        choice is recorded in ``result.params["features"]``.
    model : path, optional
        Checkpoint of the feed-forward model (``pointcvx train``); default: the bundled one.
    views : int
        With the model: encode the shape in this many orientations and use the concatenated
        features (a test-time ensemble; each view costs one more network pass).
    merge : bool
        After splitting, join neighbouring parts whose joint hull stays under ``threshold``.
    split : {"auto", "kmeans", "ward"}
        How a part is cut in two: k-means on [features, blend * xyz], or Ward linkage constrained
        to the surface graph ("auto": k-means, which measured better on vhacd61).
    blend : float
        Weight of position (scaled to the part's size) against features when cutting a part.
    n_points : int
        Surface points used (meshes are sampled, clouds capped; seeded).
    seed : int
        Same seed, same result.
    target : {"mujoco", "bullet", "physx", "physx-gpu", "newton", "unity"}, optional
        Keep every hull within this engine's per-hull caps (see :mod:`pointcvx.simplify`): a
        hull over a cap is replaced by a coarser one that still contains its part.
    max_hull_vertices : int, optional
        At most this many vertices per hull (with ``target``, the tighter cap wins).
    subsurface : float, optional
        Leave points deeper than this inside the solid (a fraction of half the longest side of
        the bounds; :data:`SUBSURFACE_DEPTH` = 0.05 suits splats) out of the concavity measure;
        they stay in their parts and hulls. For trained splats that keep a layer of Gaussians
        under their surface (:func:`subsurface_points`): the dev donut splat takes 17 hulls with
        0.05 instead of 44. Off by default, because the walls of folds narrower than about four
        voxels, which the solid closes, read as deep too. The count is
        ``result.cloud.info["subsurface_points"]``.
    progress : callable, optional
        ``progress(stage, done, total)``.
    **load_options
        Passed to the loader (see :class:`pointcvx.LoadOptions`).

    Returns
    -------
    Decomposition
    """
    if not threshold > 0:
        raise InputError(f"threshold must be positive, got {threshold}")
    if max_hulls < 1:
        raise InputError(f"max_hulls must be at least 1, got {max_hulls}")
    if int(views) != views or views < 1:
        raise InputError(f"views must be a positive integer, got {views}")
    check_subsurface(subsurface)
    from .recursive import SPLIT_METHODS, Decomposer
    from .watertight import solid_for

    if split not in SPLIT_METHODS:
        raise InputError(f"unknown split method {split!r}; expected one of {SPLIT_METHODS}")
    if features not in FEATURE_METHODS:
        raise InputError(f"unknown feature method {features!r}; expected one of {FEATURE_METHODS}")
    if features == "model" or (features == "auto" and model is not None):
        load_cached_model(model)  # a missing or broken checkpoint fails now, not at the first split
    limits = None
    if target is not None or max_hull_vertices is not None:
        from .simplify import hull_limits

        limits = hull_limits(target, max_hull_vertices)  # bad settings fail before any work
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    cloud = as_cloud(x, n_points=n_points, seed=seed, **load_options)
    timings["load"] = time.perf_counter() - t0
    t = time.perf_counter()
    solid = solid_for(cloud)
    surface = None
    if subsurface is not None:
        deep = subsurface_points(cloud.points, solid, float(subsurface))
        if deep.any() and not deep.all():
            surface = ~deep
            cloud = cloud.replace(info={**cloud.info, "subsurface_points": int(deep.sum())})
    timings["solid"] = time.perf_counter() - t
    features = resolve_features(features, cloud.modality, model)
    # Features are computed when the first split needs them: a shape already under the
    # threshold (a convex part) is one hull without them.
    feature_step = functools.partial(_feature_array, cloud, solid, method=features, seed=seed,
                                     model=model, views=int(views))
    t = time.perf_counter()
    with threadpool_limits(1):
        decomposer = Decomposer(cloud.points, cloud.normals, feature_step, solid, split=split,
                                is_mesh=cloud.mesh is not None, blend=blend, seed=seed,
                                surface=surface)
    timings["tree"] = time.perf_counter() - t
    params = {"threshold": float(threshold), "max_hulls": int(max_hulls), "features": features,
              "model": None if model is None else str(model), "views": int(views),
              "merge": bool(merge), "split": decomposer.method, "blend": float(blend),
              "n_points": int(n_points), "subsurface": None if subsurface is None else float(subsurface),
              "seed": int(seed), **load_options}
    timings["_start"] = t0
    result = cut_decomposition(decomposer, cloud, params, timings, progress=progress)
    if limits is not None:
        result = result.limit_hulls(limits.target, limits.max_vertices, limits.max_faces)
    return result


def _feature_array(cloud: OrientedCloud, solid, progress: Progress | None = None,
                   **options: Any) -> np.ndarray:
    """(n, k) float32 features of ``cloud.points`` (:func:`compute_features` without the source)."""
    return compute_features(cloud, solid, progress=progress, **options)[1]


def cut_decomposition(decomposer, cloud: OrientedCloud, params: dict,
                      timings: dict, progress: Progress | None = None) -> Decomposition:
    """Cut ``decomposer``'s tree at ``params`` (threshold, max_hulls, merge) into a result."""
    from .metrics import convex_hull

    timings = dict(timings)
    start = timings.pop("_start", None)
    # The features are computed once per decomposer, when a cut first splits; every cut that
    # splits reports their time, whichever computed them, and a cut that does not reports 0.
    timings["features"] = 0.0
    if decomposer.will_split(params["threshold"], params["max_hulls"]):
        # Outside the single-thread limit below: the model's forward pass uses every core.
        decomposer.load_features(progress)
        timings["features"] = decomposer.feature_seconds
    t = time.perf_counter()
    report = None if progress is None else (
        lambda n, worst: progress("split", n, params["max_hulls"]))
    with threadpool_limits(1):  # many small BLAS calls: threads only add overhead
        leaves = decomposer.cut(params["threshold"], params["max_hulls"], progress=report)
        timings["split"] = time.perf_counter() - t
        t = time.perf_counter()
        if params["merge"]:
            parts, concavity = decomposer.merge(leaves, params["threshold"])
        else:
            parts, concavity = decomposer.leaf_parts(leaves, params["threshold"])
    timings["merge"] = time.perf_counter() - t
    t = time.perf_counter()
    labels = np.empty(len(cloud), dtype=np.int64)
    hulls = []
    back = cloud.normalization
    for i, (idx, conc) in enumerate(zip(parts, concavity, strict=True)):
        labels[idx] = i
        h = convex_hull(cloud.points[idx])
        hulls.append(ConvexHull(back.inverse(h.vertices), h.faces.astype(np.int64), float(conc),
                                int(len(idx))))
    timings["hulls"] = time.perf_counter() - t
    if start is not None:
        timings["total"] = time.perf_counter() - start
    else:
        timings["total"] = sum(v for k, v in timings.items() if k != "total")
    return Decomposition(hulls, labels, cloud, decomposer.tree.as_table(), timings, params,
                         _decomposer=decomposer)
