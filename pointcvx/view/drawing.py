"""What a picture of a decomposition shows: a :class:`Drawing` of plain arrays in the input's units,
made from a :class:`~pointcvx.result.Decomposition`, an :class:`~pointcvx.cloud.OrientedCloud` or
bare arrays, and shared by the HTML viewer (:mod:`pointcvx.view.html`) and the PNG renderer
(:mod:`pointcvx.view.png`)."""

from __future__ import annotations

import colorsys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..cloud import OrientedCloud, check_points
from ..errors import InputError

#: At most this many points are drawn (a seeded subset of the rest): a page stays a few MB.
MAX_POINTS = 50_000
#: Axes a picture can stand on; ``z`` (robotics, MuJoCo, the bundled samples) unless told.
UP_AXES = ("z", "y", "x", "-z", "-y", "-x")
#: Colour of points without their own (RGB in [0, 1]) and of points that isolation removed.
POINT_COLOR = (0.56, 0.60, 0.66)
REMOVED_COLOR = (0.74, 0.74, 0.74)


@dataclass(eq=False)
class Drawing:
    """Everything one picture draws, in the input's units.

    Attributes
    ----------
    points : (n, 3) float64
        The shape's points, at most ``max_points`` of them.
    colors : (n, 3) float32 in [0, 1], optional
        Their own colours (splats, coloured scans).
    normals : (n, 3) float64, optional
        Unit outward normals, for shading.
    labels : (n,) int64, optional
        Hull index of each point (a decomposition's points), for "colour by hull".
    hulls : list of ((v, 3) float64, (f, 3) int64)
        Vertices and outward triangles of each hull.
    removed : (m, 3) float64, optional
        Points that isolation removed (support plane, clutter), drawn grey.
    legend : dict
        What the page's legend and the PNG's caption say: ``title``, ``hulls``,
        ``max_concavity``, ``seconds``, ``features``, ``modality``, ``points`` and
        ``points_total`` (drawn and given), ``removed``, ``noise`` (a scan's or splat's points
        in no hull), ``resolved_threshold`` (the largest threshold an object too sparse for the
        asked one was cut at), ``budget`` (``max_hulls``, where that budget stopped the split
        above the threshold), ``static`` (the names of a scene's objects that are static bodies
        in the exports, held by what the capture does not show); ``None`` where unknown.
    up : str
        The axis that points up, one of :data:`UP_AXES`.
    up_exact : (3,) float64, optional
        The detected up direction (the support plane's normal) when it is not an axis: the
        picture's camera stands on it, so a tilted depth frame's table reads as a floor.
    """

    points: np.ndarray
    colors: np.ndarray | None = None
    normals: np.ndarray | None = None
    labels: np.ndarray | None = None
    hulls: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    removed: np.ndarray | None = None
    legend: dict[str, Any] = field(default_factory=dict)
    up: str = "z"
    up_exact: np.ndarray | None = None

    @property
    def hull_colors(self) -> np.ndarray:
        """(h, 3) float RGB in [0, 1]: one colour per hull."""
        return hull_colors(len(self.hulls))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """((3,), (3,)) float64: the box around points, hulls and removed points."""
        parts = [self.points] + [v for v, _ in self.hulls]
        if self.removed is not None and len(self.removed):
            parts.append(self.removed)
        allp = np.concatenate(parts)
        return allp.min(axis=0), allp.max(axis=0)


def hull_colors(n: int) -> np.ndarray:
    """(n, 3) float RGB in [0, 1]: distinct colours, neighbours far apart (golden-ratio hues)."""
    return np.array([colorsys.hsv_to_rgb((0.13 + i * 0.618034) % 1.0, 0.68, 0.92) for i in range(n)],
                    dtype=np.float64).reshape(-1, 3)


def nearest_axis(up) -> str:
    """The signed axis (one of :data:`UP_AXES`) closest to ``up``: an axis name, or a (3,) vector
    such as the support plane's normal that isolation records in ``cloud.info["up"]``."""
    if isinstance(up, str):
        return up if up in UP_AXES else "z"
    v = np.asarray(up, dtype=np.float64).reshape(3)
    i = int(np.argmax(np.abs(v)))
    return ("-" if v[i] < 0 else "") + "xyz"[i]


def up_vector(up: str) -> np.ndarray:
    """``'z'``, ``'-y'``, ... -> (3,) float unit vector."""
    if up not in UP_AXES:
        raise InputError(f"up axis must be one of {', '.join(UP_AXES)}, got {up!r}")
    v = np.zeros(3)
    v["xyz".index(up[-1])] = -1.0 if up.startswith("-") else 1.0
    return v


def subsample(n: int, limit: int | None, seed: int = 0) -> np.ndarray | None:
    """Sorted indices of a seeded choice of ``limit`` of ``n`` items, or None to keep all."""
    if limit is None or n <= limit:
        return None
    if limit < 1:
        raise InputError(f"the point limit must be positive, got {limit}")
    return np.sort(np.random.default_rng(seed).choice(n, size=limit, replace=False))


