"""Decompose every shape of a folder with pointcvx and score it with the paper's protocol.

    python tools/eval_dataset.py ../shared/data/vhacd61 -o docs/results/vhacd61.csv \
        [--threshold 0.1] [--max-hulls 64] [--jobs 2] [--limit N] [--split auto] \
        [--features optimize|model|auto] [--model CKPT] [--subsurface 0.05] [--band auto|on|off] \
        [--seam-variants]

Each shape runs in its own worker process (``--jobs`` at a time). For each shape: the time of
``pointcvx.decompose`` (features + splitting + merge + hulls) and the metrics of
``pointcvx.evaluate.evaluate`` (hull count, concavity, Chamfer reconstruction, volume IoU,
coverage) on the shape normalised to [-1, 1]^3. Every format pointcvx reads is taken: meshes
and CAD parts are scored against their surface; splats and point clouds, which have no closed
surface, with ``pointcvx.evaluate.evaluate_points`` (reconstruction and coverage against the
loaded points; concavity is then the decomposer's own estimate, ``internal_max``), unless
``--truth DIR`` holds the true mesh of each input (same stem; ``tools/synthetic_splats.py``):
then every input is scored against its true mesh. With ``--seam-variants`` the same
decomposition is also scored with the seams along its cuts made otherwise than
``pointcvx.decomposition.seams`` makes them (:func:`seam_variant_hulls`: ``open_*``,
``points_*`` and ``allmid_*`` columns). Writes one CSV row per shape and prints a markdown
summary (means and medians).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

SKIP_SUFFIXES = {".md", ".txt", ".json", ".csv", ".urdf", ".mtl", ".png", ".jpg", ".npy"}


def shape_names(files: list[str]) -> dict[str, str]:
    """File -> row name: its stem, or its whole name where two files share a stem (biker.ply and
    biker.spz)."""
    stems = [Path(f).stem for f in files]
    return {f: (Path(f).name if stems.count(s) > 1 else s) for f, s in zip(files, stems, strict=True)}


def run_one(path: str, opts: dict, name: str | None = None, truth: str | None = None,
            seam_variants: bool = False) -> dict:
    import torch

    torch.set_num_threads(1)
    import pointcvx
    from pointcvx.evaluate import evaluate, evaluate_points
    from pointcvx.io.mesh import read_mesh

    row = {"shape": name or Path(path).stem}
    try:
        t = time.perf_counter()
        result = pointcvx.decompose(path, **opts)
        row["seconds"] = round(time.perf_counter() - t, 3)
        for key in ("features", "split", "merge", "solid"):
            row[f"t_{key}"] = round(result.timings.get(key, 0.0), 3)
        hulls = [h.vertices for h in result.hulls]
        cloud = pointcvx.load(path, normalize=False, seed=opts.get("seed", 0))
        row["modality"] = cloud.modality
        if truth is not None:  # a synthetic input made from a known solid, in the same frame
            mesh = read_mesh(truth, pointcvx.detect(truth).format)
        elif cloud.modality == "mesh":
            mesh = read_mesh(path, pointcvx.detect(path).format)
        else:
            mesh = cloud.mesh  # CAD: the tessellation; splats and scans: None
        def score(vertices: list) -> dict:
            if mesh is not None:
                ev = evaluate(mesh, vertices)
                out = dict(concavity=round(ev["concavity"], 5), iou=round(ev["iou"], 4),
                           eval_seconds=round(ev["seconds"], 2))
            else:
                ev = evaluate_points(cloud.points, vertices)
                out = dict(concavity=round(result.max_concavity, 5), outside_max=round(ev["outside_max"], 4))
            return {**out, "hulls": ev["hulls"], "reconstruction": round(ev["reconstruction"], 5),
                    "coverage": round(ev["coverage"], 4)}

        row.update(score(hulls), internal_max=round(result.max_concavity, 5))
        if seam_variants:
            for prefix, vertices in seam_variant_hulls(result).items():
                row.update({f"{prefix}_{k}": v for k, v in score(vertices).items() if k != "eval_seconds"})
    except Exception as exc:  # noqa: BLE001 - a benchmark records failures and goes on
        row["error"] = f"{type(exc).__name__}: {exc}"
    return row


def seam_variant_hulls(result) -> dict[str, list]:
    """The hulls of ``result``'s parts (a :class:`pointcvx.Decomposition`) with the seams made
    otherwise than the default's midpoints across seams within one face, in the input's units:
    ``open`` (each part's own points alone), ``points`` (its own points and the points of its
    seam pairs' other ends, edges too) and ``allmid`` (the midpoints of every seam pair, edges
    too); {prefix: list of (m, 3) float hull vertices}, or {} for a scene (each object's parts
    have their own spacing)."""
    import numpy as np

    from pointcvx.decomposition.hull import convex_hull
    from pointcvx.decomposition.seams import seam_pairs, seam_points

    if result._decomposer is None:  # a scene: objects decomposed apart (result.merge_parts)
        return {}
    cloud, labels = result.cloud, result.labels  # the hulls' frame
    spacing = result._decomposer.spacing
    a, b = seam_pairs(cloud.points, cloud.normals, labels, spacing, crease_degrees=180.0)
    allmid = seam_points(cloud.points, cloud.normals, labels, spacing, crease_degrees=180.0)
    sets: dict[str, list] = {"open": [], "points": [], "allmid": allmid}
    for i in range(len(result.hulls)):
        own = labels == i
        sets["open"].append(cloud.points[own])
        across = np.union1d(b[labels[a] == i], a[labels[b] == i])
        sets["points"].append(cloud.points[np.union1d(np.flatnonzero(own), across)])
    back = cloud.normalization
    return {k: [back.inverse(convex_hull(v).vertices) for v in hulls] for k, hulls in sets.items()}


def truth_file(folder: str, path: str) -> str:
    """The one file in ``folder`` with the stem of ``path`` (any mesh format; SystemExit when
    there is none or more than one)."""
    stem = Path(path).stem
    found = sorted(p for p in Path(folder).iterdir()
                   if p.is_file() and p.stem == stem and p.suffix.lower() not in SKIP_SUFFIXES)
    if len(found) != 1:
        what = "no" if not found else f"{len(found)} candidate"
        raise SystemExit(f"{what} true mesh for {path} in {folder}: {[p.name for p in found]}")
    return str(found[0])


def summarize(rows: list[dict]) -> str:
    import numpy as np

    ok = [r for r in rows if "error" not in r]
    lines = ["| metric | mean | median |", "|---|---|---|"]
    keys = ("hulls", "concavity", "reconstruction", "iou", "coverage", "t_features", "seconds")
    variants = tuple(f"{p}_{k}" for p in ("open", "points", "allmid") for k in keys[:5])
    for key in keys + variants:
        vals = np.array([r[key] for r in ok if key in r], dtype=float)
        if len(vals):
            lines.append(f"| {key} | {vals.mean():.4f} | {np.median(vals):.4f} |")
    lines.append(f"\n{len(ok)} of {len(rows)} shapes decomposed without error.")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from pointcvx.options import BAND_MODES

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folder")
    ap.add_argument("-o", "--output", required=True, help="CSV to write")
    ap.add_argument("--threshold", type=float, default=0.1)
    ap.add_argument("--max-hulls", type=int, default=64)
    ap.add_argument("--split", default="auto")
    ap.add_argument("--blend", type=float, default=1.0)
    ap.add_argument("--features", default="auto",
                    help="as pointcvx decompose (auto: optimisation, the model on splats)")
    ap.add_argument("--model", default=None, help="checkpoint for --features model")
    ap.add_argument("--views", type=int, default=1, help="model views (test-time ensemble)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--limit", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--subsurface", type=float, default=None,
                    help="decompose(subsurface=...): depth below which points leave the measure")
    ap.add_argument("--band", default="auto", choices=BAND_MODES,
                    help="decompose(band=...): points moved to the middle of their surface band")
    ap.add_argument("--truth", default=None,
                    help="folder of the true meshes (same stem, any mesh format): score against them")
    ap.add_argument("--seam-variants", action="store_true",
                    help="also score the hulls with the seams open (open_* columns), closed with "
                         "the neighbours' points (points_*) and with every midpoint (allmid_*)")
    args = ap.parse_args(argv)
    files = sorted(str(p) for p in Path(args.folder).iterdir()
                   if p.is_file() and p.suffix.lower() not in SKIP_SUFFIXES and not p.name.startswith("."))
    if args.limit:
        files = files[: args.limit]
    opts = {"threshold": args.threshold, "max_hulls": args.max_hulls, "split": args.split,
            "blend": args.blend,
            "features": args.features, "model": args.model, "views": args.views, "seed": args.seed,
            "subsurface": args.subsurface, "band": args.band}
    truths = {f: truth_file(args.truth, f) for f in files} if args.truth else dict.fromkeys(files)
    rows = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        names = shape_names(files)
        futures = {pool.submit(run_one, f, opts, names[f], truths[f], args.seam_variants): f for f in files}
        for fut in as_completed(futures):
            row = fut.result()
            rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
    rows.sort(key=lambda r: r["shape"])
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    keys = sorted({k for r in rows for k in r}, key=lambda k: (k != "shape", k))
    with open(out, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    print(summarize(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
