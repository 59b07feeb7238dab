"""The single entry point: anything -> :class:`~pointcvx.result.Decomposition`.

load -> oriented cloud -> solid -> features -> recursive split (+ merge) -> hulls.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import inspect
import os
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from .cloud import OrientedCloud
from .deadline import Deadline
from .errors import InputError
from .io import as_cloud
from .model.weights import bundled_model_path, load_cached_model, needs_model
from .options import (
    DECOMPOSE_POINTS,
    FEATURE_METHODS,
    LENGTH_UNITS,
    DecomposeOptions,
    LoadOptions,
    parse_length,
    split_kwargs,
)
from .result import Decomposition, check_scene_budget, cut_decomposition, merge_parts, share_budget
from .scene.objects import is_scene, may_be_scene, object_pieces

#: Modalities whose default feature source is the bundled model (docs/model.md compares the
#: sources per modality); the others are optimised per shape.
MODEL_MODALITIES = ("splat",)
#: Modalities whose points are moved to the middle of their surface band by default
#: (``band="auto"``; docs/captures.md, "Splats judged against their meshes").
BAND_MODALITIES = ("splat",)

Progress = Callable[[str, int, int], None]
"""progress(stage, done, total): stage is "features" or "split"."""

#: Convex-pair sampling of per-shape optimisation: it sees one shape only, so many anchors with
#: fewer candidates each cover its surface better than the paper's 1024 x 1024 (docs/model.md).
SINGLE_SHAPE_TRIPLETS = {"pool_size": 8192, "n_anchors": 4096, "n_candidates": 256,
                         "n_hard": 64, "n_uniform": 64}
#: Peak learning rate of per-shape optimisation (cosine decay over its ``steps``).
OPTIMIZE_LR = 3e-3

#: A ``subsurface`` depth that suits splats with a sub-surface layer (normalised frame: half the
#: default threshold).
SUBSURFACE_DEPTH = 0.05


def subsurface_points(points: np.ndarray, solid, depth: float = SUBSURFACE_DEPTH) -> np.ndarray:
    """(n,) bool: which of (n, 3) ``points`` lie deeper than ``depth`` inside ``solid``.

    A trained 3D Gaussian splat keeps Gaussians under its surface. A part's hull contains them,
    but the concavity measure would read their distance to the hull's surface as concavity, so a
    part would have to split until a hull face passed near each of them; :func:`decompose` leaves
    them out of the measure when asked (``subsurface``). The walls of a fold that the solid closed
    read as deep too, hence it is not the default.

    ``depth`` is a fraction of half the longest side of the points' bounds.
    """
    pts = np.asarray(points, dtype=np.float64)
    limit = depth * 0.5 * float(np.ptp(pts, axis=0).max())
    deep = solid.contains(pts)
    deep[deep] = solid.distance(pts[deep]) > limit
    return deep


#: Modules that :func:`decompose` imports lazily, the libraries among them (optional ones too).
LAZY_MODULES = (
    "open3d", "trimesh", "manifold3d", "scipy.ndimage", "scipy.sparse.csgraph", "scipy.spatial",
    "skimage.measure", "sklearn.cluster", "pointcvx.export", "pointcvx.io.mesh", "pointcvx.io.scan",
    "pointcvx.io.splat", "pointcvx.solid", "pointcvx.decomposition.tree",
    "pointcvx.evaluate",
)


def input_unit(units: str, cloud: OrientedCloud) -> str:
    """The length unit of ``cloud``'s input coordinates: ``units``, or for "auto" mm on CAD parts
    (OpenCASCADE reads STEP in mm) and m otherwise."""
    if units != "auto":
        return units
    return "mm" if cloud.modality == "cad" else "m"


def resolve_threshold(threshold: float | str, units: str, cloud: OrientedCloud) -> float:
    """The concavity threshold in ``cloud``'s normalised frame: a number is one already; a length
    (``"5mm"``) is converted with the input's unit (:func:`input_unit`) and the cloud's scale."""
    if not isinstance(threshold, str):
        return float(threshold)
    unit = input_unit(units, cloud)
    return parse_length(threshold) / LENGTH_UNITS[unit] / float(cloud.normalization.scale)


def resolve_features(features: str, modality: str, model: str | os.PathLike | None = None) -> str:
    """The feature source that ``features`` means for a cloud of ``modality``: "optimize" and
    "model" are themselves; "auto" is the model for the modalities of :data:`MODEL_MODALITIES`
    (splats) when there is one (``model``, or the bundled one), per-shape optimisation otherwise."""
    if features not in FEATURE_METHODS:
        raise InputError(f"unknown features {features!r}; expected one of {', '.join(FEATURE_METHODS)}")
    if features != "auto":
        return features
    if modality in MODEL_MODALITIES and (model is not None or bundled_model_path() is not None):
        return "model"
    return "optimize"


def preload(features: str = "auto", model: str | os.PathLike | None = None) -> None:
    """Import what :func:`decompose` imports lazily (optional libraries that are not installed are
    skipped) and, for ``features="model"`` (or "auto" with a model available), load the network
    of ``model`` (default: the bundled one) into the per-process cache: what a long-running
    process (``pointcvx batch`` and ``pointcvx bench`` workers) does once before its first shape."""
    import importlib

    field = ("pointcvx.features.field",)
    uses = {"optimize": field, "fast": field, "model": ("pointcvx.model.numpy_net",),
            "auto": field + ("pointcvx.model.numpy_net",)}[features]
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
    ``pointcvx train``), or the bundled one. "optimize" fits a per-shape field
    (:mod:`pointcvx.features.field`, numpy, no torch) to the shape's convex pairs
    (:data:`SINGLE_SHAPE_TRIPLETS`) in ``steps`` Adam steps; "fast" fits the same field in
    fewer steps on fewer pairs (the settings of :mod:`pointcvx.features.field`; ``steps`` is for
    "optimize" only). "auto" picks by the cloud's modality (:func:`resolve_features`).
    """
    method = resolve_features(method, cloud.modality, model)
    if method == "model":
        if views == 1:  # numpy: a decomposition with one view imports no torch
            from .model.numpy_net import NumpyModelSource

            source = NumpyModelSource(load_cached_model(model), cloud.points, cloud.normals)
        else:  # the rotated views of the test-time ensemble run in torch
            from .model.source import ModelFeatureSource, load_model
            from .model.weights import model_path

            source = ModelFeatureSource(load_model(model_path(model)), cloud.points, cloud.normals,
                                        views=views)
        return source, source.features(cloud.points)
    from .features import field

    if method == "fast":
        total, lr, triplet_kw = field.FAST_STEPS, field.FAST_LR, field.FAST_TRIPLETS
    else:
        total, lr, triplet_kw = steps, OPTIMIZE_LR, SINGLE_SHAPE_TRIPLETS
    if progress is not None:  # step 0: the convex pairs (a time limit is checked here too)
        progress("features", 0, total)
    triplets = field.sample_field_triplets(solid, cloud.points, cloud.normals, seed=seed, **triplet_kw)
    report = None if progress is None else (lambda step, loss: progress("features", step + 1, total))
    source = field.fit_field(triplets, steps=total, lr=lr, seed=seed, progress=report)
    return source, source.features(cloud.points)


