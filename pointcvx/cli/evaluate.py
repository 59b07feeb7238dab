"""``pointcvx evaluate``: score a decomposition against its shape (the paper's protocol)."""

from __future__ import annotations

import argparse
import json


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "evaluate",
        help="score a decomposition against its shape (the paper's protocol)",
        description="Score HULLS (an OBJ with one object per hull, or any mesh file whose "
        "connected components are the hulls) against MESH, both normalised to [-1,1]^3 by "
        "MESH's bounding box: number of hulls; concavity = max over hulls of CoACD's concavity of "
        "MESH ∩ hull (20,000 samples per component); reconstruction = Chamfer distance between "
        "MESH and the union of hulls (20,000 samples); volume IoU; share of MESH's surface "
        "covered by the hulls.",
    )
    p.add_argument("mesh", help="the original shape (a mesh file)")
    p.add_argument("hulls", help="the hulls (OBJ with one 'o' per hull, or a multi-body mesh)")
    p.add_argument("--samples", type=int, default=20000, help="samples per surface (20000)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from ..evaluate import evaluate_files

    report = evaluate_files(args.mesh, args.hulls, n_samples=args.samples, seed=args.seed)
    if args.json:
        print(json.dumps(report, indent=2, default=float))
    else:
        for key in ("hulls", "concavity", "reconstruction", "iou", "coverage", "seconds"):
            if key in report:
                value = report[key]
                print(f"{key:<15} {value:.5f}" if isinstance(value, float) else f"{key:<15} {value}")
    return 0
