"""The one result type, a convex decomposition with plain numpy at the boundary, and how it is
cut from a split tree (:func:`cut_decomposition`)."""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from .cloud import OrientedCloud
from .errors import InputError, OutputError

log = logging.getLogger(__name__)

#: What a cut found, kept in its ``params`` beside the settings (a scene keeps them per object):
#: the threshold a cloud too sparse for the asked one was cut at, and whether the hull budget
#: (``max_hulls``) stopped the split with a part still above the threshold.
OUTCOMES = ("resolved_threshold", "max_hulls_reached")


@dataclass(eq=False)
class ConvexHull:
    """One convex piece, in the input's units.

    Attributes
    ----------
    vertices : (v, 3) float64
    faces : (f, 3) int64, wound outward.
    concavity : float
        Concavity of the part it covers, in the normalised [-1, 1]^3 frame.
    n_points : int
        How many cloud points the part holds.
    added_volume : float
        Volume added by engine limits (:meth:`Decomposition.limit_hulls`); 0 for the plain hull.
    """

    vertices: np.ndarray
    faces: np.ndarray
    concavity: float
    n_points: int
    added_volume: float = 0.0

    @property
    def volume(self) -> float:
        tri = self.vertices[self.faces]
        return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)

    def to_trimesh(self):
        import trimesh

        return trimesh.Trimesh(self.vertices.copy(), self.faces.copy(), process=False)