def _feature_array(cloud: OrientedCloud, solid, progress: Progress | None = None,
                   **options: Any) -> np.ndarray:
    """(n, k) float32 features of ``cloud.points`` (:func:`compute_features` without the source)."""
    return compute_features(cloud, solid, progress=progress, **options)[1]


def decompose(x: Any, *, progress: Progress | None = None, **options: Any) -> Decomposition:
    """Split a shape into convex hulls.

    Parameters
    ----------
    x : path, (n, 3) array, (points, normals), open3d geometry, trimesh or OrientedCloud
        The shape: a mesh, a CAD part, a splat or a scan (see :func:`pointcvx.load`).
    progress : callable, optional
        ``progress(stage, done, total)`` with stage "features" or "split".
    **options
        Every option of :class:`pointcvx.options.DecomposeOptions` and
        :class:`pointcvx.options.LoadOptions`, by name, each checked as declared there; the
        most used: ``threshold`` (0.1, the normalised frame), ``max_hulls`` (64), ``features``
        ("auto": the model on splats, optimisation on other inputs; the choice is recorded in
        ``result.params["features"]``), ``n_points`` (:data:`pointcvx.options.DECOMPOSE_POINTS`
        surface points), ``seed`` (same seed, same result), ``target`` (an engine's per-hull
        caps), ``subsurface`` (leave a splat's sub-surface layer out of the concavity measure),
        ``timeout`` (seconds, loading included).

    Returns
    -------
    Decomposition

    Raises
    ------
    InputError
        An option of the wrong type or out of its range, or unusable input.
    TypeError
        An option name that does not exist.
    TimeLimitError
        ``timeout`` seconds passed before the result was ready (:mod:`pointcvx.deadline`).
    """
    if progress is not None and not callable(progress):  # fails now, not at the first step
        raise InputError(f"progress must be a callable progress(stage, done, total) or None, "
                         f"got {type(progress).__name__}")
    dec_kw, load_kw = split_kwargs(options)
    load_kw.setdefault("n_points", DECOMPOSE_POINTS)
    dec, load = DecomposeOptions(**dec_kw), LoadOptions(**load_kw)
    if needs_model(dec.features, dec.model):
        load_cached_model(dec.model)  # a broken checkpoint fails now, not at the first split
    limits = None
    if dec.target is not None or dec.max_hull_vertices is not None:
        from .decomposition.limits import hull_limits

        limits = hull_limits(dec.target, dec.max_hull_vertices)  # bad settings fail before any work
    deadline = Deadline(dec.timeout)
    progress = deadline.watch(progress)
    t0 = time.perf_counter()
    cloud = as_cloud(x, load)
    loaded = time.perf_counter() - t0
    deadline.check("finding objects")
    pieces = object_pieces(cloud.points) if may_be_scene(cloud, dec.scene) else []
    if is_scene(cloud, dec.scene, pieces) and len(pieces) > 0:
        result = _decompose_scene(cloud, pieces, dec, load, loaded, t0, progress, deadline)
    else:
        result = _decompose_cloud(cloud, dec, load, {"load": loaded, "_start": t0}, progress, deadline)
    if limits is not None:
        deadline.check("fitting hulls to the engine's caps")
        result = result.limit_hulls(limits.target, limits.max_vertices, limits.max_faces)
    deadline.check("finishing")
    return result