def as_hulls(hulls) -> list[tuple[np.ndarray, np.ndarray]]:
    """Hulls in any of the forms people hold them -> list of ((v, 3) float64, (f, 3) int64).

    Accepts :class:`~pointcvx.result.ConvexHull` objects (or anything with ``vertices`` and
    ``faces``), ``(vertices, faces)`` pairs, and bare (m, 3) vertex arrays (as
    :func:`pointcvx.evaluate.load_hulls` gives), whose convex hull is taken.
    """
    from ..decomposition.hull import convex_hull

    out = []
    for i, h in enumerate(hulls or ()):
        if hasattr(h, "vertices") and hasattr(h, "faces"):
            v, f = h.vertices, h.faces
        elif isinstance(h, tuple | list) and len(h) == 2 and np.ndim(h[1]) == 2:
            v, f = h
        else:
            poly = convex_hull(check_points(h, f"hull {i} vertices"))
            v, f = poly.vertices, poly.faces
        v = check_points(v, f"hull {i} vertices")
        f = np.asarray(f, dtype=np.int64).reshape(-1, 3)
        if len(f) and (f.min() < 0 or f.max() >= len(v)):
            raise InputError(f"hull {i}: a face refers to a vertex it does not have")
        if len(f):  # wound outward, as the viewer's face culling and the shading expect
            tri = v[f]
            out_of = np.einsum("ij,ij->i", np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]),
                               tri.mean(axis=1) - v.mean(axis=0))
            f = np.where((out_of < 0)[:, None], f[:, ::-1], f)
        out.append((v, f))
    return out


def _legend_of(x) -> dict[str, Any]:
    """The legend entries a decomposition or a cloud knows about itself."""
    legend: dict[str, Any] = {}
    cloud = getattr(x, "cloud", x)
    if isinstance(cloud, OrientedCloud):
        source = cloud.info.get("source")
        legend["title"] = Path(str(source)).name if source else None
        legend["modality"] = cloud.modality
    if hasattr(x, "hulls") and hasattr(x, "labels"):
        legend["max_concavity"] = float(x.max_concavity) if len(x.hulls) else None
        legend["seconds"] = float(x.timings.get("total")) if "total" in x.timings else None
        legend["features"] = x.params.get("features")
        legend["noise"] = cloud.info.get("noise_points") or None
        # the threshold the sparsest object was cut at, where its samples could not resolve
        # the asked one (Decomposer.stop_threshold)
        resolved = x.resolved_thresholds.values() if hasattr(x, "resolved_thresholds") else ()
        legend["resolved_threshold"] = max(resolved, default=None)
        # the hull budget stopped the split above the threshold (Decomposition.budget_stopped)
        stopped = getattr(x, "budget_stopped", [])
        legend["budget"] = x.params.get("max_hulls") if stopped else None
        # a scene's objects held by what the capture does not show: static bodies in the exports
        held = [o["name"] for o in getattr(x, "objects", None) or [] if o.get("static")]
        legend["static"] = ", ".join(held) if held else None
    return legend


def drawing(points, colors=None, hulls=None, removed=None, *, normals=None, labels=None,
          legend: dict | None = None, up: str = "z", max_points: int | None = MAX_POINTS,
          seed: int = 0) -> Drawing:
    """A :class:`Drawing` from plain arrays, all in the same (input) units.

    Parameters
    ----------
    points : (n, 3) float
    colors : (n, 3) float in [0, 1] or uint8, optional
    hulls : see :func:`as_hulls`, optional
    removed : (m, 3) float, optional
        Points that isolation removed, drawn grey.
    normals : (n, 3) float, optional
    labels : (n,) int, optional
        Hull index per point.
    legend : dict, optional
        Entries for the legend (see :class:`Drawing`); counts are filled in here.
    up : str
        One of :data:`UP_AXES`.
    max_points : int or None
        Draw at most this many points (and removed points): a seeded subset.
    """
    pts = check_points(points)
    n = len(pts)
    up_vector(up)

    def per_point(a, what, dtype, width=3):
        if a is None:
            return None
        a = np.asarray(a)
        if a.shape != ((n, width) if width else (n,)):
            raise InputError(f"{what} must have shape ({n}{', 3' if width else ''},), got {a.shape}")
        return a.astype(dtype)

    if colors is not None and np.asarray(colors).dtype == np.uint8:
        colors = np.asarray(colors, dtype=np.float32) / 255.0
    cols = per_point(colors, "colors", np.float32)
    if cols is not None:
        cols = np.clip(np.nan_to_num(cols), 0.0, 1.0)
    nrm = per_point(normals, "normals", np.float64)
    lab = per_point(labels, "labels", np.int64, width=0)
    keep = subsample(n, max_points, seed)
    if keep is not None:
        pts, cols, nrm, lab = (None if a is None else a[keep] for a in (pts, cols, nrm, lab))
    rem, rem_total = None, 0
    if removed is not None and len(np.asarray(removed)):
        rem = check_points(removed, "removed points")
        rem_total = len(rem)
        k = subsample(len(rem), max_points, seed + 1)
        rem = rem if k is None else rem[k]
    hs = as_hulls(hulls)
    info = {"title": None, "hulls": len(hs), "max_concavity": None, "seconds": None, "features": None,
            "modality": None}
    info.update({k: v for k, v in (legend or {}).items() if v is not None})
    info.update(points=len(pts), points_total=n, removed=rem_total, hulls=len(hs))
    return Drawing(pts, cols, nrm, lab, hs, rem, info, up)