@dataclass(eq=False)
class Decomposition:
    """A convex decomposition of one shape.

    Attributes
    ----------
    hulls : list of ConvexHull
        In the input's units; every cloud point lies in the hull of its part.
    labels : (n,) int64
        Hull index of each point of ``cloud``; -1 for a scan's or splat's noise (tiny leaves,
        counted in ``cloud.info["noise_points"]``) and a scene's points of no object.
    cloud : OrientedCloud
        The points that were decomposed (normalised frame; ``cloud.normalization`` maps back).
    features : (n, k) float32
        The convex-aware features of the cloud's points (a property: a shape that needed no
        split has them computed on first access; the constructor takes them, if known, as
        ``_features``, else from ``_decomposer``).
    tree : list of dict
        The split tree (id, parent, children, points, concavity), root first.
    timings : dict of str -> float
        Seconds per stage.
    params : dict
        Every setting that produced the result, seed included.
    objects : list of dict, optional
        For a scene (``decompose(..., scene=...)``): per object, its ``name``, the indices of its
        ``hulls``, its ``points`` count, its ``bounds`` (input units) and ``max_concavity``, and
        where they apply its :data:`OUTCOMES` (``resolved_threshold``, ``max_hulls_reached``),
        what it ``rests_on`` ("support", another object's name, or None), whether it ``stands``
        there (its centre of mass over where it touches; None without an up direction) and
        whether it is ``static`` (held by something out of view: rests on nothing or does not
        stand; :func:`pointcvx.decomposition.ground.resting_on`). Each object was decomposed in
        its own normalised frame. None for a single object.
    removed_points : (m, 3) float64, optional
        What isolation removed from the input (support plane, clutter), in input units.
    """

    hulls: list[ConvexHull]
    labels: np.ndarray
    cloud: OrientedCloud
    tree: list[dict]
    timings: dict[str, float]
    params: dict[str, Any]
    objects: list[dict] | None = None
    _decomposer: Any = field(default=None, repr=False)
    _features: np.ndarray | None = field(default=None, repr=False)
    _parts: list | None = field(default=None, repr=False)

    @property
    def features(self) -> np.ndarray:
        """(n, k) float32 features of ``cloud.points`` (a scene's objects each have their own)."""
        if self._features is None:
            if self._parts is not None:
                dims = {p.features.shape[1] for _, p in self._parts}
                out = np.zeros((len(self.labels), max(dims)), dtype=np.float32)
                for idx, part in self._parts:
                    out[idx, : part.features.shape[1]] = part.features
                self._features = out
            elif self._decomposer is None:
                raise OutputError("this decomposition holds no features")
            else:
                self._features = self._decomposer.features.astype(np.float32)
        return self._features

    @property
    def removed_points(self) -> np.ndarray | None:
        removed = self.cloud.removed
        return None if removed is None else self.cloud.normalization.inverse(removed)

    @property
    def support(self) -> dict | None:
        """The support plane isolation found (``normal``, ``offset`` in input units), or None."""
        return self.cloud.info.get("isolation", {}).get("support_plane")

    def __len__(self) -> int:
        return len(self.hulls)

    def __repr__(self) -> str:
        return (f"Decomposition({len(self.hulls)} hulls, max concavity {self.max_concavity:.4f}, "
                f"{self.timings.get('total', 0.0):.2f} s)")

    @property
    def seed(self) -> int:
        return int(self.params.get("seed", 0))

    @property
    def concavity(self) -> np.ndarray:
        """(h,) float: concavity of each hull's part (normalised frame)."""
        return np.array([h.concavity for h in self.hulls], dtype=np.float64)

    @property
    def resolved_thresholds(self) -> dict[str, float]:
        """Object name (or "shape") -> the threshold it was cut at, for each one whose samples
        were too sparse to resolve the asked one (``Decomposer.stop_threshold``)."""
        if "resolved_threshold" in self.params:
            return {"shape": self.params["resolved_threshold"]}
        return {o["name"]: o["resolved_threshold"] for o in self.objects or [] if "resolved_threshold" in o}

    @property
    def budget_stopped(self) -> list[str]:
        """The objects (or ["shape"]) whose split the hull budget (``max_hulls``) stopped with a
        part still above the threshold: more hulls would have brought them under it."""
        if self.params.get("max_hulls_reached"):
            return ["shape"]
        return [o["name"] for o in self.objects or [] if o.get("max_hulls_reached")]

    @property
    def max_concavity(self) -> float:
        return float(self.concavity.max()) if self.hulls else 0.0

    def summary(self) -> dict[str, Any]:
        """The numbers people check: hull count, concavity, time."""
        return {
            "hulls": len(self.hulls),
            "max_concavity": round(self.max_concavity, 5),
            "mean_concavity": round(float(self.concavity.mean()), 5) if self.hulls else 0.0,
            "points": int(len(self.labels)),
            "hull_vertices": int(sum(len(h.vertices) for h in self.hulls)),
            "seconds": round(float(self.timings.get("total", 0.0)), 3),
        } | ({"max_hull_vertices": max((len(h.vertices) for h in self.hulls), default=0),
              "added_volume": self.added_volume,
              "added_volume_ratio": self._added_ratio()} if self.params.get("hull_limits") else {})

    def _added_ratio(self) -> float:
        before = sum(h.volume - h.added_volume for h in self.hulls)
        return float(self.added_volume / before) if before > 0 else 0.0

    # ------------------------------------------------------------------ re-cutting
    def recut(self, threshold: float | None = None, max_hulls: int | None = None,
              merge: bool | None = None) -> Decomposition:
        """The same features and split tree cut at another threshold or hull count.

        Splits already made are reused; deeper ones are computed on demand. Features are never
        recomputed (a shape that needed no split computes them here if the new cut splits).
        """
        if self._parts is not None:
            budget = self.params["max_hulls"] if max_hulls is None else int(max_hulls)
            parts = [part.recut(threshold, budget, merge) for _, part in self._parts]
            parts = share_budget(parts, budget)
            return merge_parts(parts, [idx for idx, _ in self._parts], self.cloud,
                               {"load": self.timings.get("load", 0.0)})
        if self._decomposer is None:
            raise OutputError("this decomposition no longer holds its split tree (it was loaded "
                              "from disk); decompose again to re-cut it")
        params = dict(self.params)
        if threshold is not None:
            params["threshold"] = float(threshold)
        if max_hulls is not None:
            params["max_hulls"] = int(max_hulls)
        if merge is not None:
            params["merge"] = bool(merge)
        out = cut_decomposition(self._decomposer, self.cloud, params, dict(self.timings))
        limits = params.get("hull_limits")
        if limits:
            out = out.limit_hulls(limits.get("target"), limits.get("max_vertices"),
                                  limits.get("max_faces"))
        return out

    # ------------------------------------------------------------------ conversions
    def to_trimesh(self):
        """A ``trimesh.Scene`` with one geometry per hull (``hull_000``, ...)."""
        import trimesh

        scene = trimesh.Scene()
        for i, h in enumerate(self.hulls):
            scene.add_geometry(h.to_trimesh(), node_name=f"hull_{i:03d}", geom_name=f"hull_{i:03d}")
        return scene

    def to_open3d(self) -> list:
        """A list of ``open3d.geometry.TriangleMesh``, one per hull, with vertex normals."""
        from .syslibs import import_open3d
        o3d = import_open3d()

        out = []
        for h in self.hulls:
            m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(h.vertices),
                                          o3d.utility.Vector3iVector(h.faces.astype(np.int32)))
            m.compute_vertex_normals()
            out.append(m)
        return out

    # ------------------------------------------------------------------ engine limits
    def limit_hulls(self, target: str | None = None, max_vertices: int | None = None,
                    max_faces: int | None = None) -> Decomposition:
        """The same decomposition with every hull within an engine's per-hull caps.

        ``target``: ``"mujoco"``, ``"bullet"`` (no caps), ``"physx"`` (255 vertices, 255
        triangles), ``"physx-gpu"`` (64 vertices, 64 triangles), ``"newton"`` (64 vertices),
        ``"unity"`` (255 triangles); ``max_vertices`` / ``max_faces`` (triangles) tighten them.
        A hull over a cap is replaced by a coarser one that contains it (see
        :mod:`pointcvx.decomposition.limits`), so no point loses coverage; each hull's ``added_volume`` says
        what it cost. The caps are kept in ``params["hull_limits"]`` and :meth:`recut` applies
        them again.
        """
        from .decomposition.limits import hull_limits, simplify_hull

        limits = hull_limits(target, max_vertices, max_faces)
        t = time.perf_counter()
        hulls = []
        for h in self.hulls:
            v, f, added = simplify_hull(h.vertices, h.faces, limits)
            hulls.append(ConvexHull(v, f, h.concavity, h.n_points, h.added_volume + added))
        seconds = time.perf_counter() - t
        timings = dict(self.timings)
        timings["limits"] = timings.get("limits", 0.0) + seconds
        timings["total"] = timings.get("total", 0.0) + seconds
        params = dict(self.params)
        params["hull_limits"] = limits.as_dict()
        return replace(self, hulls=hulls, timings=timings, params=params)

    def hull_offsets(self, samples: int = 2000) -> np.ndarray:
        """(h,) float: how far each hull reaches out of the input, in input units: the largest
        distance from its surface (``samples`` area-weighted samples and its vertices) to the
        nearest input point."""
        from scipy.spatial import cKDTree

        from .decomposition.hull import sample_triangles

        tree = cKDTree(self.cloud.normalization.inverse(self.cloud.points))
        rng = np.random.default_rng(self.seed)
        out = np.zeros(len(self.hulls))
        for i, h in enumerate(self.hulls):
            probe = h.vertices
            if len(h.faces):
                probe = np.concatenate([probe, sample_triangles(h.vertices[h.faces], samples, rng)[0]])
            out[i] = float(tree.query(probe)[0].max()) if len(probe) else 0.0
        return out

    @property
    def added_volume(self) -> float:
        """Volume the engine limits added to the hulls, in input units cubed (0 without limits)."""
        return float(sum(h.added_volume for h in self.hulls))

    # ------------------------------------------------------------------ export
    def export(self, path: str | os.PathLike, format: str | None = None, *, overwrite: bool = False,
               per_hull: bool = False, target: str | None = None,
               max_hull_vertices: int | None = None, free_joint: bool = True,
               density: float = 1000.0, up="auto") -> list[Path]:
        """Write the hulls; return the files written, the main one first.

        ``format`` (default: from ``path``'s suffix): ``"obj"`` (.obj: one file, an ``o
        hull_NNN`` object per hull; with ``per_hull``, a folder or a path without suffix: one
        ``hull_NNN.obj`` each), ``"stl"`` (``NAME.stl``: one ``hull_NNN.stl`` per hull in the
        folder ``NAME_stl/``), ``"glb"``/``"gltf"`` (a scene, a node per hull), ``"urdf"``
        (``NAME.urdf``) and ``"mjcf"`` (``NAME.xml``, ``NAME.mjcf``): the folder ``NAME_urdf/`` or
        ``NAME_mjcf/`` holding the robot file and an OBJ per hull (plus the input mesh as visual),
        ``"usda"`` (.usda, .usd: one USD text file, a rigid body with a convex-hull collider Mesh
        per hull and the input mesh as visual), ``"json"`` (.json: the report). A path without a
        suffix (or an existing folder) names the folder itself. See :mod:`pointcvx.export` for
        the layouts. ``target`` / ``max_hull_vertices`` apply :meth:`limit_hulls` first.
        ``free_joint`` (MJCF) and ``density`` (URDF, MJCF, USD mass; input units) shape the robot
        files; ``up`` (URDF, MJCF, USD: "auto", an axis such as "-y", or a (3,) direction) is the
        input's up, turned to +z there while the hull coordinates stay in the input's frame
        ("auto": the support plane isolation found, else +z). A scene (``objects``) is one body
        per object on its static support plane.

        Outputs appear whole or not at all, even if the process is killed, with the user's umask.
        A folder output is pointcvx's alone: ``overwrite`` replaces a previous one whole (no stale
        files), and a folder holding files pointcvx did not write is refused, never emptied. The
        input file is never written over, and existing outputs are kept
        (:class:`~pointcvx.errors.OutputError`) unless ``overwrite``.
        """
        from .export import export_decomposition

        result = self
        if target is not None or max_hull_vertices is not None:
            result = self.limit_hulls(target, max_hull_vertices)
        return export_decomposition(result, path, format, overwrite=overwrite, per_hull=per_hull,
                                    free_joint=free_joint, density=density, up=up)

    def report(self) -> dict[str, Any]:
        """The JSON report (per hull: vertices, faces, volume, added volume, concavity; totals;
        parameters; seed; timings), as written by ``export(..., format="json")``."""
        from .export import report

        return report(self)


