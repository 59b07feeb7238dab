"""Render a shape's feature field (PCA colours) and its convex decomposition side by side.

    python tools/render.py INPUT... -o docs/images [--features model|optimize] [--model CKPT]
        [--threshold 0.1] [--seed 0] [--elev 20 --azim -60]

Writes ``<stem>_<features>.png`` per input: left, the loaded oriented cloud coloured by the first
three principal components of its features; right, the hulls of ``pointcvx.decompose`` (one
colour per hull) in the same view. Needs matplotlib (``pip install matplotlib``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def pca_colors(feats: np.ndarray) -> np.ndarray:
    """(n, k) float features -> (n, 3) float RGB in [0, 1]: the first three principal components,
    each stretched between its 1st and 99th percentile."""
    x = feats - feats.mean(axis=0)
    _, _, vt = np.linalg.svd(x[:: max(1, len(x) // 20000)], full_matrices=False)
    pc = x @ vt[:3].T
    lo, hi = np.percentile(pc, 1, axis=0), np.percentile(pc, 99, axis=0)
    return np.clip((pc - lo) / np.maximum(hi - lo, 1e-9), 0.0, 1.0)


def hull_colors(n: int) -> np.ndarray:
    """(n, 3) float: distinct colours (golden-ratio hues)."""
    import colorsys

    return np.array([colorsys.hsv_to_rgb((0.13 + i * 0.618034) % 1.0, 0.65, 0.95) for i in range(n)])


UP = {"y": ([0, 2, 1], [1, 1, 1]), "-y": ([0, 2, 1], [1, 1, -1]), "z": ([0, 1, 2], [1, 1, 1])}


def render(path: str, out: Path, *, features: str, model: str | None, threshold: float, seed: int,
           elev: float, azim: float, up: str = "y", subsurface: float | None = None) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    import pointcvx
    from pointcvx.decomposition.hull import convex_hull
    from pointcvx.model.weights import load_cached_model

    if features == "model":  # load the network first: time a loaded model, as in a loop over shapes
        load_cached_model(model)
    result = pointcvx.decompose(path, features=features, model=model, threshold=threshold, seed=seed,
                                subsurface=subsurface)
    t_feat = result.timings["features"]
    cloud, feats = result.cloud, result.features

    axes, signs = UP[up]
    pts = cloud.points[:, axes] * signs
    keep = np.random.default_rng(seed).permutation(len(pts))[:8000]
    fig = plt.figure(figsize=(9, 4.6), dpi=90)
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    ax.scatter(pts[keep, 0], pts[keep, 1], pts[keep, 2], c=pca_colors(feats)[keep], s=1.5, linewidths=0)
    ax.set_title(f"{features} features (PCA), {t_feat:.2f} s", fontsize=9)
    ax2 = fig.add_subplot(1, 2, 2, projection="3d")
    for colour, hull in zip(hull_colors(len(result.hulls)), result.hulls, strict=True):
        h = convex_hull(cloud.normalization.forward(hull.vertices))
        if h.dim < 3:
            continue
        tri = h.triangles[:, :, axes] * signs
        ax2.add_collection3d(Poly3DCollection(tri, facecolors=colour, edgecolors=colour * 0.6,
                                              linewidths=0.2, alpha=0.85))
    ax2.set_title(f"{len(result.hulls)} hulls, concavity {result.max_concavity:.3f}", fontsize=9)
    for a in (ax, ax2):
        a.set_xlim(-1, 1)
        a.set_ylim(-1, 1)
        a.set_zlim(-1, 1)
        a.set_box_aspect((1, 1, 1))
        a.view_init(elev=elev, azim=azim)
        a.set_axis_off()
    fig.suptitle(Path(path).name, fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return {"file": str(out), "hulls": len(result.hulls), "feature_seconds": round(t_feat, 3)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("inputs", nargs="+")
    ap.add_argument("-o", "--output", required=True, help="output folder")
    ap.add_argument("--features", default="model", choices=["model", "optimize"])
    ap.add_argument("--model", default=None, help="checkpoint (default: the bundled model)")
    ap.add_argument("--threshold", type=float, default=0.1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--elev", type=float, default=20.0)
    ap.add_argument("--azim", type=float, default=-60.0)
    ap.add_argument("--up", choices=sorted(UP), default="y", help="the input's up axis (splats: often -y)")
    ap.add_argument("--subsurface", type=float, default=None,
                    help="decompose(subsurface=...); the file name gets _subsurface")
    args = ap.parse_args(argv)
    for path in args.inputs:
        tag = "_subsurface" if args.subsurface is not None else ""
        out = Path(args.output) / f"{Path(path).name.split('.')[0]}{tag}_{args.features}.png"
        info = render(path, out, features=args.features, model=args.model, threshold=args.threshold,
                      seed=args.seed, elev=args.elev, azim=args.azim, up=args.up,
                      subsurface=args.subsurface)
        print(info, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