def drawing_from(x, hulls=None, removed=None, *, colors=None, legend: dict | None = None,
               up: str | None = None, max_points: int | None = MAX_POINTS, seed: int = 0) -> Drawing:
    """A :class:`Drawing` of a decomposition, a cloud or an (n, 3) array of points.

    ``x`` a :class:`~pointcvx.result.Decomposition`: its cloud's points (in input units), colours
    and hull labels, its hulls unless ``hulls`` is given, its ``removed_points`` (where the
    decomposition records them) unless ``removed`` is given, and hull count, max concavity, time
    and feature source in the legend. ``x`` an :class:`~pointcvx.cloud.OrientedCloud`: its points,
    colours and normals in input units. ``up``: as given, else the cloud's ``info["up"]`` where
    known, else ``z``. ``colors`` replaces the points' own (e.g. PCA colours of features).
    """
    auto = dict(_legend_of(x))
    cloud = getattr(x, "cloud", x)
    exact = None
    labels = None
    if hasattr(x, "hulls") and hasattr(x, "labels"):
        hulls = x.hulls if hulls is None else hulls
        removed = getattr(x, "removed_points", None) if removed is None else removed
        labels = x.labels if hulls is x.hulls else None
    if isinstance(cloud, OrientedCloud):
        to_input = cloud.normalization.inverse
        points, normals = to_input(cloud.points), cloud.normals
        own_removed = getattr(cloud, "removed", None)  # what isolation took out, where recorded
        if removed is None and own_removed is not None and len(own_removed):
            removed = to_input(own_removed)
        colors = cloud.colors if colors is None else colors
        if up is None and cloud.info.get("up") is not None:
            up = nearest_axis(cloud.info["up"])
            exact = np.asarray(cloud.info["up"], dtype=np.float64).reshape(3)
            exact = exact / np.linalg.norm(exact)
    elif hasattr(x, "hulls"):
        raise InputError("this decomposition holds no cloud to draw")
    else:
        points, normals = x, None
    auto.update(legend or {})
    out = drawing(points, colors, hulls, removed, normals=normals, labels=labels, legend=auto,
                  up=up or "z", max_points=max_points, seed=seed)
    if exact is not None:
        out.up_exact = exact
    return out



def edge_faces(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The edges of a triangle mesh and the faces beside them.

    Returns (e, 2) int64 vertex pairs (smaller index first) and (e, 2) int64 indices of the two
    faces sharing each edge; -1 in both columns where an edge is not shared by exactly two faces
    (a border, or a flat hull that lists each triangle once per side).
    """
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if not len(faces):
        return np.zeros((0, 2), dtype=np.int64), np.zeros((0, 2), dtype=np.int64)
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    owner = np.repeat(np.arange(len(faces)), 3)
    uniq, inverse, counts = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    order = np.argsort(inverse.reshape(-1), kind="stable")
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    pair = np.full((len(uniq), 2), -1, dtype=np.int64)
    two = counts == 2
    pair[two, 0] = owner[order[first[two]]]
    pair[two, 1] = owner[order[first[two] + 1]]
    return uniq, pair


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(f, 3) float64 unit normals of triangles (zero for degenerate ones)."""
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64).reshape(-1, 3)]
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)


def creases(normals: np.ndarray, pair: np.ndarray, angle: float = 20.0) -> np.ndarray:
    """(e,) bool: which edges are creases, given the (f, 3) face ``normals`` and the (e, 2) face
    ``pair`` of each edge (:func:`edge_faces`): their faces meet at more than ``angle`` degrees,
    or they are not shared by exactly two faces (borders, flat hulls)."""
    crease = pair[:, 0] < 0
    two = ~crease
    cos = np.einsum("ij,ij->i", normals[pair[two, 0]], normals[pair[two, 1]])
    crease[two] = cos < np.cos(np.radians(angle))
    return crease


def feature_edges(vertices: np.ndarray, faces: np.ndarray, angle: float = 20.0) -> np.ndarray:
    """(e, 2) int64 vertex pairs of a hull's creases (see :func:`creases`).

    Convex hulls of point sets are triangulated finely where the shape is round; drawing only
    the creases keeps a hull's outline readable without the triangulation's clutter.
    """
    edges, pair = edge_faces(faces)
    return edges[creases(face_normals(vertices, faces), pair, angle)]
