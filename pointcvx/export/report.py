"""The JSON report of a decomposition: per hull counts, volume, added volume, concavity and how
far it reaches out of the input (``max_offset``, input units); totals; a scene's objects and
support plane; what isolation removed; parameters; seed; timings."""

from __future__ import annotations

import json
from typing import Any


def report(result) -> dict[str, Any]:
    """The JSON report of a :class:`~pointcvx.result.Decomposition` (input units for volumes)."""
    from ..version import __version__

    hulls = []
    offsets = result.hull_offsets()
    for i, h in enumerate(result.hulls):
        volume = h.volume
        hulls.append({"name": f"hull_{i:03d}", "vertices": int(len(h.vertices)),
                      "faces": int(len(h.faces)), "volume": volume,
                      "added_volume": float(h.added_volume), "concavity": float(h.concavity),
                      "points": int(h.n_points), "max_offset": float(offsets[i])})
    volume = float(sum(h["volume"] for h in hulls))
    added = float(sum(h["added_volume"] for h in hulls))
    totals = {"hulls": len(hulls), "vertices": int(sum(h["vertices"] for h in hulls)),
              "faces": int(sum(h["faces"] for h in hulls)),
              "max_hull_vertices": int(max((h["vertices"] for h in hulls), default=0)),
              "volume": volume, "added_volume": added,
              "added_volume_ratio": added / (volume - added) if volume - added > 0 else 0.0,
              "max_concavity": float(result.max_concavity),
              "mean_concavity": float(result.concavity.mean()) if hulls else 0.0,
              "points": int(len(result.labels)),
              "noise_points": int(result.cloud.info.get("noise_points", 0)),
              "air_points": int(result.cloud.info.get("air_points", 0)),
              "grounded_hulls": int(result.cloud.info.get("grounded_hulls", 0)),
              "static_objects": int(sum(bool(o.get("static")) for o in result.objects or [])),
              "max_offset": float(offsets.max()) if len(offsets) else 0.0}
    extra = {}
    if result.objects:
        extra["objects"] = result.objects
    if result.support:
        extra["support_plane"] = result.support
    if result.cloud.info.get("up") is not None:
        extra["up_detected"] = result.cloud.info["up"]
    if "isolation" in result.cloud.info:
        extra["isolation"] = {k: v for k, v in result.cloud.info["isolation"].items() if k != "support_plane"}
    return {"pointcvx": __version__, "source": result.cloud.info.get("source"), "units": "input",
            "hulls": hulls, "totals": totals, "limits": result.params.get("hull_limits"),
            "parameters": {k: v for k, v in result.params.items() if k != "hull_limits"},
            "seed": result.seed, "timings": dict(result.timings), **extra}


def report_text(result) -> str:
    return json.dumps(report(result), indent=2, default=str) + "\n"
