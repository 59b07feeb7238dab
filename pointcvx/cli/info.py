"""``pointcvx info``: load any input and report what was detected."""

from __future__ import annotations

import argparse
import json

from ..flags import add_flags, options_from_args
from ..options import LoadOptions


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "info",
        help="load any input and report what was detected",
        description="Load PATH (mesh, CAD, splat or scan; the format is sniffed from the content), "
        "print what was detected (modality, format, counts, bounding box, how normals were "
        "obtained, what was filtered) and optionally write the oriented cloud as a PLY.",
    )
    p.add_argument("path", help="input file: OBJ/PLY/STL/OFF/GLB/GLTF mesh, STEP/IGES part, "
                                "INRIA/compressed PLY, SPZ or .splat splat, PLY/PCD/XYZ/PTS/LAS scan")
    p.add_argument("-o", "--output", metavar="OUT.ply",
                   help="write the oriented cloud (points, normals, colours) to this PLY")
    p.add_argument("--normalized", action="store_true",
                   help="write OUT.ply in the normalised [-1, 1]^3 frame instead of input units")
    p.add_argument("--overwrite", action="store_true", help="replace OUT.ply if it exists")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("-q", "--quiet", action="store_true",
                   help="print nothing but errors (and the report, with --json)")
    p.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    add_flags(p, LoadOptions)
    p.set_defaults(func=run)
    return p


def report(cloud) -> dict:
    """What ``info`` prints about a loaded cloud (JSON-able)."""
    import numpy as np

    lo, hi = cloud.in_input_units().bounds if not cloud.normalization.is_identity else cloud.bounds
    info = dict(cloud.info)
    out = {
        "source": info.pop("source", None),
        "modality": cloud.modality,
        "format": info.pop("format", None),
        "points": len(cloud),
        "bbox_min": np.round(lo, 6).tolist(),
        "bbox_max": np.round(hi, 6).tolist(),
        "normalization": {
            "center": np.round(cloud.normalization.center, 6).tolist(),
            "scale": round(float(cloud.normalization.scale), 9),
        },
        "has_colors": cloud.colors is not None,
        "has_mesh": cloud.mesh is not None,
    }
    out.update(info)
    return out


def run(args: argparse.Namespace) -> int:
    from ..io import load, save_cloud
    from ..io.files import check_writable

    opts = options_from_args(args, LoadOptions)
    out = check_writable(args.output, [args.path], args.overwrite) if args.output else None
    cloud = load(args.path, opts)
    rep = report(cloud)
    if out is not None:
        save_cloud(cloud if args.normalized else cloud.in_input_units(), out)
        rep["written"] = str(out)
    if args.quiet and not args.json:  # --json asks for the report: it is printed even with -q
        return 0
    if args.json:
        print(json.dumps(rep, indent=2, default=str))
    else:
        width = max(len(k) for k in rep)
        for key, value in rep.items():
            print(f"{key:<{width}}  {value}")
    return 0
