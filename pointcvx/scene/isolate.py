"""Objects freed from their surroundings: the support plane (floor, table, the ground disc under a
captured object) found and removed, small clutter pieces and floaters dropped, an optional box.

:func:`isolate` works on plain (n, 3) points and says what it removed; the loaders apply it to
splats and scans by default (:func:`pointcvx.io.load`, option ``isolate``), where a capture
usually holds more than the object.

A plane is the **support** when:

- the other points lie on one side of it (at least :data:`ONE_SIDED` of them), so it is under
  the object, not through it;
- it holds at most :data:`MAX_SUPPORT_SHARE` of the points (a flat scan is its own plane);
- its outline covers at least :data:`UNDER` of the area of the rest's shadow on it (what
  stands on it is not much wider than it);
- and it is not a face of the object: its outline covers at least :data:`WIDER` times the area
  of the rest's shadow on it (a ground disc around a box), or it joins pieces of similar size
  that are apart without it (a floor under several objects), or it is a layer of its own, with few
  points just above it (at most :data:`SEPARATE` of its own count within four tolerances: the
  ground under vegetation). The flat bottom of an object (a donut's base) is none of these:
  the object's sides rise right from it, and it stays.

In an organised depth frame the image's up direction (``-y`` of the sensor frame) is known, and
the support is the largest plane facing it (within :data:`FRAME_UP_COS`) with the objects above
it (a desk top has things below it), among :data:`FRAME_PLANES` planes of at least
:data:`FRAME_FLOOR_SHARE` of the points (the floor is often a strip under walls and furniture).

A depth frame of a room also sees the room's **walls** (and ceiling), which join whatever stands
against them into one piece. A plane of a frame is a wall when (:func:`walls`):

- it holds at least :data:`WALL_SHARE` of the points left after the support;
- the sensor and at least :data:`ONE_SIDED` of the other points lie on the same side of it, or
  at most :data:`WALL_DEPTH` of its distance from the sensor behind it (it bounds the view: a
  cabinet's front has the wall behind it, a box's top has the sensor above it and the other
  objects below; a niche or a step in the wall is only just behind);
- its outline covers at least :data:`WALL_AREA` of the area of the rest's shadow on it, and it
  spans at least :data:`WALL_SPAN` of the whole frame's extent along both of its own axes (a
  box's face is small beside the floor it stands on).

A plane facing up (within :data:`FRAME_UP_COS`) is a floor or a table, never a wall. Every plane
that passes in a search is taken, then planes are looked for again among the rest. Walls are
removed like the support, band and all, and reported (``removed["walls"]``, the planes in
``walls``); scene exports give each a static box.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..workers import kd_workers
from .components import components
from .planes import Plane, find_planes

ONE_SIDED = 0.95
MAX_SUPPORT_SHARE = 0.97
WIDER = 1.5
#: Any support covers at least this share of the area of the rest's shadow on it.
UNDER = 0.5
SEPARATE = 0.15
#: Points below the support plane or within this many plane tolerances above it go with it.
SUPPORT_BAND = 1.0
FRAME_UP_COS = 0.5
#: In a frame the support is looked for among this many planes of at least this share each.
FRAME_PLANES, FRAME_FLOOR_SHARE = 12, 0.02
#: A piece smaller than this share of the largest piece is clutter (or a floater).
CLUTTER_SHARE = 0.05
#: Plane tolerance: this many median point spacings, and at least this share of the extent.
PLANE_SPACINGS, PLANE_EXTENT = 2.0, 0.005
#: A wall holds at least this share of a depth frame's points left after the support ...
WALL_SHARE = 0.05
#: ... and its outline covers at least this share of the rest's shadow on it.
WALL_AREA = 0.5
#: ... and spans at least this share of the frame's extent along both of its axes.
WALL_SPAN = 0.5
#: Points at most this share of a wall's distance from the sensor behind its band are on its side:
#: a niche, a step in the wall, a door's reveal (in a room's corner frame the side wall stood
#: 0.35 m proud of itself over a third of its length).
WALL_DEPTH = 0.25
#: At most this many walls per frame.
MAX_WALLS = 6
#: A depth sensor's error grows with distance: a wall's points and the points just in front of
#: it spread over this share of the wall's distance from the sensor either way (a Kinect's 5 m
#: wall is a slab about 0.3 m thick), and at least the plane tolerance.
WALL_NOISE = 0.03


@dataclass
class Isolation:
    """What :func:`isolate` kept and removed.

    Attributes
    ----------
    keep : (n,) bool, the points of the object(s).
    support : Plane or None, oriented with the objects on its positive side.
    removed : dict of str -> int, points removed per reason ("crop", "support", "walls",
        "clutter").
    pieces : int, separate pieces kept.
    up : (3,) float or None, the support's normal (the up axis it implies).
    walls : list of (Plane, (2, 3) float, dict), a depth frame's walls, oriented towards the
        sensor, each with the box (min and max corners) of its points and its face
        (:func:`wall_face`).
    labels : (n,) int or None, the kept piece of each point (0 the largest, -1 removed); None
        when no pieces were looked for.
    """

    keep: np.ndarray
    support: Plane | None = None
    removed: dict = field(default_factory=dict)
    pieces: int = 1
    up: np.ndarray | None = None
    walls: list = field(default_factory=list)
    labels: np.ndarray | None = None

    def report(self) -> dict:
        """JSON-able summary for ``cloud.info``."""
        out = {"kept": int(self.keep.sum()), "removed": dict(self.removed), "pieces": int(self.pieces)}
        if self.support is not None:
            out["support_plane"] = self.support.as_dict()
        if self.walls:
            out["walls"] = [{**plane.as_dict(), "bounds": np.round(box, 9).tolist(), "face": face}
                            for plane, box, face in self.walls]
        if self.up is not None:
            out["up"] = np.round(self.up, 6).tolist()
        return out


def spacing(points: np.ndarray, sample: int = 20000) -> float:
    """Median nearest-neighbour distance of (n, 3) ``points`` (on a seeded subsample)."""
    from scipy.spatial import cKDTree

    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 2:
        return 0.0
    sub = pts[np.random.default_rng(0).permutation(len(pts))[:sample]] if len(pts) > sample else pts
    return float(np.median(cKDTree(sub).query(sub, k=2, workers=kd_workers(len(sub)))[0][:, 1]))


def plane_tolerance(points: np.ndarray) -> float:
    """How far from a plane of (n, 3) ``points`` its points may lie: :data:`PLANE_SPACINGS`
    median spacings, and at least :data:`PLANE_EXTENT` of their extent."""
    pts = np.asarray(points, dtype=np.float64)
    return max(PLANE_SPACINGS * spacing(pts), PLANE_EXTENT * float(np.ptp(pts, axis=0).max()))


def plane_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two (3,) float unit axes u, v of the plane with (3,) unit ``normal`` (u x v = normal)."""
    helper = np.eye(3)[int(np.argmin(np.abs(normal)))]
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(normal, u)


