"""Recursive decomposition: split the most concave part in two until every part is under the
threshold or the hull budget is spent, then merge neighbours whose joint hull stays under it.

Parts are sets of surface points (indices into the cloud). A max-heap keyed by concavity picks
the part to split. A split clusters the part's points on [features, lambda * xyz] (k-means, or
Ward linkage constrained to the surface neighbour graph) for a few values of lambda, adds the
median plane across the part's longest axis, and keeps the proposal whose more concave child is
least concave (between cuts into two convex children, the one whose hulls hold the least volume:
:func:`split_score`). Disconnected parts are first split into components. Every split is kept in a
binary tree, so the same feature field can be re-cut at another threshold or hull count without
recomputing anything. The measures of a split's proposals and of a merge's candidate pairs are
independent, and run on the worker threads (:mod:`pointcvx.workers`): the same numbers with
one thread or several.
"""

from __future__ import annotations

import heapq
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from ..errors import InputError
from ..options import SPLIT_METHODS
from ..workers import kd_workers, pmap, threads
from .concavity import GAP_SPACINGS, HOLE_SURFACE_SPACINGS, part_concavity, sample_spacing
from .hull import convex_hull, hull_contains, sample_hull_interior
from .kmeans import nearest_centre, two_means

log = logging.getLogger(__name__)

MIN_PART_POINTS = 4
# A point cloud's leaves of fewer than 2 * MIN_PART_POINTS points, or whose points are scattered
# (no piece of the neighbour graph among them holds 2 * MIN_PART_POINTS), are noise (floaters,
# scattered sensor points) when together they are at most this fraction of the cloud; see
# leaf_parts.
NOISE_FRACTION = 0.01
# A mesh's final part is air when less than AIR_FRACTION of AIR_SAMPLES uniform samples of its
# hull lie inside the solid, and at least AIR_COVERED of its points lie within AIR_SPACINGS sample
# spacings of the other parts' hulls; see drop_air.
AIR_FRACTION = 0.01
AIR_SAMPLES = 2000
AIR_COVERED = 0.9
AIR_SPACINGS = 2.0


@dataclass
class Node:
    """One part in the split tree.

    Attributes
    ----------
    id : int
    parent : int or None
    indices : (m,) int, the cloud points of the part.
    concavity : float
    children : (int, int) or None, set once the part has been split.
    """

    id: int
    parent: int | None
    indices: np.ndarray
    concavity: float
    depth: int = 0
    children: tuple[int, int] | None = None


@dataclass
class SplitTree:
    """All parts ever made, root first; leaves of a cut are the parts of a decomposition."""

    nodes: list[Node] = field(default_factory=list)

    def add(self, parent: int | None, indices: np.ndarray, concavity: float) -> Node:
        depth = 0 if parent is None else self.nodes[parent].depth + 1
        node = Node(len(self.nodes), parent, indices, concavity, depth)
        self.nodes.append(node)
        return node

    def as_table(self) -> list[dict]:
        """Plain rows (id, parent, children, size, concavity) for export."""
        return [
            {"id": n.id, "parent": n.parent, "children": list(n.children) if n.children else None,
             "points": int(len(n.indices)), "concavity": round(float(n.concavity), 6)}
            for n in self.nodes
        ]


def neighbour_graph(points: np.ndarray, k: int = 10, radius_factor: float = 3.0,
                    tree: cKDTree | None = None) -> sparse.csr_matrix:
    """(n, n) symmetric k-NN adjacency of (n, 3) surface points, without edges much longer than
    the typical spacing (so separate components stay separate). ``tree``: a kd-tree of
    ``points`` if already built."""
    k = int(min(k, len(points) - 1))
    dist, idx = (cKDTree(points) if tree is None else tree).query(points, k=k + 1,
                                                                  workers=kd_workers(len(points)))
    dist, idx = dist[:, 1:], idx[:, 1:]
    cap = radius_factor * np.median(dist[:, -1])
    keep = dist <= cap
    rows = np.repeat(np.arange(len(points)), k)[keep.ravel()]
    graph = sparse.coo_matrix((np.ones(len(rows)), (rows, idx.ravel()[keep.ravel()])),
                              shape=(len(points),) * 2).tocsr()
    return ((graph + graph.T) > 0).astype(np.float64).tocsr()


