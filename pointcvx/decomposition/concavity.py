"""CoACD's concavity, as the decomposition's stop rule measures it.

``Concavity(P) = max(Hb, k * Rv)`` with ``k = 0.3``, ``Hb`` the two-way Hausdorff distance between
the surface of ``P`` and the surface of its convex hull, and ``Rv = (3 |V(hull) - V(P)| /
(4 pi))^(1/3)`` the radius of the sphere of the missing volume. :func:`part_concavity` measures
a part known only by its surface samples, inside the whole shape's solid, fast enough for the
recursive decomposition's hot loop; :mod:`pointcvx.evaluate` measures exact pieces of a mesh with
the same terms (:func:`concavity_terms`).
"""

from __future__ import annotations

import numpy as np

from ..cloud import check_points
from ..errors import InputError
from ..workers import kd_workers
from .hull import Polytope, convex_hull, max_inside_depth, sample_hull_interior, sample_hull_surface

K_CONCAVITY = 0.3
_FOUR_THIRDS_PI = 4.0 * np.pi / 3.0


# ---------------------------------------------------------------------------------- distances
def nearest_distance(points, targets) -> np.ndarray:
    """(n,) float: Euclidean distance from each of (n, 3) ``points`` to the nearest of (m, 3)
    ``targets`` (kd-tree)."""
    from scipy.spatial import cKDTree

    pts = check_points(points, allow_empty=True)
    tgt = check_points(targets, "targets", allow_empty=True)
    if len(pts) == 0:
        return np.zeros(0)
    if len(tgt) == 0:
        raise InputError("no target points to measure distances to")
    tree = cKDTree(tgt, leafsize=32, balanced_tree=False, compact_nodes=False)
    return tree.query(pts, workers=-1 if len(pts) > 50000 else 1)[0]


#: Neighbours of a hull sample that tell a hole in the part's sampling from air
#: (:func:`hole_aware_distance`).
HOLE_NEIGHBOURS = 16
#: Of those, the ones whose normals are within this angle (degrees) of the nearest one's are
#: its face.
HOLE_FACE_DEGREES = 30.0
#: The fewest of those on the face for it to be seen round the sample.
HOLE_FACE_POINTS = 5


