"""How pointcvx's time and memory grow with the size of its input.

    python tools/scaling.py SHAPE -o OUTDIR [--sizes 10000,100000,1000000] [--features auto]
                            [--timeout 600]

From one real mesh (``SHAPE``, e.g. ``../shared/data/dev/scans/armadillo.obj``) it writes, for
every size N, two inputs into OUTDIR:

- ``cloud_N.ply``: N surface samples with normals and 0.2 % noise (an oriented scan), and
- ``splat_N.ply``: N flat Gaussians on the surface (INRIA 3DGS layout, SH degree 0), oriented
  along the surface with random in-plane extents, opacities and colours.

Then it decomposes each input in its own process (``pointcvx.decompose``, seed 0) twice: with the
default cap of 20,000 surface points and with every input point kept (``n_points=N``), and records
wall time (loading included), the per-stage timings, the hull count and the peak resident memory
of that process (``VmHWM``). Results: ``OUTDIR/scaling.csv`` and a markdown table on stdout.
Runs that exceed ``--timeout`` are recorded as such.
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

_CHILD = r"""
import json, sys, time
from pointcvx.apps.common import peak_kb
import pointcvx
args = json.loads(sys.argv[1])
t = time.perf_counter()
d = pointcvx.decompose(args["input"], features=args["features"], n_points=args["n_points"],
                       seed=0)
seconds = time.perf_counter() - t
print(json.dumps({"seconds": seconds, "hulls": len(d.hulls), "peak_mb": peak_kb() / 1024,
                  "timings": {k: round(v, 3) for k, v in d.timings.items()},
                  "concavity": d.max_concavity}))
"""


def surface_samples(mesh, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) points and (n, 3) unit normals, area-uniform on ``mesh`` (normalised to [-1, 1]^3)."""
    import trimesh

    rng = np.random.default_rng(seed)
    pts, face = trimesh.sample.sample_surface(mesh, n, seed=int(rng.integers(1 << 31)))
    return np.asarray(pts), np.asarray(mesh.face_normals[face])


def write_inputs(shape: str, outdir: Path, sizes: list[int]) -> list[tuple[str, int, Path]]:
    """Write the cloud and splat inputs of every size; return (kind, size, path) rows."""
    import trimesh
    from scipy.spatial.transform import Rotation

    from pointcvx.io.ply import write_cloud_ply
    from pointcvx.io.splat import write_inria_ply

    mesh = trimesh.load(shape, force="mesh")
    mesh.apply_translation(-mesh.bounds.mean(axis=0))
    mesh.apply_scale(2.0 / float(np.ptp(mesh.bounds, axis=0).max()))
    rows = []
    for n in sizes:
        rng = np.random.default_rng(n)
        pts, nrm = surface_samples(mesh, n, seed=n)
        cloud = outdir / f"cloud_{n}.ply"
        if not cloud.exists():
            write_cloud_ply(cloud, pts + rng.normal(0.0, 0.002, pts.shape), nrm)
        rows.append(("cloud", n, cloud))
        splat = outdir / f"splat_{n}.ply"
        if not splat.exists():
            # Rotation whose third axis is the normal: the Gaussian is flat across the surface.
            helper = np.where(np.abs(nrm[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
            u = np.cross(nrm, helper)
            u /= np.linalg.norm(u, axis=1, keepdims=True)
            rot = np.stack([u, np.cross(nrm, u), nrm], axis=2)  # columns: u, v, n
            spacing = np.sqrt(4.0 * mesh.area / n)
            scales = np.stack([rng.uniform(0.5, 1.5, n) * spacing, rng.uniform(0.5, 1.5, n) * spacing,
                               np.full(n, 0.05 * spacing)], axis=1)
            quat = Rotation.from_matrix(rot).as_quat()[:, [3, 0, 1, 2]]  # (w, x, y, z)
            write_inria_ply(splat, pts, scales, quat, rng.uniform(0.3, 1.0, n),
                            rng.uniform(0.0, 1.0, (n, 3)))
        rows.append(("splat", n, splat))
    return rows


def run_child(path: Path, n_points: int, features: str, timeout: float) -> dict:
    args = json.dumps({"input": str(path), "n_points": int(n_points), "features": features})
    t = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, "-c", _CHILD, args], capture_output=True, text=True,
                              timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": f"timeout after {timeout:.0f} s", "seconds": time.perf_counter() - t}
    if proc.returncode != 0:
        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        return {"error": tail[:200]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("shape")
    ap.add_argument("-o", "--output", required=True, help="output folder")
    ap.add_argument("--sizes", default="10000,100000,1000000")
    ap.add_argument("--features", default="auto", choices=["auto", "model", "optimize", "fast"],
                    help="feature source (default auto: what `pointcvx decompose` picks, the model on "
                         "splats and the per-shape fit on clouds)")
    ap.add_argument("--timeout", type=float, default=600.0)
    ap.add_argument("--full-max", type=int, default=100000,
                    help="largest size also decomposed with every point kept (default 100000)")
    args = ap.parse_args(argv)
    outdir = Path(args.output)
    outdir.mkdir(parents=True, exist_ok=True)
    sizes = [int(s) for s in args.sizes.split(",")]
    results = []
    for kind, n, path in write_inputs(args.shape, outdir, sizes):
        for n_points in sorted({min(20000, n), n} if n <= args.full_max else {min(20000, n)}):
            r = run_child(path, n_points, args.features, args.timeout)
            row = {"input": kind, "size": n, "n_points": min(n_points, n),
                   "file_mb": round(path.stat().st_size / 2**20, 1),
                   "seconds": round(r.get("seconds", float("nan")), 2),
                   "peak_mb": round(r.get("peak_mb", float("nan")), 0),
                   "hulls": r.get("hulls", ""), "error": r.get("error", "")}
            for stage in ("load", "solid", "features", "split", "merge"):
                row[f"t_{stage}"] = r.get("timings", {}).get(stage, "")
            results.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
    with open(outdir / "scaling.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(results[0]))
        w.writeheader()
        w.writerows(results)
    print("| input | size | points used | file MB | seconds | peak MB | hulls "
          "| load / solid / features / split / merge s |")
    print("|---|---|---|---|---|---|---|---|")
    for r in results:
        stages = " / ".join(str(r[f"t_{s}"]) for s in ("load", "solid", "features", "split", "merge"))
        print(f"| {r['input']} | {r['size']:,} | {r['n_points']:,} | {r['file_mb']} | {r['seconds']} | "
              f"{r['peak_mb']:.0f} | {r['hulls']} | {stages or r['error']} |" if not r["error"] else
              f"| {r['input']} | {r['size']:,} | {r['n_points']:,} | {r['file_mb']} | {r['error']} | | | |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