def cut_decomposition(decomposer, cloud: OrientedCloud, params: dict, timings: dict,
                      progress=None) -> Decomposition:
    """Cut ``decomposer``'s tree (a :class:`~pointcvx.decomposition.tree.Decomposer`) at
    ``params`` (threshold, max_hulls, merge) into a result; ``progress(stage, done, total)``."""
    from .decomposition.ground import grounded_vertices, support_band
    from .decomposition.hull import convex_hull
    from .decomposition.seams import seam_points

    timings = dict(timings)
    start = timings.pop("_start", None)
    # The features are computed once per decomposer, when a cut first splits; every cut that
    # splits reports their time, whichever computed them, and a cut that does not reports 0.
    timings["features"] = 0.0
    # A cloud too sparse to resolve the threshold is cut at what it resolves, and says so.
    threshold = decomposer.stop_threshold(params["threshold"])
    params = {k: v for k, v in params.items() if k not in OUTCOMES}
    if threshold > params["threshold"]:
        params["resolved_threshold"] = round(threshold, 6)
    splits = decomposer.will_split(threshold, params["max_hulls"])
    if splits:
        # Outside the single-thread limit below: the model's forward pass uses every core.
        decomposer.load_features(progress)
        timings["features"] = decomposer.feature_seconds
    t = time.perf_counter()
    report = None if progress is None else (
        lambda n, worst: progress("split", n, params["max_hulls"]))
    if splits and decomposer.method == "ward":
        # Ward clustering loads scikit-learn's OpenMP runtime; threadpoolctl limits only the
        # runtimes already loaded, so load it before the limit (scikit-learn's k-means, when the
        # default split used it, otherwise ran on every core: 12-14 s instead of 2 s on chair.off).
        import sklearn.cluster  # noqa: F401
    with threadpool_limits(1):  # many small BLAS calls: threads only add overhead
        leaves = decomposer.cut(threshold, params["max_hulls"], progress=report)
        timings["split"] = time.perf_counter() - t
        t = time.perf_counter()
        if params["merge"]:
            parts, concavity = decomposer.merge(leaves, threshold)
        else:
            parts, concavity = decomposer.leaf_parts(leaves, threshold)
        before = sum(len(idx) for idx in parts)
        parts, concavity = decomposer.drop_air(parts, concavity)
        air_points = before - sum(len(idx) for idx in parts)
    timings["merge"] = time.perf_counter() - t
    if len(leaves) >= params["max_hulls"] and max(concavity, default=0.0) > threshold:
        # The budget, not the threshold, stopped the split: the user should know to raise it.
        params["max_hulls_reached"] = True
    t = time.perf_counter()
    labels = np.full(len(cloud), -1, dtype=np.int64)  # -1: noise, in no hull (leaf_parts)
    for i, idx in enumerate(parts):
        labels[idx] = i
    hulls = []
    back = cloud.normalization
    # Each hull also reaches halfway across the cut to its neighbours, so hulls meet there
    # instead of leaving a gap (decomposition.seams).
    spanned = seam_points(cloud.points, cloud.normals, labels, decomposer.spacing)
    # What stood on a removed support plane reaches down to it (decomposition.ground).
    support = support_band(cloud.info) if params.get("close_bases") == "hulls" else None
    grounded = 0
    for idx, span, conc in zip(parts, spanned, concavity, strict=True):
        h = convex_hull(span)
        vertices, faces = back.inverse(h.vertices), h.faces
        down = None if support is None else grounded_vertices(vertices, *support)
        if down is not None:
            h = convex_hull(down)
            vertices, faces = h.vertices, h.faces
            grounded += 1
        hulls.append(ConvexHull(vertices, faces.astype(np.int64), float(conc), int(len(idx))))
    timings["hulls"] = time.perf_counter() - t
    noise = int(np.count_nonzero(labels < 0)) - air_points
    # A mesh's surface points of parts whose hulls held no material (Decomposer.drop_air).
    if air_points or "air_points" in cloud.info:
        cloud = cloud.replace(info={**cloud.info, "air_points": air_points})
    if noise or "noise_points" in cloud.info:  # a recut may drop none where an earlier cut did
        cloud = cloud.replace(info={**cloud.info, "noise_points": noise})
    if grounded or "grounded_hulls" in cloud.info:
        cloud = cloud.replace(info={**cloud.info, "grounded_hulls": grounded})
    if start is not None:
        timings["total"] = time.perf_counter() - start
    else:
        timings["total"] = sum(v for k, v in timings.items() if k != "total")
    return Decomposition(hulls, labels, cloud, decomposer.tree.as_table(), timings, params,
                         _decomposer=decomposer)


