"""Captures as scenes: support planes (:mod:`.planes`), connected pieces (:mod:`.components`),
and the object freed from its surroundings (:mod:`.isolate`); :func:`isolate_cloud` applies it to
a loaded cloud."""

from __future__ import annotations

import numpy as np

from ..cloud import OrientedCloud
from .base import base_samples
from .components import components
from .isolate import SUPPORT_BAND, Isolation, isolate, support_plane, walls
from .planes import Plane, find_planes, fit_plane, ransac_plane

__all__ = ["Isolation", "Plane", "base_samples", "components", "find_planes", "fit_plane", "frame_sensor",
           "isolate", "isolate_cloud", "ransac_plane", "support_plane", "walls", "with_closed_bases"]

#: Modalities that ``isolate="auto"`` frees from their surroundings.
ISOLATED_MODALITIES = ("splat", "scan")
#: The image's up direction in an organised depth frame's sensor coordinates (rows go down).
FRAME_UP = np.array([0.0, -1.0, 0.0])


def resolve_mode(mode: str, modality: str) -> str:
    """What ``isolate=mode`` means for a cloud of ``modality``: "auto" is "all" on splats and
    scans, "none" on meshes, CAD parts and in-memory points."""
    if mode != "auto":
        return mode
    return "all" if modality in ISOLATED_MODALITIES else "none"


def frame_sensor(info: dict) -> np.ndarray | None:
    """(3,) float: where the sensor of an organised depth frame stood (its ``viewpoint``'s
    translation; a PCD without one was taken at the origin), None for any other cloud."""
    if not info.get("organized"):
        return None
    return np.asarray(info.get("viewpoint", [0.0] * 7)[:3], dtype=np.float64)


def isolate_cloud(cloud: OrientedCloud, mode: str = "auto", crop=None, seed: int = 0,
                  close_bases: bool = False) -> OrientedCloud:
    """``cloud`` (in its current coordinates) with its surroundings removed (:func:`isolate`):
    the kept points, ``cloud.removed`` holding the others, ``cloud.info["isolation"]`` saying
    what was removed and why, and ``cloud.info["up"]`` the support plane's normal when found (in a
    depth frame without one, the image's up). With ``close_bases``, what rested on the support
    has its base closed down to it (:func:`with_closed_bases`)."""
    mode = resolve_mode(mode, cloud.modality)
    if mode == "none" and crop is None:
        return cloud
    sensor = frame_sensor(cloud.info)
    frame = sensor is not None
    up = FRAME_UP if frame else None
    found = isolate(cloud.points, mode, crop=None if crop is None else np.reshape(crop, (2, 3)),
                    up=up, sensor=sensor, seed=seed)
    if found.keep.all():
        out = cloud.replace()
    else:
        out = cloud.subset(found.keep)
        gone = cloud.points[~found.keep]
        out.removed = gone if cloud.removed is None else np.concatenate([cloud.removed, gone])
    out.info["isolation"] = {"mode": mode, **found.report()}
    if close_bases and found.support is not None and found.labels is not None and out.mesh is None:
        out = with_closed_bases(out, found.labels[found.keep], found.support,
                                SUPPORT_BAND * found.support.tolerance)
    if found.up is not None:
        out.info["up"] = np.round(found.up, 6).tolist()
    elif frame:  # no floor in view (a wall seen straight on): the image's up
        out.info["up"] = FRAME_UP.tolist()
    return out


def with_closed_bases(cloud: OrientedCloud, labels: np.ndarray, plane: Plane, band: float) -> OrientedCloud:
    """``cloud`` with the bases of its pieces that rest on ``plane`` closed (:func:`base_samples`):
    the samples appended, each with the colour and weight of the point it was made from, and
    ``cloud.info["isolation"]["base"]`` counting them (``points``, ``objects``)."""
    pts, nrm, src = base_samples(cloud.points, cloud.normals, labels, plane, band)
    if len(pts) == 0:
        return cloud

    def grow(a):
        return None if a is None else np.concatenate([a, a[src]])

    out = cloud.replace(points=np.concatenate([cloud.points, pts]),
                        normals=np.concatenate([cloud.normals, nrm]),
                        colors=grow(cloud.colors), weights=grow(cloud.weights),
                        face_index=grow(cloud.face_index))
    out.info["isolation"] = {**cloud.info["isolation"],
                             "base": {"points": int(len(pts)), "objects": int(len(np.unique(labels[src])))}}
    return out
