"""Hulls grounded on the support plane a capture stood on.

Isolation removes the support plane (floor, table, the ground under a captured object) with
its band, and with it whatever of the objects lay in the band (:mod:`pointcvx.scene.isolate`):
the hulls of what stood there end about a band's height above the plane, and in a simulator the
object drops onto it. A hull rests on the plane when its lowest vertex is at most
:data:`RESTING_BANDS` bands above it; its vertices within one band of that lowest one (its
base) are repeated on the plane, moved down along its normal, and the hull is taken again: a
slab under its base, down to the plane. No hull is added and no piece changes (the samples of
``close_bases="on"``, :mod:`pointcvx.scene.base`, change both); the concavity of each hull stays
what the split measured on the points.

A scene's object that neither reaches the support nor lies on another object (a shelf on a
wall, a ceiling lamp, a chair whose legs the sensor missed), or one whose centre of mass is not
over where it touches them (a board leaning on a wall, a person seen from the front only), is
held by something the capture does not show: it stood still when captured. :func:`resting_on`
says which, and the scene exports make such an object a static body, so it stays where it was
seen instead of falling or tipping over.
"""

from __future__ import annotations

import numpy as np

#: A hull rests on the support when its lowest vertex is at most this many bands above it (the
#: bases of what stood on the floor of the raw_scans/ frames end 1.0-1.06 bands above it).
RESTING_BANDS = 2.5


def grounded_vertices(vertices: np.ndarray, normal: np.ndarray, offset: float,
                      band: float) -> np.ndarray | None:
    """The (v, 3) float ``vertices`` of a hull and its base moved down onto the plane
    ``normal . x = offset`` ((3,) float unit ``normal`` towards the objects), as (v + b, 3)
    float points to take the hull of; None when the hull does not rest on the plane (its lowest
    vertex below it, or more than :data:`RESTING_BANDS` ``band`` above it).

    ``band``: the height above the plane up to which isolation removed points, in the
    vertices' units."""
    v = np.asarray(vertices, dtype=np.float64)
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    if len(v) == 0 or not band > 0:
        return None
    height = v @ n - offset
    low = float(height.min())
    if low <= 0.0 or low > RESTING_BANDS * band:
        return None
    base = v[height <= low + band]
    return np.concatenate([v, base - np.outer(base @ n - offset, n)])


def centre_of_mass(hulls: list[np.ndarray]) -> np.ndarray | None:
    """(3,) float centre of the solid hulls of an object (each given by its (v_i, 3) float
    vertices; overlaps counted once per hull, as an engine summing its geoms does), or None
    when they hold no volume."""
    from .hull import convex_hull

    total, moment = 0.0, np.zeros(3)
    for v in hulls:
        if len(v) < 4:
            continue
        h = convex_hull(v)
        if h.dim < 3 or not h.volume > 0:
            continue
        tri = h.vertices[h.faces]
        apex = h.vertices.mean(axis=0)
        a, b, c = tri[:, 0] - apex, tri[:, 1] - apex, tri[:, 2] - apex
        vol = np.abs(np.einsum("ij,ij->i", a, np.cross(b, c))) / 6
        total += float(vol.sum())
        moment += (vol[:, None] * (tri.sum(axis=1) + apex) / 4).sum(axis=0)
    return moment / total if total > 0 else None


def over_base(centre: np.ndarray, contact: np.ndarray, normal: np.ndarray) -> bool:
    """Whether the (3,) ``centre`` of mass lies over the (m, 3) ``contact`` points (inside or on
    their convex outline seen along the unit ``normal``): an object that stands there without
    tipping over."""
    from scipy.spatial import ConvexHull, QhullError

    from .hull import plane_basis

    if len(contact) < 3:
        return False
    u, v = plane_basis(normal)
    flat = np.stack([contact @ u, contact @ v], axis=1)
    try:
        outline = ConvexHull(flat)
    except QhullError:  # the contact is a line or a point: nothing stands on it
        return False
    c = np.array([centre @ u, centre @ v])
    extent = float(np.ptp(flat, axis=0).max())
    return bool((outline.equations[:, :2] @ c + outline.equations[:, 2] <= 1e-9 * extent).all())