def hole_aware_distance(samples, points, normals, tree=None) -> np.ndarray:
    """(n,) float: distance from each of (n, 3) ``samples`` to the surface that (m, 3) ``points``
    with (m, 3) unit outward ``normals`` sample, reading a hole in the sampling as surface.

    A sample's distance is the Euclidean distance to its nearest point, except where the
    surface surrounds it: of its :data:`HOLE_NEIGHBOURS` nearest points, those whose normals are
    within :data:`HOLE_FACE_DEGREES` of the nearest one's are its face (at least
    :data:`HOLE_FACE_POINTS`), and all of them, seen along the face's mean normal, leave no
    empty half-plane about the sample (near an edge of a face the next face's points close the
    side the face leaves open). There it is its height above that face, ``|(s - c) . n|``
    with ``c`` the face points' centroid and ``n`` their mean normal, if less.
    A sample in a hole between random samples of a flat face is then about 0 instead of the
    hole's radius; one over a cavity, whose nearest points are the cavity's floor, is its
    height over the floor as before; one beyond the edge of the part has all its neighbours on
    one side and keeps its Euclidean distance.

    ``tree``: a ``scipy.spatial.cKDTree`` of ``points`` if already built. Each sample's
    distance depends on that sample alone: the distances of a subset of ``samples`` are those
    rows of the whole set's.
    """
    from scipy.spatial import cKDTree

    samples = np.asarray(samples, dtype=np.float64).reshape(-1, 3)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    if len(samples) == 0:
        return np.zeros(0)
    k = min(HOLE_NEIGHBOURS, len(points))
    d, nn = (cKDTree(points) if tree is None else tree).query(samples, k=k)
    if k < HOLE_FACE_POINTS:  # too few points to see a face round the sample
        return np.asarray(d if k == 1 else d[:, 0], dtype=np.float64)
    nb, nbn = points[nn], normals[nn]  # (n, k, 3)
    face = np.einsum("nkc,nc->nk", nbn, nbn[:, 0]) >= np.cos(np.radians(HOLE_FACE_DEGREES))
    count = face.sum(axis=1)
    mean = (nbn * face[:, :, None]).sum(axis=1)
    mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-12)
    # A tangent basis (u, v) of each mean normal; the angle of each neighbour about the sample.
    helper = np.where(np.abs(mean[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(mean, helper)
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
    v = np.cross(mean, u)
    rel = nb - samples[:, None, :]
    # Every neighbour, of the face or not, closes a side of the sample: near an edge of the
    # face the next face's points, seen along this face's normal, lie on the edge, so a hole
    # there is surrounded; beyond the edge they lie between the face and the sample, which
    # keeps an empty side.
    angle = np.sort(np.arctan2(np.einsum("nkc,nc->nk", rel, v), np.einsum("nkc,nc->nk", rel, u)), axis=1)
    widest = np.maximum(np.diff(angle, axis=1).max(axis=1), angle[:, 0] + 2 * np.pi - angle[:, -1])
    hole = (count >= HOLE_FACE_POINTS) & (widest < np.pi)
    out = d[:, 0].copy()
    if hole.any():
        w = face[hole][:, :, None]
        centre = (nb[hole] * w).sum(axis=1) / w.sum(axis=1)
        height = np.abs(np.einsum("nc,nc->n", samples[hole] - centre, mean[hole]))
        out[hole] = np.minimum(out[hole], height)
    return out


def chamfer_distance(a, b) -> float:
    """Chamfer distance of two samplings (n, 3) and (m, 3): the mean of the two directional mean
    nearest-neighbour Euclidean distances, ``(mean_a d(a, B) + mean_b d(b, A)) / 2``."""
    return 0.5 * float(nearest_distance(a, b).mean() + nearest_distance(b, a).mean())


def hausdorff_distance(a, b) -> float:
    """Two-way Hausdorff distance of two samplings (n, 3) and (m, 3)."""
    return float(max(nearest_distance(a, b).max(), nearest_distance(b, a).max()))


def rv_term(volume_difference: float) -> float:
    """CoACD's Rv: radius of the sphere of volume ``|volume_difference|``."""
    return float((abs(volume_difference) / _FOUR_THIRDS_PI) ** (1.0 / 3.0))


def concavity_terms(hb_part: float, hb_hull: float, hull_volume: float, part_volume: float,
                     k: float) -> dict[str, float]:
    """CoACD's concavity ``max(Hb, k * Rv)`` from its two Hausdorff directions and the volumes,
    with every term, as both concavity functions report them."""
    hb = max(hb_part, hb_hull)
    rv = rv_term(hull_volume - part_volume)
    return {
        "concavity": max(hb, k * rv),
        "hb": hb,
        "hb_part": hb_part,
        "hb_hull": hb_hull,
        "rv": rv,
        "hull_volume": float(hull_volume),
        "part_volume": float(part_volume),
    }


# ------------------------------------------------------------------- the stop rule
#: Polytope-surface samples closer than this to the solid's surface lie on the shape, not in the
#: air (normalised frame).
SURFACE_TOL = 1e-3
#: A part's samples leave gaps of up to about this many times their typical spacing.
GAP_SPACINGS = 4.0
#: A solid rebuilt from samples (scans, splats) has its surface within this many sample
#: spacings of the true one (more at rounded edges than on faces): the surface tolerance of their
#: measure.
HOLE_SURFACE_SPACINGS = 1.0


def _max_outside(solid, samples: np.ndarray, dist: np.ndarray, surface_gap: float = 0.0,
                 tol: float = SURFACE_TOL, foreign=None) -> float:
    """max of (n,) ``dist`` over the (n, 3) hull-surface ``samples`` that are concavity (0 if
    none): those in the air (outside ``solid``), and those on the solid's surface (within
    ``tol``) further than ``surface_gap`` from the part.

    A sample on the surface near the part sits on a face the part shares with its hull, in a gap
    between the part's samples: not concavity. One on the surface far from the part lies on
    *another* part's face: the hull spreads over it. (The inside test of a point on the surface
    depends on the face's orientation, so surface samples are told apart by distance first.)
    Tests samples in decreasing order of ``dist``, in growing batches, and stops at the first
    batch holding one that counts: exact, and cheap unless most far samples are inside. The
    inside test (ray parity) comes first, being several times cheaper than the distance to the
    surface, which is then asked only where it decides: a far sample (beyond ``surface_gap``)
    reported outside counts whether it is on the surface or in the air, and a near one reported
    inside counts in neither case.

    ``foreign`` ((k, 3) samples -> (k,) bool: whether the cloud point nearest each is another
    part's), for a solid rebuilt from samples: a far sample on the surface counts only where it
    is foreign, on another part's face. One whose nearest point is the part's own lies in a hole
    of the part's sampling (a sparse scan's holes reach four spacings and more, and the rebuilt
    solid's rounded edges put such samples on either side of it).
    """
    order = np.argsort(-dist)
    s, step = 0, 64
    while s < len(order):
        chunk = order[s : s + step]
        outside = ~solid.contains(samples[chunk])
        far = dist[chunk] > surface_gap
        counts = far & outside
        ask = far != outside  # far and inside, or near and outside
        surface_counts = far
        if foreign is not None:
            surface_counts = far.copy()  # the kd-tree is asked about the far samples only
            if far.any():
                surface_counts[far] = foreign(samples[chunk[far]])
            ask |= far & outside & ~surface_counts  # in the air, or in a hole of the part's own
        ask = np.flatnonzero(ask)
        if len(ask):
            on_surface = solid.distance(samples[chunk[ask]]) <= tol
            counts[ask] = np.where(on_surface, surface_counts[ask], outside[ask])
        if counts.any():
            return float(dist[chunk[int(np.argmax(counts))]])
        s, step = s + step, 4 * step
    return 0.0


def _max_outside_holes(solid, samples: np.ndarray, points: np.ndarray, normals: np.ndarray,
                       surface_gap: float, tol: float, foreign=None) -> float:
    """:func:`_max_outside` of the :func:`hole_aware_distance` of (n, 3) hull ``samples`` to
    the part's (m, 3) ``points`` and ``normals``, with the hole test made only where it can
    decide the answer: a sample's hole-aware distance is at most its nearest-point distance,
    so once the samples of the largest nearest-point distances give a concavity no smaller
    than every other sample's nearest-point distance, those others cannot exceed it. The
    same value as measuring every sample (each sample's distance depends on it alone, and
    the answer is the largest distance of a counting sample); on a splat's parts the hole
    test (16 neighbours, their angles about each sample) then runs on a fifth of the samples
    (io/mug_splat.ply: 151,000 rows instead of 745,000; the split 0.82x, the merge 0.8x)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(points)
    upper = tree.query(samples, k=1)[0]  # (n,) nearest-point distances
    order = np.argsort(-upper, kind="stable")
    m = 32  # rows of the first round, then four times more each round
    while True:
        top = order[:m]
        found = _max_outside(solid, samples[top], hole_aware_distance(samples[top], points, normals, tree),
                             surface_gap, tol, foreign)
        if m >= len(order) or found >= upper[order[m]]:
            return found
        m *= 4


def _sample_distances(samples: np.ndarray, points: np.ndarray, normals) -> np.ndarray:
    """(n,) float: the distance from each of (n, 3) hull ``samples`` to the part's (m, 3)
    ``points``: :func:`hole_aware_distance` given their (m, 3) ``normals``, else
    :func:`nearest_distance`."""
    if not len(samples):
        return np.zeros(0)
    if normals is None:
        return nearest_distance(samples, points)
    return hole_aware_distance(samples, points, normals)


def sample_spacing(points: np.ndarray, tree=None) -> float:
    """Median distance from each of the (n, 3) ``points`` to its nearest neighbour. ``tree``:
    a ``scipy.spatial.cKDTree`` of ``points`` if already built."""
    from scipy.spatial import cKDTree

    if len(points) < 2:
        return 0.0
    tree = cKDTree(points) if tree is None else tree
    return float(np.median(tree.query(points, k=2, workers=kd_workers(len(points)))[0][:, 1]))


def part_concavity(
    points,
    solid,
    *,
    k: float = K_CONCAVITY,
    hull: Polytope | None = None,
    n_hull_samples: int = 1000,
    n_volume_samples: int = 1000,
    seed: int = 0,
    surface_gap: float | None = None,
    normals=None,
    surface_tol: float | None = None,
    foreign=None,
    return_terms: bool = False,
):
    """Concavity of a part known by its surface samples, inside the whole shape's solid.

    Parameters
    ----------
    points : (n, 3) float
        Samples of the part's share of the shape's surface. Where the part was cut from the rest
        of the shape there is no surface, hence no samples (no cap).
    solid : pointcvx.solid.Solid or None
        The whole shape. ``None`` gives the pure surface version (see below).
    k : float
        Weight of the volume term (CoACD: 0.3).
    hull : Polytope, optional
        ``convex_hull(points)`` if already known (saves the qhull call, about a third of the
        time); it must be the hull of ``points``: points outside it count as depth 0.
    n_hull_samples, n_volume_samples : int
        Samples of the hull's surface (for Hb) and of its volume (for Rv).
    seed : int
        Seeds both samplings; same input and seed, same result.
    surface_gap : float, optional
        The largest gap expected between neighbouring part samples (default: ``GAP_SPACINGS``
        times their median spacing). Polytope-surface samples on the solid's surface and within
        this of the part lie on the part's own faces and are not concavity.
    normals : (n, 3) float, optional
        Unit outward normals of ``points``. Given (a solid rebuilt from samples: scans and
        splats), hull samples in holes of the part's sampling are read as surface
        (:func:`hole_aware_distance`), so a convex part measures about 0 however unevenly it
        was sampled.
    surface_tol : float, optional
        How far from the solid's surface a point still lies on it (default
        :data:`SURFACE_TOL`, for an exact solid). Given (a solid rebuilt from samples), volume
        samples outside the solid but within it are also the part's.
    foreign : callable, optional
        (k, 3) points -> (k,) bool, whether the cloud point nearest each belongs to another
        part. Given (a solid rebuilt from samples), a hull sample on the surface far from the
        part counts only where it is foreign (see :func:`_max_outside`).
    return_terms : bool
        Return a dict of the terms instead of the concavity alone.

    Returns
    -------
    float, or dict with ``concavity``, ``hb``, ``hb_part`` (part -> hull), ``hb_hull``
    (hull -> part), ``rv``, ``hull_volume``, ``part_volume``, ``outside_fraction``.

    Definition
    ----------
    With ``H = conv(points)`` and ``S`` the solid::

        Hb = max( max_p dist(p, boundary of H),
                  max over hull-surface samples h NOT inside S of min_p |h - p| )
        Rv = (3 |V(H) - V(H ∩ S)| / (4 pi))^(1/3)
        concavity = max(Hb, k * Rv)

    ``dist(p, boundary of H)`` is exact (facet planes; the points are inside their hull). The
    hull-surface samples inside the solid lie on or across the cut, through the interior, where the
    part has no samples: they are not concavity and are skipped. The part's volume is the solid
    inside its hull: ``V(H) - V(H ∩ S)`` is ``V(H)`` times the fraction of ``n_volume_samples``
    uniform samples of ``H`` that fall outside ``S`` (Monte Carlo). Material of other parts that
    lies inside ``H`` therefore counts as the part's, as in :func:`evaluate` (``M ∩ hull``).

    ``solid=None``: ``Hb`` counts every hull-surface sample and ``Rv = 0``.

    The hull -> part direction measures distances to the nearest *sample*. Where a face of the
    part is also a face of its hull (a box, a flat CAD face), hull samples lie on the solid's
    surface, between part samples: they are skipped when within ``surface_gap`` of the part, so
    a convex part measures 0 whatever its sampling density. A hull face spread over the surface of
    *another* part (two boxes of an L grouped into overlapping hulls) is further than that from
    the part's samples and still counts.
    """
    pts = check_points(points, allow_empty=True)
    if len(pts) == 0:
        raise InputError("the part has no points")
    own_hull = hull is None
    if own_hull:
        hull = convex_hull(pts)
    rng = np.random.default_rng(seed)
    hs = sample_hull_surface(hull, int(n_hull_samples), rng)
    hb_part = max_inside_depth(hull, pts, hull.index if own_hull else None)
    part_volume = hull.volume
    outside_fraction = 0.0
    if solid is None:
        hb_hull = float(_sample_distances(hs, pts, normals).max(initial=0.0))
    else:
        if hull.volume > 0 and n_volume_samples > 0:
            vs = sample_hull_interior(hull, int(n_volume_samples), rng)
            outside = ~solid.contains(vs)
            if surface_tol is not None and outside.any():
                # A rebuilt solid is rounded at the edges: volume samples within its surface
                # tolerance are the part's.
                outside[outside] = solid.distance(vs[outside]) > surface_tol
            outside_fraction = float(outside.mean())
            part_volume = hull.volume * (1.0 - outside_fraction)
        if surface_gap is None:
            surface_gap = GAP_SPACINGS * sample_spacing(pts)
        tol = SURFACE_TOL if surface_tol is None else surface_tol
        if normals is not None and len(hs):  # the hole test only where it decides
            hb_hull = _max_outside_holes(solid, hs, pts, np.asarray(normals, dtype=np.float64).reshape(-1, 3),
                                         surface_gap, tol, foreign)
        else:
            hb_hull = _max_outside(solid, hs, _sample_distances(hs, pts, None), surface_gap, tol, foreign)
    terms = concavity_terms(hb_part, hb_hull, hull.volume, part_volume, k)
    terms["outside_fraction"] = outside_fraction
    return terms if return_terms else terms["concavity"]