def check_scene_budget(max_hulls: int, n_objects: int) -> None:
    """:class:`InputError` when a scene of ``n_objects`` cannot fit ``max_hulls`` hulls (each
    object needs one)."""
    if max_hulls < n_objects:
        raise InputError(f"max_hulls is {max_hulls}, less than the scene's {n_objects} objects "
                         "(each needs a hull): raise it, or decompose the whole as one shape "
                         "(scene off) or its largest object only (isolate largest)")


def share_budget(parts: list[Decomposition], max_hulls: int) -> list[Decomposition]:
    """A scene's objects, each decomposed with the whole budget, cut again so that together
    they hold at most ``max_hulls`` hulls: the budget goes where the concavity is
    (:func:`~pointcvx.decomposition.tree.greedy_cut`), and only objects whose share is
    below what they used are cut again (their splits are reused; their merge runs again)."""
    from .decomposition.tree import greedy_cut

    check_scene_budget(max_hulls, len(parts))
    if sum(len(p.hulls) for p in parts) <= max_hulls:
        return parts
    decs = [p._decomposer for p in parts]
    thresholds = [d.stop_threshold(p.params["threshold"]) for d, p in zip(decs, parts, strict=True)]
    counts = [len(leaves) for leaves in greedy_cut(decs, thresholds, max_hulls)]
    out = []
    for part, dec, threshold, k in zip(parts, decs, thresholds, counts, strict=True):
        if k < len(dec.cut(threshold, part.params["max_hulls"])):
            part = part.recut(max_hulls=k)
            part.params["max_hulls"] = max_hulls  # the scene's budget; its share was k
        out.append(part)
    return out