#: Concavities below this count as 0 when split proposals are ranked (normalised frame; the
#: measure's numerical noise on an exactly convex part).
CONCAVITY_TIE = 1e-3


def split_score(a: tuple[float, float], b: tuple[float, float]) -> tuple[float, float, float]:
    """Rank of a two-way split from its children's (concavity, hull volume): the more concave
    child first, then the pair's sum. Between cuts into two convex children (both below
    :data:`CONCAVITY_TIE`) the lower total hull volume wins: the one whose hulls overlap least
    (an L cut into its two boxes, not into overlapping ones). Lower is better."""
    (ca, va), (cb, vb) = a, b
    ca, cb = (c if c >= CONCAVITY_TIE else 0.0 for c in (ca, cb))
    return (max(ca, cb), ca + cb, va + vb if ca + cb == 0.0 else 0.0)


def in_box(columns: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(n,) bool: which points lie in the box [lo, hi] (both (3,) float), from their (3, n)
    float coordinate rows: ``np.all((points >= lo) & (points <= hi), axis=1)``, 30x faster
    (a reduction along an axis of length 3 is slow in NumPy, and every measure of a part
    filters the whole cloud)."""
    inside = (columns[0] >= lo[0]) & (columns[0] <= hi[0])
    for k in (1, 2):
        inside &= columns[k] >= lo[k]
        inside &= columns[k] <= hi[k]
    return inside


class Decomposer:
    """Recursive splitting of one shape, with memoised splits so cuts can be redone cheaply.

    Parameters
    ----------
    points, normals : (n, 3) float
        The oriented cloud in the normalised frame.
    features : (n, k) float, or a callable ``f(progress=None) -> (n, k) float``
        Unit features of the points. A callable is called once, when they are first needed
        (:meth:`load_features`): a shape already under the threshold never pays for them.
    solid : pointcvx.solid.Solid
        The shape's inside (for the concavity's outside test and volume term).
    split : {"auto", "kmeans", "ward"}
        Clustering used to cut a part: k-means on [features, blend * xyz], or Ward linkage
        constrained to the surface neighbour graph ("auto": k-means).
    is_mesh : bool
        Whether the cloud was sampled from a mesh. Both modalities split alike; a scan's or
        splat's tiny leaves are dropped as noise where a mesh's are absorbed (:meth:`leaf_parts`).
    blend : float
        Weight of xyz (scaled to the part's size) against the features in the split.
    candidates : tuple of float
        Multipliers of ``blend`` tried at every split, plus the median plane across the longest
        axis; the proposal whose more concave child is least concave is kept.
    max_split_points : int
        Clustering runs on at most this many points of a part (the rest follow).
    concavity_samples : int
        Hull-surface and volume samples of the full concavity measure.
    rank_points, rank_samples : int
        The coarse concavity that ranks split proposals and merge candidates: at most
        ``rank_points`` of a part's points and ``rank_samples`` samples.
    refine : int
        How many of the best-ranked proposals get the full measure; the best of those is kept.
    seed : int
    surface : (n,) bool, optional
        Which points are surface samples (default: all). The others (a splat's sub-surface
        centres, :func:`pointcvx.pipeline.subsurface_points`) belong to parts and their hulls
        but are left out of the concavity measure, whose surface they are not.
    """

    def __init__(self, points, normals, features, solid, *, split: str = "auto",
                 is_mesh: bool = False, blend: float = 1.0, candidates: tuple = (0.5, 1.0, 2.0),
                 max_split_points: int = 3000, concavity_samples: int = 2000,
                 rank_points: int = 1000, rank_samples: int = 300, refine: int = 2,
                 seed: int = 0, surface: np.ndarray | None = None):
        if split not in SPLIT_METHODS:
            raise InputError(f"unknown split method {split!r}; expected one of {SPLIT_METHODS}")
        self.points = np.asarray(points, dtype=np.float64)
        self.normals = np.asarray(normals, dtype=np.float64)
        self._features = features if callable(features) else np.asarray(features, dtype=np.float64)
        self.feature_seconds = 0.0
        self.solid = solid
        # "auto" is k-means for every modality (docs/decomposition.md compares it with Ward).
        self.method = "kmeans" if split == "auto" else split
        self.blend = float(blend)
        # Blends tried at every split (relative to ``blend``); the split whose worse child is
        # least concave wins.
        self.candidates = tuple(float(c) for c in candidates) or (1.0,)
        self.max_split_points = int(max_split_points)
        self.concavity_samples = int(concavity_samples)
        self.rank_points = int(rank_points)
        self.rank_samples = int(rank_samples)
        self.refine = int(refine)
        self.seed = int(seed)
        self.is_mesh = bool(is_mesh)
        self.surface = None if surface is None else np.asarray(surface, dtype=bool).reshape(-1)
        if self.surface is not None and len(self.surface) != len(self.points):
            raise InputError(f"surface mask has {len(self.surface)} entries for {len(self.points)} points")
        # A fixed random priority per point: a part's coarse subsample is its rank_points
        # points of lowest priority, the same points whichever proposal the part comes from.
        self._priority = np.random.default_rng(self.seed).permutation(len(self.points))
        # Of every point: the spacing, the neighbour graph, and on a cloud which part a hull
        # sample's nearest point is (_foreign).
        self._kdtree = cKDTree(self.points)
        self._columns = np.ascontiguousarray(self.points.T)  # x, y, z rows for in_box
        # Typical distance between neighbouring points (for the coarse estimate's error bound).
        self.spacing = sample_spacing(self.points, self._kdtree)
        self.graph = neighbour_graph(self.points, tree=self._kdtree)
        self.tree = SplitTree()
        self.evaluations = 0
        root = np.arange(len(self.points))
        self.tree.add(None, root, self.concavity(root))

    # ------------------------------------------------------------------ features
    @property
    def features(self) -> np.ndarray:
        """(n, k) float64 unit features (computed on first use)."""
        self.load_features()
        return self._features

    def load_features(self, progress=None) -> None:
        """Compute the features if they are still pending (their time goes to
        ``feature_seconds``). ``progress`` is passed to the feature callable."""
        if not callable(self._features):
            return
        t = time.perf_counter()
        self._features = np.asarray(self._features(progress=progress), dtype=np.float64)
        self.feature_seconds = time.perf_counter() - t

    @property
    def resolution(self) -> float:
        """The least concavity this cloud's samples resolve: :data:`GAP_SPACINGS` sample
        spacings (0 for a mesh, whose solid is exact).

        On a point cloud the air between a hull and the surface is read as the distance to the
        nearest sample, and the solid is rebuilt from the samples; both err by up to the gaps
        the samples leave. A convex box of 300 points measures 0.28 (4 spacings); a LiDAR
        lamp head of 289 points, cut at 0.1 (2 of its spacings), became 20 hulls of 5-30
        points, each still about 0.1 (docs/captures.md)."""
        return 0.0 if self.is_mesh else GAP_SPACINGS * self.spacing

    def stop_threshold(self, threshold: float) -> float:
        """The threshold the split and merge use: ``threshold``, or :attr:`resolution` where
        the samples are too sparse to resolve it."""
        return max(float(threshold), self.resolution)

    def will_split(self, threshold: float, max_hulls: int) -> bool:
        """Whether :meth:`cut` at these settings splits anything (the root is above the
        threshold and more than one hull is allowed), i.e. needs the features."""
        return not (self.tree.nodes[0].concavity <= threshold) and max_hulls > 1

    # ------------------------------------------------------------------ measures
    def concavity(self, indices: np.ndarray, coarse: bool = False) -> float:
        """Concavity of the part made of the points ``indices`` (see :meth:`measure`)."""
        return self.measure(indices, coarse)[0]

    def measure_all(self, parts: list[np.ndarray], coarse: bool = False) -> list[tuple[float, float]]:
        """:meth:`measure` of each of ``parts`` (index arrays), on the worker threads
        (:func:`pointcvx.workers.pmap`): the same numbers as one at a time."""
        self.evaluations += len(parts)
        return pmap(lambda idx: self._measure(idx, coarse), parts)

    def measure(self, indices: np.ndarray, coarse: bool = False) -> tuple[float, float]:
        """(concavity, volume of the convex hull) of the part made of the points ``indices``.

        As in the evaluation protocol (the shape intersected with the part's hull), the surface
        of the piece is every cloud point inside the part's hull, the part's own and any other
        part's that the hull swallows (see concavity.part_concavity for the measure itself). One
        difference from the protocol, on purpose: a hull face lying on *another* part's face of
        the surface (beyond the gap between samples) counts, where the shape intersected with the
        hull would not; cuts whose hulls overlap rank worse.

        ``coarse``: a cheaper estimate for ranking proposals, from at most ``rank_points`` of
        the part's points (and of the swallowed ones, the same share) and ``rank_samples``
        samples.
        """
        self.evaluations += 1
        return self._measure(indices, coarse)

    def _measure(self, indices: np.ndarray, coarse: bool) -> tuple[float, float]:
        """:meth:`measure` without the count: a pure function of its arguments, safe to call
        from several threads at once."""
        # A function of the set of points, not of their order (the hull's triangulation, hence
        # its samples, follows the order): a merge measures the pair's concatenation and keeps
        # it sorted.
        indices = np.sort(indices)
        n_samples = min(self.concavity_samples, self.rank_samples) if coarse else self.concavity_samples
        cut = None
        n_part, full = len(indices), indices
        if coarse and len(indices) > self.rank_points:
            # The part's rank_points points of lowest priority: exactly its points of priority
            # <= cut, so the same cut applied to the other points takes the same share of them.
            keep = np.argpartition(self._priority[indices], self.rank_points - 1)[: self.rank_points]
            indices = indices[keep]
            cut = self._priority[indices].max()
        if len(indices) < 4:
            return 0.0, 0.0
        hull = convex_hull(self.points[indices])
        lo, hi = hull.bounds
        near = in_box(self._columns, lo, hi)
        if cut is not None:
            near &= self._priority <= cut
        near[indices] = False
        measured = indices
        if self.surface is not None:
            near &= self.surface
            own = self.surface[indices]
            if own.sum() >= 4:  # the measure reads the part's surface samples only
                measured = indices[own]
        near = np.flatnonzero(near)
        if len(near):
            # Points at least a hair inside the hull (not those on a shared cut face).
            swallowed = near[hull_contains(hull, self.points[near], tol=-1e-3, dtype=np.float32)]
            if len(swallowed):
                measured = np.concatenate([measured, swallowed])
        # The gaps between the part's samples: the cloud's, wider in a coarse subsample.
        gap = GAP_SPACINGS * self.spacing * (np.sqrt(n_part / len(indices)) if cut is not None else 1.0)
        # A solid rebuilt from samples: hull samples in the holes of the part's sampling are
        # surface, and its surface is known to within a sample spacing.
        rebuilt = {} if self.is_mesh else {"normals": self.normals[measured],
                                           "surface_tol": HOLE_SURFACE_SPACINGS * self.spacing,
                                           "foreign": self._foreign(np.concatenate([full, measured]))}
        conc = part_concavity(self.points[measured], self.solid, hull=hull, n_hull_samples=n_samples,
                              n_volume_samples=n_samples, seed=self.seed, surface_gap=gap, **rebuilt)
        return float(conc), float(hull.volume)

    def _foreign(self, members: np.ndarray):
        """(k, 3) points -> (k,) bool: whether the cloud point nearest each is outside
        ``members`` (indices), i.e. on another part's surface."""
        inside = np.zeros(len(self.points), bool)
        inside[members] = True
        return lambda pts: ~inside[self._kdtree.query(pts)[1]]

    def coarse_margin(self, n_points: int) -> float:
        """How far above the full concavity the coarse estimate of a part of ``n_points``
        points can read: a coarse subsample of ``rank_points`` points is sparser than the cloud
        by ``sqrt(n_points / rank_points)``, and the hull-to-part distance of hull samples in the
        air reads the gaps between the kept points (about two spacings at worst). (Samples on
        the surface are skipped within a gap scaled the same way, so the coarse estimate may
        also read lower; :meth:`merge` only uses it to rule pairs out, with this margin.)"""
        if n_points <= self.rank_points:
            return 0.0
        return 2.0 * self.spacing * float(np.sqrt(n_points / self.rank_points))

    # ------------------------------------------------------------------ splitting
    def _components(self, indices: np.ndarray) -> np.ndarray:
        sub = self.graph[indices][:, indices]
        return csgraph.connected_components(sub, directed=False)[1]

    def _scattered(self, indices: np.ndarray) -> bool:
        """Whether no piece of the neighbour graph among the points ``indices`` holds
        ``2 * MIN_PART_POINTS`` of them (checked only for parts of under
        ``NOISE_FRACTION`` of the cloud: a larger one is never dropped as noise)."""
        if len(indices) > NOISE_FRACTION * len(self.points):
            return False
        return int(np.bincount(self._components(indices)).max()) < 2 * MIN_PART_POINTS

    def _embedding(self, indices: np.ndarray, blend: float) -> np.ndarray:
        xyz = self.points[indices]
        xyz = (xyz - xyz.mean(axis=0)) / max(float(np.linalg.norm(xyz.std(axis=0))), 1e-9)
        return np.concatenate([self.features[indices], blend * xyz], axis=1)

    def _cluster(self, indices: np.ndarray, blend: float, seed: int) -> np.ndarray:
        """(m,) bool: a two-way clustering of the part on [features, blend * xyz]."""
        x = self._embedding(indices, blend)
        rng = np.random.default_rng(seed)
        if len(indices) > self.max_split_points:
            sel = np.sort(rng.choice(len(indices), self.max_split_points, replace=False))
        else:
            sel = np.arange(len(indices))
        if self.method == "kmeans":
            side = nearest_centre(x, two_means(x[sel], seed=seed, n_init=2))
        else:
            from sklearn.cluster import AgglomerativeClustering

            conn = self.graph[indices[sel]][:, indices[sel]]
            n_comp, comp = csgraph.connected_components(conn, directed=False)
            if n_comp > 1:  # the subsample broke the graph: link pieces by nearest points
                conn = _link_components(self.points[indices[sel]], conn, comp)
            ward = AgglomerativeClustering(n_clusters=2, linkage="ward", connectivity=conn)
            sub = ward.fit_predict(x[sel]) == 1
            if len(sel) == len(indices):
                side = sub
            else:  # every point follows its nearest subsampled neighbour
                _, nn = cKDTree(self.points[indices[sel]]).query(self.points[indices])
                side = sub[nn]
        return side

    def split(self, node_id: int) -> tuple[int, int] | None:
        """Split a part in two (memoised); None when it cannot be split."""
        node = self.tree.nodes[node_id]
        if node.children is not None:
            return node.children
        idx = node.indices
        if len(idx) < 2 * MIN_PART_POINTS:
            return None
        sides = []
        for side, min_size in self._proposals(idx, self.seed + node_id):
            if side.sum() < min_size or (~side).sum() < min_size:
                continue
            if any(np.count_nonzero(side != other) <= 0.005 * len(idx)
                   or np.count_nonzero(side == other) <= 0.005 * len(idx) for other in sides):
                continue  # (nearly) a proposal already scored
            sides.append(side)
        if not sides:
            return None
        rough = self.measure_all([part for side in sides for part in (idx[~side], idx[side])], coarse=True)
        scored = [(split_score(rough[2 * k], rough[2 * k + 1]), side) for k, side in enumerate(sides)]
        # The best coarse proposals get the full measure; the best of those is kept.
        best_sides = [side for _, side in sorted(scored, key=lambda item: item[0])[: self.refine]]
        full = self.measure_all([part for side in best_sides for part in (idx[~side], idx[side])])
        best = None
        for k, side in enumerate(best_sides):
            (ca, va), (cb, vb) = full[2 * k], full[2 * k + 1]
            score = split_score((ca, va), (cb, vb))
            if best is None or score < best[0]:
                best = (score, side, ca, cb)
        _, side, ca, cb = best
        a = self.tree.add(node_id, idx[~side], ca)
        b = self.tree.add(node_id, idx[side], cb)
        node.children = (a.id, b.id)
        return node.children

    def _proposals(self, indices: np.ndarray, seed: int):
        """Candidate two-way splits of a part: ((m,) bool side, smallest allowed side) pairs."""
        labels = self._components(indices)
        if labels.max() > 0:
            # Disconnected part: the largest component against the rest. With several sizeable
            # components nothing else is worth trying; a tiny stray piece competes with the rest.
            sizes = np.bincount(labels)
            yield labels != np.argmax(sizes), 1
            if (sizes >= MIN_PART_POINTS).sum() > 1:
                return
        pts = self.points[indices]
        self.load_features()  # once, here: the clusterings below share them
        # The clusterings of the blends are independent (each seeded alike): on the worker
        # threads, in order.
        clustered = pmap(lambda c: self._cluster(indices, self.blend * c, seed), self.candidates)
        for side in clustered:
            yield side, MIN_PART_POINTS
            # The same split made planar: convex pieces meet along planes, and a clean planar
            # cut leaves no holes in either side's surface.
            planar = planar_cut(pts, side)
            if planar is not None:
                yield planar, MIN_PART_POINTS
        # Always-available fallback: halve the part across its longest axis.
        axis = np.argmax(np.ptp(pts, axis=0))
        order = np.argsort(pts[:, axis], kind="stable")
        side = np.zeros(len(indices), dtype=bool)
        side[order[len(order) // 2 :]] = True
        yield side, 1


    # ------------------------------------------------------------------ cutting
    def cut(self, threshold: float, max_hulls: int,
            progress: Callable[[int, float], None] | None = None) -> list[int]:
        """Leaves (node ids) of the decomposition at ``threshold`` / ``max_hulls``.

        Pops the most concave part and splits it until every part is at most ``threshold`` or
        ``max_hulls`` parts exist. ``progress(n_parts, worst_concavity)`` after each split.
        """
        if max_hulls < 1:
            raise InputError(f"max_hulls must be at least 1, got {max_hulls}")
        return greedy_cut([self], [threshold], max_hulls, progress)[0]

    def leaf_parts(self, leaves: list[int], threshold: float) -> tuple[list[np.ndarray], list[float]]:
        """The parts (index arrays) and concavities of ``leaves``, tiny leaves dropped or absorbed.

        A tiny leaf has under ``2 * MIN_PART_POINTS`` points, too few to split. On a mesh, one
        whose concavity is still above ``threshold`` is a stray (the tip of a thin feature cut
        off by a split, whose hull would bridge empty space): each of its points joins the part
        of its nearest point in another leaf, and those parts are measured again. On a scan or
        splat every tiny leaf is noise (a floater, scattered sensor points): absorbing it raised
        a clean neighbour's concavity from under 0.1 to 0.37 on a depth frame, and its own hull
        is a sliver. So is a *scattered* leaf, whose points no piece of the neighbour graph holds
        ``2 * MIN_PART_POINTS`` of: the rest of a part after its largest piece was split off
        (sensor points strewn round an object, pairs of flying pixels), whose hull is a sliver
        spanning the gaps (on five_people.pcd one of 9 points 0.85 long, on kinect_frame.pcd a
        sheet of 12 points as wide as the box beside it). Its points belong to no part (label
        -1), as long as all such leaves together are at most ``NOISE_FRACTION`` of the cloud;
        beyond that they are absorbed as on a mesh.
        """
        parts = [self.tree.nodes[leaf].indices for leaf in leaves]
        conc = [self.tree.nodes[leaf].concavity for leaf in leaves]
        tiny = {k for k, idx in enumerate(parts) if len(idx) < 2 * MIN_PART_POINTS}
        if not self.is_mesh:
            noise = tiny | {k for k, idx in enumerate(parts) if k not in tiny and self._scattered(idx)}
            dropped = sum(len(parts[k]) for k in noise)
            if noise and len(noise) < len(parts) and dropped <= NOISE_FRACTION * len(self.points):
                log.debug("dropped %d tiny or scattered parts as noise (%d points)", len(noise), dropped)
                keep = [k for k in range(len(parts)) if k not in noise]
                return [parts[k] for k in keep], [conc[k] for k in keep]
        stray = {k for k in tiny if conc[k] > threshold}
        if not stray or len(stray) == len(parts):
            return parts, conc
        keep = [k for k in range(len(parts)) if k not in stray]
        owner = np.concatenate([np.full(len(parts[k]), j) for j, k in enumerate(keep)])
        kept = np.concatenate([parts[k] for k in keep])
        moved = np.concatenate([parts[k] for k in sorted(stray)])
        _, nearest = cKDTree(self.points[kept]).query(self.points[moved])
        to = owner[nearest]
        parts, conc = [parts[k] for k in keep], [conc[k] for k in keep]
        grown = np.unique(to)
        for j in grown:
            parts[j] = np.sort(np.concatenate([parts[j], moved[to == j]]))
        for j, (c, _) in zip(grown, self.measure_all([parts[j] for j in grown]), strict=True):
            conc[j] = c
        log.debug("absorbed %d stray parts (%d points)", len(stray), len(moved))
        return parts, conc

    def drop_air(self, parts: list[np.ndarray], conc: list[float]) -> tuple[list[np.ndarray], list[float]]:
        """The parts (index arrays) and concavities without a mesh's air parts.

        An air part is a skin of surface points whose hull holds no material: a face's patch
        cut from the body below it (on vhacd61's test2.off the top of a base plate round a
        column, 0.08 thick and 1.3 wide, wholly outside the solid). Its concavity reads under
        the threshold, as its hull stands off the surface by less than that, but the hull is
        pure air, a false collider, and the evaluation protocol's piece (the shape inside the
        hull) is empty. A part is air when under :data:`AIR_FRACTION` of
        :data:`AIR_SAMPLES` samples of its hull lie inside the solid; it is dropped (its
        points get no hull, label -1) only where at least :data:`AIR_COVERED` of its points lie
        within :data:`AIR_SPACINGS` spacings of the other parts' hulls, so no surface is left
        bare (an open sheet's parts, whose hulls hold little of a repaired solid, stay).
        Clouds are left alone: their solids are rebuilt from the samples. Seeded, the same with
        any number of threads.
        """
        if not self.is_mesh or len(parts) < 2:
            return parts, conc
        hulls = [convex_hull(self.points[idx]) if len(idx) >= 4 else None for idx in parts]

        def material(k: int) -> float:
            hull = hulls[k]
            if hull is None or hull.dim < 3 or not hull.volume > 0:
                return 1.0
            samples = sample_hull_interior(hull, AIR_SAMPLES, np.random.default_rng([self.seed, k]))
            return float(self.solid.contains(samples).mean())

        air = {k for k, share in enumerate(pmap(material, range(len(parts)))) if share < AIR_FRACTION}
        dropped: set[int] = set()
        tol = AIR_SPACINGS * self.spacing
        for k in sorted(air):
            pts = self.points[parts[k]]
            covered = np.zeros(len(pts), bool)
            for j, hull in enumerate(hulls):
                if j not in air and hull is not None:
                    covered |= hull_contains(hull, pts, tol=tol)
            if covered.mean() >= AIR_COVERED:
                dropped.add(k)
        if not dropped or len(dropped) == len(parts):
            return parts, conc
        log.debug("dropped %d air parts (%d points)", len(dropped), sum(len(parts[k]) for k in dropped))
        keep = [k for k in range(len(parts)) if k not in dropped]
        return [parts[k] for k in keep], [conc[k] for k in keep]

    def merge(self, leaves: list[int], threshold: float) -> tuple[list[np.ndarray], list[float]]:
        """Greedily join neighbouring parts while the joint part stays under ``threshold``.

        Returns the final parts as index arrays, and their concavities. Neighbours: parts linked
        by an edge of the surface neighbour graph. Pairs are tried in order of a coarse estimate
        of their joint concavity (see :meth:`concavity`), and the first whose full measure is at
        most ``threshold`` is merged.
        """
        first, first_conc = self.leaf_parts(leaves, threshold)
        parts = dict(enumerate(first))
        conc = dict(enumerate(first_conc))
        label = np.full(len(self.points), -1, dtype=np.int64)  # -1: noise, in no part
        for i, idx in parts.items():
            label[idx] = i
        rough: dict[tuple[int, int], float] = {}  # coarse estimates of joint parts
        full: dict[tuple[int, int], float] = {}
        next_id = len(parts)
        coo = self.graph.tocoo()  # the graph's edges, once: merging only relabels their ends
        while len(parts) > 1:
            a, b = label[coo.row], label[coo.col]
            link = (a < b) & (a >= 0)
            pairs = {(int(x), int(y)) for x, y in zip(a[link], b[link], strict=True)}
            def joint(pair: tuple[int, int]) -> np.ndarray:
                return np.concatenate([parts[pair[0]], parts[pair[1]]])

            new = sorted(pairs - rough.keys())
            for pair, (c, _) in zip(new, self.measure_all([joint(p) for p in new], coarse=True), strict=True):
                rough[pair] = c
            # Candidates in order of their coarse estimate; the first whose full measure is
            # under the threshold is merged. Pairs whose estimate is far above it (beyond the
            # estimate's own error, see coarse_margin) are never measured in full.
            chosen = None
            size = {p: len(parts[p[0]]) + len(parts[p[1]]) for p in pairs}
            hopeful = [p for p in pairs if rough[p] <= 1.5 * threshold + self.coarse_margin(size[p])]
            order = sorted(hopeful, key=lambda p: (rough[p], p))
            for k, pair in enumerate(order):
                if pair not in full:
                    # This pair and the next unmeasured ones, one per thread: a pair's measure
                    # stays valid until one of its parts merges, so those ahead are kept.
                    ahead = [p for p in order[k:] if p not in full][: threads()]
                    for p, (c, _) in zip(ahead, self.measure_all([joint(q) for q in ahead]), strict=True):
                        full[p] = c
                if full[pair] <= threshold:
                    chosen = pair
                    break
            if chosen is None:
                break
            i, j = chosen
            merged = np.sort(np.concatenate([parts.pop(i), parts.pop(j)]))
            conc.pop(i), conc.pop(j)
            parts[next_id], conc[next_id] = merged, full[chosen]
            label[merged] = next_id
            next_id += 1
        return [parts[k] for k in sorted(parts)], [conc[k] for k in sorted(parts)]


def greedy_cut(decomposers: list[Decomposer], thresholds: list[float], max_hulls: int,
               progress: Callable[[int, float], None] | None = None) -> list[list[int]]:
    """Leaves (node ids, sorted) of each of several shapes' split trees under one budget of
    ``max_hulls`` parts in all (one shape: :meth:`Decomposer.cut`; a scene's objects).

    Pops the most concave part of any shape and splits it, until every part is at most its
    shape's threshold (``thresholds[k]``, in that shape's normalised frame) or ``max_hulls``
    parts exist. A tree cut alone at its count of leaves gives the same leaves, as its parts are
    split in the same order; splits are memoised, so earlier cuts are reused.
    ``progress(n_parts, worst_concavity)`` after each split.
    """
    heap = [(-d.tree.nodes[0].concavity, k, 0) for k, d in enumerate(decomposers)]
    heapq.heapify(heap)
    done: list[list[int]] = [[] for _ in decomposers]
    n_done = 0
    while heap and len(heap) + n_done < max_hulls:
        neg, k, node_id = heapq.heappop(heap)
        children = None if -neg <= thresholds[k] else decomposers[k].split(node_id)
        if children is None:  # under its threshold, or too small to split
            done[k].append(node_id)
            n_done += 1
            continue
        for c in children:
            heapq.heappush(heap, (-decomposers[k].tree.nodes[c].concavity, k, c))
        if progress is not None:
            progress(len(heap) + n_done, -heap[0][0] if heap else 0.0)
    for _, k, node_id in heap:
        done[k].append(node_id)
    return [sorted(leaves) for leaves in done]


def planar_cut(points: np.ndarray, side: np.ndarray) -> np.ndarray | None:
    """The plane that best reproduces a two-way labelling of (m, 3) ``points``.

    The plane's normal is Fisher's discriminant direction of the two groups; its offset is the
    one that disagrees with ``side`` on the fewest points. Returns the (m,) bool side of the
    plane, or None when a group is too small to define a direction.
    """
    a, b = points[~side], points[side]
    if len(a) < 2 or len(b) < 2:
        return None
    cov = np.cov(a.T) * (len(a) - 1) + np.cov(b.T) * (len(b) - 1)
    cov += np.eye(3) * 1e-9 * max(np.trace(cov), 1e-12)
    w = np.linalg.solve(cov, b.mean(axis=0) - a.mean(axis=0))
    proj = points @ w
    order = np.argsort(proj, kind="stable")
    s = side[order]
    # Cutting after position k puts order[:k] on the False side: errors = True's before k plus
    # False's from k on.
    errors = np.concatenate([[0], np.cumsum(s)]) + np.concatenate([[(~s).sum()], (~s).sum() - np.cumsum(~s)])
    k = int(np.argmin(errors))
    out = np.zeros(len(points), dtype=bool)
    out[order[k:]] = True
    return out


def _link_components(points: np.ndarray, conn: sparse.csr_matrix, comp: np.ndarray) -> sparse.csr_matrix:
    """Add one edge from each component to its nearest point in another, until connected."""
    conn = conn.tolil()
    n_comp = comp.max() + 1
    while n_comp > 1:
        first = comp == 0
        tree = cKDTree(points[~first])
        d, j = tree.query(points[first])
        i = np.flatnonzero(first)[np.argmin(d)]
        j = np.flatnonzero(~first)[j[np.argmin(d)]]
        conn[i, j] = conn[j, i] = 1.0
        n_comp, comp = csgraph.connected_components(conn.tocsr(), directed=False)
    return conn.tocsr()