def _decompose_cloud(cloud: OrientedCloud, dec: DecomposeOptions, load: LoadOptions, timings: dict,
                     progress: Progress | None = None,
                     deadline: Deadline | None = None) -> Decomposition:
    """One object: its solid, its (lazy) features, the split tree, cut at ``dec``'s settings."""
    from .decomposition.tree import Decomposer
    from .solid import solid_for

    timings = dict(timings)
    given = dec.threshold
    dec = dataclasses.replace(dec, threshold=resolve_threshold(dec.threshold, dec.units, cloud))
    deadline = deadline or Deadline(None)
    deadline.check("building the solid")
    t = time.perf_counter()
    if dec.band == "on" or (dec.band == "auto" and cloud.modality in BAND_MODALITIES):
        from .scene.band import flatten_band

        cloud = cloud.replace(points=flatten_band(cloud.points, cloud.normals))
    solid = solid_for(cloud)
    surface = None
    if dec.subsurface is not None:
        deep = subsurface_points(cloud.points, solid, dec.subsurface)
        if deep.any() and not deep.all():
            surface = ~deep
            cloud = cloud.replace(info={**cloud.info, "subsurface_points": int(deep.sum())})
    timings["solid"] = time.perf_counter() - t
    features = resolve_features(dec.features, cloud.modality, dec.model)
    # Features are computed when the first split needs them: a shape already under the
    # threshold (a convex part) is one hull without them.
    feature_step = functools.partial(_feature_array, cloud, solid, method=features, seed=load.seed,
                                     model=dec.model, views=dec.views)
    deadline.check("building the split tree")
    t = time.perf_counter()
    with threadpool_limits(1):
        decomposer = Decomposer(cloud.points, cloud.normals, feature_step, solid, split=dec.split,
                                is_mesh=cloud.mesh is not None, blend=dec.blend, seed=load.seed,
                                surface=surface)
    timings["tree"] = time.perf_counter() - t
    params = {**dec.as_dict(), **load.as_dict(), "features": features, "split": decomposer.method}
    if isinstance(given, str):  # a length: what was asked, and the unit it was read in
        params.update(threshold_given=given, units=input_unit(dec.units, cloud))
    return cut_decomposition(decomposer, cloud, params, timings, progress=progress)