def merge_parts(parts: list[Decomposition], pieces: list[np.ndarray], cloud: OrientedCloud,
                timings: dict) -> Decomposition:
    """One decomposition of a scene from its objects' decompositions: ``parts[k]`` decomposed the
    points ``pieces[k]`` ((m_k,) int indices into ``cloud``) in its own frame. Hulls keep the
    input's units; labels index the merged hull list (-1 for points of no object)."""
    from .decomposition.ground import scene_rests

    timings = dict(timings)
    start = timings.pop("_start", None)
    hulls: list[ConvexHull] = []
    labels = np.full(len(cloud), -1, dtype=np.int64)
    tree: list[dict] = []
    objects = []
    for k, (part, idx) in enumerate(zip(parts, pieces, strict=True)):
        first = len(hulls)
        labels[idx] = np.where(part.labels >= 0, part.labels + first, -1)
        hulls.extend(part.hulls)
        tree.extend({**node, "object": k} for node in part.tree)
        pts = part.cloud.normalization.inverse(part.cloud.points)
        objects.append({"name": f"object_{k:02d}", "hulls": list(range(first, len(hulls))),
                        "points": int(len(idx)),
                        "bounds": [pts.min(axis=0).tolist(), pts.max(axis=0).tolist()],
                        "max_concavity": round(part.max_concavity, 6)}
                       | {key: part.params[key] for key in OUTCOMES if key in part.params})
        for key, value in part.timings.items():
            if key != "total":
                timings[key] = timings.get(key, 0.0) + value
    # What each object rests on; one held by something out of view is a static body.
    rests = scene_rests(cloud.info, cloud.normalization.inverse(cloud.points),
                        [[hulls[h].vertices for h in obj["hulls"]] for obj in objects])
    if rests is None:  # no up direction: nothing known to rest or to hold, every object free
        rests = [(None, None)] * len(objects)
    for obj, (on, stands) in zip(objects, rests, strict=True):
        obj["rests_on"] = objects[on]["name"] if isinstance(on, int) else on
        obj["stands"] = stands  # its centre of mass over where it touches what it rests on
        obj["static"] = stands is False
    for key in ("noise_points", "air_points", "grounded_hulls"):
        count = sum(int(part.cloud.info.get(key, 0)) for part in parts)
        if count or key in cloud.info:
            cloud = cloud.replace(info={**cloud.info, key: count})
    timings["total"] = (time.perf_counter() - start) if start is not None else sum(timings.values())
    params = ({k: v for k, v in parts[0].params.items() if k not in OUTCOMES}
              | {"scene": True, "objects": len(parts)}) if parts else {"scene": True}
    return Decomposition(hulls, labels, cloud, tree, timings, params, objects=objects,
                         _parts=list(zip(pieces, parts, strict=True)))
