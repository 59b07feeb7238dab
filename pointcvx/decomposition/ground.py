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


def support_band(info: dict) -> tuple[np.ndarray, float, float] | None:
    """(unit normal (3,), offset, band) of the support plane a cloud's isolation removed, in
    input units, from its ``info`` (``cloud.info``); None without one."""
    from ..scene.isolate import SUPPORT_BAND

    plane = (info.get("isolation") or {}).get("support_plane")
    if not plane:
        return None
    return (np.asarray(plane["normal"], dtype=np.float64), float(plane["offset"]),
            SUPPORT_BAND * float(plane["tolerance"]))