def _decompose_scene(cloud: OrientedCloud, pieces: list[np.ndarray], dec: DecomposeOptions,
                     load: LoadOptions, loaded: float, t0: float,
                     progress: Progress | None = None,
                     deadline: Deadline | None = None) -> Decomposition:
    """A scene: each object (a connected piece of the isolated cloud) decomposed in its own
    normalised frame, so the threshold is relative to each object's size, then merged.

    The objects run on the worker threads, each on one core (its own maps then serial, BLAS
    single-threaded): an object's work is a pure function of its points and the seed, so the
    hulls are those of one object after the other (docs/benchmarks.md, "Depth frames: normals
    that face the sensor"). Progress is then one stage, ``"objects"``, counting finished objects; with one
    thread or one object each object's own stages are reported (``"object 2/3 features"``)."""
    from .workers import pmap, threads

    check_scene_budget(dec.max_hulls, len(pieces))  # before any object's work
    n = len(pieces)
    at_once = threads() > 1 and n > 1
    lock, finished = threading.Lock(), [0]

    def one(k: int) -> Decomposition:
        obj = cloud.subset(pieces[k]).normalized()
        obj.info["object"] = k
        if at_once:  # each step still checks the time limit; the user hears of whole objects
            report = None if deadline is None else (
                lambda stage, done, total: deadline.check(f"object {k + 1}/{n} {stage}"))
        else:
            report = None if progress is None else (
                lambda stage, done, total: progress(f"object {k + 1}/{n} {stage}", done, total))
        part = _decompose_cloud(obj, dec, load, {"load": 0.0}, report, deadline)
        if progress is not None and at_once:
            with lock:  # a user's callback is called by one thread at a time
                finished[0] += 1
                progress("objects", finished[0], n)
        return part

    if at_once:
        if progress is not None:
            progress("objects", 0, n)
        with threadpool_limits(1):
            parts = pmap(one, range(n))
    else:
        parts = [one(k) for k in range(n)]
    # max_hulls bounds the scene's hulls, not each object's
    return merge_parts(share_budget(parts, dec.max_hulls), pieces, cloud, {"load": loaded, "_start": t0})


def _signature() -> inspect.Signature:
    """``decompose(x, *, progress=None, <every option with its default>)`` for help() and IDEs."""
    params = [inspect.Parameter("x", inspect.Parameter.POSITIONAL_OR_KEYWORD),
              inspect.Parameter("progress", inspect.Parameter.KEYWORD_ONLY, default=None)]
    defaults = {**DecomposeOptions.defaults(), **LoadOptions.defaults(), "n_points": DECOMPOSE_POINTS}
    params += [inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=value)
               for name, value in defaults.items()]
    return inspect.Signature(params, return_annotation="Decomposition")


decompose.__signature__ = _signature()