def resting_on(objects: list[list[np.ndarray]], normal: np.ndarray, offset: float, band: float,
               support: bool = True) -> list[tuple[str | int | None, bool]]:
    """What each object of a scene rests on, and whether it stands there: per object
    (``"support"`` (the plane ``normal . x = offset``, (3,) float ``normal`` towards the
    objects), the index of the object it lies on, or None: held by something out of view;
    whether its centre of mass is over where it touches that (False for None)).

    ``objects``: per object, the (v_i, 3) float vertex arrays of its hulls, in the plane's
    units. An object rests on the support when its lowest vertex is at most
    :data:`RESTING_BANDS` ``band`` above the plane (``support``: whether the plane is a real
    support; False for an up direction without one, which nothing rests on), touching it with
    its base (its vertices within one ``band`` of its lowest); else on the objects starting
    lower than it that it touches (:func:`within` :data:`RESTING_BANDS` ``band``): its base
    vertices on their hulls and their vertices at its base's height under its hulls (a table
    top on a narrower pedestal, a plank across two boxes), named by the one with the most
    contact points, standing if its centre is over all of them. Objects that float together:
    the lowest of them is held, the others rest on it."""
    from .hull import convex_hull

    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    gap = RESTING_BANDS * float(band)
    verts = [[np.asarray(v, dtype=np.float64).reshape(-1, 3) for v in hulls] for hulls in objects]
    heights = [[v @ n - offset for v in hulls] for hulls in verts]
    lows = [min((float(h.min()) for h in hs if len(h)), default=np.inf) for hs in heights]
    out: list[tuple[str | int | None, bool]] = [(None, False)] * len(objects)
    # Solid and flat hulls (the exports grow a flat one into a slab): what can be touched.
    solids = [[h for h in (convex_hull(v) for v in hulls if len(v) >= 3) if h.dim >= 2] for hulls in verts]
    order = np.argsort(lows, kind="stable")  # lowest first
    for k in order:
        if not np.isfinite(lows[k]):
            continue
        base = np.concatenate([v[h <= lows[k] + band] for v, h in zip(verts[k], heights[k], strict=True)])
        on, contact = None, base
        if support and lows[k] <= gap:
            on = "support"
        else:  # every lower object it touches: its base on their hulls, their tops under its hulls
            touched, pieces = [], []
            for j in order:
                if not lows[j] < lows[k]:
                    break  # the rest start no lower than it (itself included)
                mine = base[within(solids[j], base, gap)]
                top = np.concatenate([v[(h >= lows[k] - gap) & (h <= lows[k] + band)]
                                      for v, h in zip(verts[j], heights[j], strict=True)])
                theirs = top[within(solids[k], top, gap)]
                if len(mine) + len(theirs):
                    touched.append((len(mine) + len(theirs), -len(touched), int(j)))
                    pieces += [mine, theirs]
            if touched:
                on, contact = max(touched)[2], np.concatenate(pieces)
        if on is not None:
            centre = centre_of_mass(objects[k])
            out[k] = (on, centre is not None and over_base(centre, contact, n))
    return out


def within(hulls: list, points: np.ndarray, reach: float) -> np.ndarray:
    """(m,) bool: which of (m, 3) ``points`` lie inside one of ``hulls`` (Polytopes) or within
    about ``reach`` of one: the largest signed plane distance (a lower bound of the distance
    outside, short beyond a sharp edge) at most ``reach``, inside the hull's box grown by
    ``reach`` (which bounds the distance by sqrt(3) ``reach``)."""
    from .hull import signed_plane_distance
    from .tree import in_box

    near = np.zeros(len(points), dtype=bool)
    columns = points.T
    for h in hulls:
        if not len(points):
            break
        lo, hi = h.vertices.min(axis=0) - reach, h.vertices.max(axis=0) + reach
        boxed = np.flatnonzero(in_box(columns, lo, hi))
        if len(boxed):
            near[boxed[signed_plane_distance(h, points[boxed]) <= reach]] = True
    return near


def scene_rests(info: dict, points: np.ndarray, objects: list[list[np.ndarray]]) -> list | None:
    """:func:`resting_on` (per object: what it rests on, whether it stands there) for a scene's
    ``objects`` (per object, its hulls' (v_i, 3) float vertex arrays) with the support its
    isolation removed (``info``: the scene cloud's), else with its up direction alone (a depth
    frame with no floor in view: nothing rests on the ground) and a band of a plane's tolerance
    of the (n, 3) ``points`` (the scene's, the hulls' units); None
    when the scene has no up direction."""
    from ..scene.isolate import SUPPORT_BAND, plane_tolerance

    found = support_band(info)
    if found is not None:
        return resting_on(objects, *found)
    up = info.get("up")
    if up is None or len(points) < 2:
        return None
    return resting_on(objects, np.asarray(up, dtype=np.float64), 0.0,
                      SUPPORT_BAND * plane_tolerance(points), support=False)


def support_band(info: dict) -> tuple[np.ndarray, float, float] | None:
    """(unit normal (3,), offset, band) of the support plane a cloud's isolation removed, in
    input units, from its ``info`` (``cloud.info``); None without one."""
    from ..scene.isolate import SUPPORT_BAND

    plane = (info.get("isolation") or {}).get("support_plane")
    if not plane:
        return None
    return (np.asarray(plane["normal"], dtype=np.float64), float(plane["offset"]),
            SUPPORT_BAND * float(plane["tolerance"]))
