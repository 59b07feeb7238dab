"""A scene capture split into its objects: the connected pieces of the isolated cloud, each to be
decomposed on its own (:func:`pointcvx.decompose` with ``scene``)."""

from __future__ import annotations

import numpy as np

from ..cloud import OrientedCloud
from .components import components
from .isolate import CLUTTER_SHARE

#: An object needs at least this many points to be decomposed (smaller pieces are left out).
MIN_OBJECT_POINTS = 32


def object_pieces(points: np.ndarray) -> list[np.ndarray]:
    """Index arrays of the objects of (n, 3) ``points``, largest first: the connected pieces of at
    least :data:`CLUTTER_SHARE` of the largest and :data:`MIN_OBJECT_POINTS` points."""
    labels = components(points)
    sizes = np.bincount(labels) if len(labels) else np.zeros(0, dtype=np.int64)
    return [np.flatnonzero(labels == k) for k in range(len(sizes))
            if sizes[k] >= max(MIN_OBJECT_POINTS, CLUTTER_SHARE * sizes[0])]


#: Modalities that ``scene="auto"`` may decompose as scenes (meshes and CAD parts stay one object,
#: whatever their components).
SCENE_MODALITIES = ("splat", "scan")


def may_be_scene(cloud: OrientedCloud, mode: str) -> bool:
    """Whether ``cloud``'s pieces must be found to decide (:func:`is_scene`)."""
    return mode == "on" or (mode == "auto" and cloud.modality in SCENE_MODALITIES)


def is_scene(cloud: OrientedCloud, mode: str, pieces: list[np.ndarray]) -> bool:
    """Whether ``cloud`` is decomposed as a scene: ``mode`` "on"/"off", or "auto": a splat or scan
    that is an organised depth frame (a view of a room or a desk) or whose isolation kept several
    objects."""
    if mode != "auto":
        return mode == "on"
    if cloud.modality not in SCENE_MODALITIES:
        return False
    return bool(cloud.info.get("organized")) or len(pieces) > 1