def _outline_area(points: np.ndarray, normal: np.ndarray, limit: int = 20000) -> float:
    """Area of the 2D convex hull of (n, 3) ``points`` projected on the plane of ``normal``."""
    from scipy.spatial import ConvexHull, QhullError

    if len(points) < 3:
        return 0.0
    pts = points[:: max(1, len(points) // limit)]
    u, v = plane_basis(normal)
    try:
        return float(ConvexHull(np.stack([pts @ u, pts @ v], axis=1)).volume)
    except QhullError:
        return 0.0


def _pieces(points: np.ndarray) -> int:
    """How many pieces of (n, 3) ``points`` hold at least a fifth of the largest one's points."""
    if len(points) < 8:
        return 1
    sizes = np.bincount(components(points))
    return int((sizes >= 0.2 * sizes[0]).sum())


def _joins_pieces(points: np.ndarray, plane: Plane) -> bool:
    """Whether ``plane``'s inliers join pieces of (n, 3) ``points`` that are apart without them
    (a floor under several objects)."""
    return _pieces(points[~plane.inliers]) > _pieces(points)


def support_plane(points: np.ndarray, *, up: np.ndarray | None = None, seed: int = 0) -> Plane | None:
    """The plane the object(s) of (n, 3) ``points`` stand on, oriented with them on its positive
    side, or None (see the module docstring). ``up``: a known up direction (depth frames)."""
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 50:
        return None
    tol = plane_tolerance(pts)
    # a frame's floor is often a strip under walls and furniture: look further for it
    more = {} if up is None else {"min_share": FRAME_FLOOR_SHARE, "max_planes": FRAME_PLANES}
    for plane in find_planes(pts, tol, seed=seed, **more):
        rest = ~plane.inliers
        share = plane.inliers.mean()
        if share > MAX_SUPPORT_SHARE or rest.sum() < 20:
            continue
        d = plane.distance(pts[rest])
        if (d > 0).mean() < 0.5:
            plane, d = plane.flipped(), -d
        if up is not None:
            if plane.normal @ up < FRAME_UP_COS:
                continue
            if (d > -tol).mean() >= ONE_SIDED - 0.05:
                return plane
            continue  # a desk top: things below it
        if (d > -tol).mean() < ONE_SIDED:
            continue
        width = _outline_area(pts[plane.inliers], plane.normal) / max(
            _outline_area(pts[rest], plane.normal), 1e-300)
        if width < UNDER:  # too small to carry what stands on it (a flat bit of the object)
            continue
        if width >= WIDER or _joins_pieces(pts, plane):
            return plane
        if ((d > tol) & (d <= 4 * tol)).sum() <= SEPARATE * plane.inliers.sum():
            return plane
    return None


def _spans(wall: np.ndarray, frame: np.ndarray, normal: np.ndarray) -> bool:
    """Whether the (m, 3) points of a wall of ``normal`` span at least :data:`WALL_SPAN` of the
    (n, 3) ``frame``'s extent along both of the wall's principal in-plane axes."""
    u, v = plane_basis(normal)
    flat = np.stack([wall @ u, wall @ v], axis=1)
    axes = np.linalg.svd(flat - flat.mean(axis=0), full_matrices=False)[2]  # (2, 2) rows
    in_plane = axes @ np.stack([u, v])  # (2, 3): the principal axes in 3D
    return bool(np.all(np.ptp(wall @ in_plane.T, axis=0) >= WALL_SPAN * np.ptp(frame @ in_plane.T, axis=0)))


def wall_face(points: np.ndarray, plane: Plane) -> dict:
    """The least-area rectangle on ``plane`` that holds its (n, 3) ``points`` projected onto it
    (one side along an edge of their convex hull, rotating calipers): {"center": (3,), "axes":
    (2, 3) unit, in-plane, the second the normal x the first, "extents": (2,) full side
    lengths}, JSON-able. A wall's box is built on it: the box of the points' coordinates would
    stand out of an oblique wall."""
    from scipy.spatial import ConvexHull, QhullError

    n = plane.normal / np.linalg.norm(plane.normal)
    flat = points - np.outer(plane.distance(points), n)  # onto the plane
    mean = flat.mean(axis=0)
    basis = np.stack(plane_basis(n))
    uv = (flat - mean) @ basis.T
    try:
        ring = uv[ConvexHull(uv).vertices]
    except QhullError:  # collinear or too few: any rectangle of the coordinates will do
        ring = uv
    edges = np.roll(ring, -1, axis=0) - ring
    angles = np.arctan2(edges[:, 1], edges[:, 0])
    best = None
    for t in angles:
        rot = np.array([[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]])  # rows: the sides
        proj = ring @ rot.T
        lo, hi = proj.min(axis=0), proj.max(axis=0)
        if best is None or np.prod(hi - lo) < best[0]:
            best = (float(np.prod(hi - lo)), rot, lo, hi)
    _, rot, lo, hi = best
    u = rot[0] @ basis
    v = np.cross(n, u)
    center = mean + ((lo + hi) / 2) @ np.stack([u, rot[1] @ basis])
    return {"center": np.round(center, 9).tolist(), "axes": np.round(np.stack([u, v]), 9).tolist(),
            "extents": np.round(hi - lo, 9).tolist()}


def walls(points: np.ndarray, sensor: np.ndarray, *, frame: np.ndarray | None = None,
          up: np.ndarray | None = None, seed: int = 0) -> list[Plane]:
    """The walls of a depth frame's (n, 3) ``points`` seen from (3,) ``sensor``, largest first,
    each oriented towards the sensor, its ``inliers`` over ``points`` (see the module docstring).
    ``frame``: all the frame's points (default ``points``), for its extent. ``up``: (3,), a
    plane facing it (within :data:`FRAME_UP_COS`) is a table or a box's top, never a wall.
    Planes are looked for again after each search's walls are taken out, at most
    :data:`MAX_WALLS` walls."""
    pts = np.asarray(points, dtype=np.float64)
    every = pts if frame is None else np.asarray(frame, dtype=np.float64)
    free = np.ones(len(pts), dtype=bool)
    found: list[Plane] = []
    if len(pts) < 50:
        return found
    tol = plane_tolerance(pts)
    while len(found) < MAX_WALLS and free.sum() >= 50:
        idx = np.flatnonzero(free)
        taken = 0
        for plane in find_planes(pts[idx], tol, min_share=WALL_SHARE, seed=seed + len(found)):
            if len(found) == MAX_WALLS:
                break
            if free[idx[plane.inliers]].mean() <= 0.5:  # in the band of a wall taken this search
                continue
            if plane.distance(sensor[None])[0] < 0:
                plane = plane.flipped()
            if up is not None and plane.normal @ up >= FRAME_UP_COS:  # a floor, a table
                continue
            away = float(plane.distance(sensor[None])[0])
            band = max(tol, WALL_NOISE * away)
            # judged on the search's points, walls taken in it included (that is stricter)
            rest = plane.distance(pts[idx]) > band
            behind = plane.distance(pts[idx[~plane.inliers]]) < -band - WALL_DEPTH * away
            if rest.sum() < 20 or 1.0 - behind.mean() < ONE_SIDED:
                continue
            area = _outline_area(pts[idx[plane.inliers]], plane.normal)
            if area < WALL_AREA * _outline_area(pts[idx[rest]], plane.normal) or not _spans(
                    pts[idx[plane.inliers]], every, plane.normal):
                continue
            on = np.zeros(len(pts), dtype=bool)
            # the wall's band (depth noise spreads it) and whatever lies behind it
            on[idx] = (plane.distance(pts[idx]) <= band) & free[idx]
            found.append(Plane(plane.normal, plane.offset, on, band))
            free &= ~on
            taken += 1
        if not taken:
            break
    return found


def isolate(points: np.ndarray, mode: str = "all", *, crop: np.ndarray | None = None,
            up: np.ndarray | None = None, sensor: np.ndarray | None = None,
            seed: int = 0) -> Isolation:
    """Which of (n, 3) ``points`` are the object(s).

    Parameters
    ----------
    points : (n, 3) float
    mode : {"all", "largest", "none"}
        "all": remove the support plane and the clutter pieces, keep every piece of at least
        :data:`CLUTTER_SHARE` of the largest; "largest": keep the largest piece only; "none":
        keep everything (but ``crop``).
    crop : (2, 3) float, optional
        Keep only the points inside this box (its min and max corners), first.
    up : (3,) float, optional
        A known up direction (an organised depth frame's image up).
    sensor : (3,) float, optional
        Where the sensor stood (a depth frame's viewpoint): its frame's walls are removed too
        (:func:`walls`).
    seed : int
    """
    pts = np.asarray(points, dtype=np.float64)
    keep = np.ones(len(pts), dtype=bool)
    result = Isolation(keep)
    if crop is not None:
        lo, hi = np.asarray(crop, dtype=np.float64).reshape(2, 3)
        inside = np.all((pts >= lo) & (pts <= hi), axis=1)
        result.removed["crop"] = int((~inside).sum())
        keep &= inside
    if mode == "none" or keep.sum() < 50:
        return result
    idx = np.flatnonzero(keep)
    framed = keep.copy()  # the frame (inside the crop), for the walls' extent
    plane = support_plane(pts[idx], up=up, seed=seed)
    if plane is not None:
        # the plane's band (depth noise spreads it) and whatever lies under it
        on = plane.inliers | (plane.distance(pts[idx]) < SUPPORT_BAND * plane.tolerance)
        full = np.zeros(len(pts), dtype=bool)
        full[idx] = plane.inliers
        result.support = Plane(plane.normal, plane.offset, full, plane.tolerance)
        result.up = plane.normal.copy()
        result.removed["support"] = int(on.sum())
        keep[idx[on]] = False
        idx = idx[~on]
    if sensor is not None and len(idx):
        for wall in walls(pts[idx], np.asarray(sensor, dtype=np.float64), frame=pts[framed],
                          up=result.up if result.up is not None else up, seed=seed):
            on = pts[idx[wall.inliers]]
            result.walls.append((wall, np.stack([on.min(axis=0), on.max(axis=0)]), wall_face(on, wall)))
            keep[idx[wall.inliers]] = False
        result.removed["walls"] = int(len(idx) - keep[idx].sum())
        idx = idx[keep[idx]]
    if len(idx) == 0:
        return result
    labels = components(pts[idx])
    sizes = np.bincount(labels)
    wanted = np.zeros(len(sizes), dtype=bool)
    if mode == "largest":
        wanted[0] = True
    else:
        wanted = sizes >= CLUTTER_SHARE * sizes[0]
    drop = ~wanted[labels]
    result.removed["clutter"] = int(drop.sum())
    result.pieces = int(wanted.sum())
    keep[idx[drop]] = False
    result.labels = np.full(len(pts), -1, dtype=np.int64)
    result.labels[idx[~drop]] = labels[~drop]
    return result
