"""Synthetic depth scans of procedural solids on a table with clutter, with the solids as truth.

    python tools/synthetic_scans.py OUTDIR [--shapes 20] [--seed 778] [--views 3] [--noise 0.003]
    python tools/eval_dataset.py OUTDIR/scans --truth OUTDIR/truth -o CSV

Each scan is what a depth sensor sees of a :func:`random_solid` shape (longest side 1.8, never
trained on) standing on a table: ``--views`` viewpoints above the table around the object, each
keeping the surface points it sees (Embree ray casts: the first hit from the sensor is the point),
with depth noise ``--noise`` along the ray; the table is a square three times the object's
footprint, and a few small clutter pieces (crumbs and a cable-like sliver) lie on it away from the
object. Written as XYZ files (no normals, as sensors give them) with the truth mesh beside, and
``OUTDIR/scans/NAME.json`` recording how many points of each kind the file holds, so the
isolation can be scored: ``python tools/synthetic_scans.py OUTDIR --score`` loads every scan
with the default isolation and reports how much of the object it kept and of the table and
clutter it removed. Same arguments, same files.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def _seen(mesh, eye: np.ndarray, points: np.ndarray, tol: float) -> np.ndarray:
    """(n,) bool: which of (n, 3) ``points`` on ``mesh`` are the first hit seen from ``eye``."""
    from pointcvx.embree import raycasting_scene
    from pointcvx.syslibs import import_open3d

    o3d = import_open3d()
    scene = raycasting_scene(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    d = points - eye
    length = np.linalg.norm(d, axis=1)
    rays = np.concatenate([np.broadcast_to(eye, d.shape), d / length[:, None]], axis=1).astype(np.float32)
    hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    return np.abs(hit - length) <= tol


def scan(mesh, rng: np.random.Generator, views: int, noise: float, n: int = 120000):
    """(points, kinds): a depth scan of ``mesh`` on a table with clutter; kinds 0 object, 1 table,
    2 clutter."""
    import trimesh

    lo, hi = mesh.bounds
    foot = float(np.ptp(mesh.vertices[:, :2], axis=0).max())
    table = trimesh.creation.box(extents=[3 * foot, 3 * foot, 0.04])
    table.apply_translation([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2] - 0.02])
    clutter = []
    for k in range(3):
        angle = 2 * np.pi * (k / 3 + rng.random() / 6)
        r = foot * rng.uniform(0.8, 1.3)
        size = foot * (rng.uniform(0.02, 0.05, 3) if k < 2 else np.array([0.4, 0.01, 0.01]))
        piece = trimesh.creation.box(extents=size)
        piece.apply_translation([r * np.cos(angle), r * np.sin(angle), lo[2] + size[2] / 2])
        clutter.append(piece)
    parts = [mesh, table, *clutter]
    world = trimesh.util.concatenate(parts)
    kinds = np.concatenate([np.full(len(p.faces), i if i < 2 else 2) for i, p in enumerate(parts)])
    samples, face = trimesh.sample.sample_surface(world, n, seed=int(rng.integers(2**31)))
    keep = np.zeros(len(samples), dtype=bool)
    centre = np.array([0.0, 0.0, 0.5 * (lo[2] + hi[2])])
    for v in range(views):
        azimuth = 2 * np.pi * (v / views) + rng.uniform(0, 0.3)
        eye = centre + 2.5 * foot * np.array([np.cos(azimuth), np.sin(azimuth), 0.8])
        keep |= _seen(world, eye, samples, 1e-4 * foot)
    pts = samples[keep]
    eyes = centre + 2.5 * foot * np.array([1.0, 0.0, 0.8])
    ray = (pts - eyes) / np.linalg.norm(pts - eyes, axis=1, keepdims=True)
    pts = pts + ray * rng.normal(0, noise, (len(pts), 1))
    return pts, kinds[face[keep]]


def score(outdir: Path) -> int:
    """Load every scan with the default isolation; print and return 0."""
    from scipy.spatial import cKDTree

    import pointcvx

    rows = []
    for xyz in sorted((outdir / "scans").glob("*.xyz")):
        kinds = np.load(xyz.with_suffix(".kinds.npy"))
        raw = np.loadtxt(xyz)
        cloud = pointcvx.load(xyz, normalize=False)
        # the loaded points are a subset of the file's (outliers and isolation removed): match them
        _, idx = cKDTree(raw).query(cloud.points)
        kept = np.zeros(len(raw), dtype=bool)
        kept[idx] = True
        rows.append([float(kept[kinds == k].mean()) if (kinds == k).any() else float("nan")
                     for k in range(3)])
        print(f"{xyz.stem}: kept object {rows[-1][0]:.3f}, table {rows[-1][1]:.3f}, "
              f"clutter {rows[-1][2]:.3f}")
    mean = np.nanmean(rows, axis=0)
    print(f"mean over {len(rows)} scans: object kept {mean[0]:.3f}, table kept {mean[1]:.3f}, "
          f"clutter kept {mean[2]:.3f}")
    return 0


def main(argv: list[str] | None = None) -> int:
    from pointcvx.training.shapes import random_solid

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("outdir")
    ap.add_argument("--shapes", type=int, default=20)
    ap.add_argument("--seed", type=int, default=778)
    ap.add_argument("--views", type=int, default=3)
    ap.add_argument("--noise", type=float, default=0.003)
    ap.add_argument("--score", action="store_true", help="score the isolation of scans written before")
    args = ap.parse_args(argv)
    out = Path(args.outdir)
    if args.score:
        return score(out)
    (out / "scans").mkdir(parents=True, exist_ok=True)
    (out / "truth").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    for i in range(args.shapes):
        mesh = random_solid(rng)
        name = f"solid_{i:02d}"
        mesh.export(out / "truth" / f"{name}.obj")
        pts, kinds = scan(mesh, np.random.default_rng([args.seed, i]), args.views, args.noise)
        np.savetxt(out / "scans" / f"{name}.xyz", pts, fmt="%.6f")
        np.save(out / "scans" / f"{name}.kinds.npy", kinds)
        counts = {k: int((kinds == j).sum()) for j, k in enumerate(("object", "table", "clutter"))}
        (out / "scans" / f"{name}.json").write_text(json.dumps(counts) + "\n")
        print(f"{name}: {len(pts)} points {counts}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
