"""Synthetic Gaussian splats of procedural solids, with the solids as ground truth.

    python tools/synthetic_splats.py OUTDIR [--shapes 30] [--seed 777] [--gaussians 14000] \
        [--depth-noise 0.004] [--subsurface 0.15]
    python tools/eval_dataset.py OUTDIR/splats --truth OUTDIR/truth -o CSV [--features model]

Real splats (``../shared/data/dev/splats``) have no ground truth: their concavity can only be
the decomposer's own estimate, against the solid it reconstructed itself. Here every splat comes
with the mesh it was made from, so ``tools/eval_dataset.py --truth`` scores the hulls of the
splat against the true solid with the paper's protocol (concavity of M ∩ hull pieces, Chamfer
reconstruction, volume IoU), in the same frame. The solids are :func:`random_solid` shapes
(unions and differences of primitives, longest side 1.8) drawn from ``--seed``; the splats are
:func:`make_samples.make_splat` (the bundled sample's recipe: flat Gaussians on the surface,
faint ones everywhere and a floater cluster beyond a corner of the bounds) with the centres
scattered along their normals by ``--depth-noise`` and, with ``--subsurface F``, F x
``--gaussians`` more Gaussians 0.03-0.08 under the surface (trained splats keep such a layer).
Same arguments, same files.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from make_samples import make_splat  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    from pointcvx.training.shapes import random_solid

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("outdir")
    ap.add_argument("--shapes", type=int, default=30)
    ap.add_argument("--seed", type=int, default=777)
    ap.add_argument("--gaussians", type=int, default=14000)
    ap.add_argument("--depth-noise", type=float, default=0.004)
    ap.add_argument("--subsurface", type=float, default=0.0)
    args = ap.parse_args(argv)
    out = Path(args.outdir)
    (out / "splats").mkdir(parents=True, exist_ok=True)
    (out / "truth").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    for i in range(args.shapes):
        mesh = random_solid(rng)
        name = f"solid_{i:02d}"
        mesh.export(out / "truth" / f"{name}.obj")
        # The floater cluster sits beyond a corner of the solid's bounds, off the shape.
        make_splat(mesh, out / "splats" / f"{name}.ply", np.random.default_rng([args.seed, i]),
                   n=args.gaussians, depth_noise=args.depth_noise, floater_at=mesh.bounds[1] + 0.15,
                   subsurface=args.subsurface)
        print(f"{name}: {len(mesh.faces)} faces, volume {mesh.volume:.3f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
