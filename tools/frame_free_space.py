"""How much of a depth frame's hulls the sensor saw through (docs/captures.md).

    python tools/frame_free_space.py [FRAME.pcd ...] [--samples N] [--seed S]
                                     # default: the organised frames of ../shared/data/raw_scans

A depth frame has no true mesh to judge hulls against, but it does say where there is nothing:
along each pixel's ray, the space in front of the measured point is empty. For each organised
frame: ``pointcvx.decompose(FRAME, seed=S)`` at default settings, then ``N`` points sampled
uniformly in each hull (input units) and projected into the frame with a pinhole at its sensor
fitted to its own pixels (column ~ x / z, row ~ y / z, least squares over the measured pixels). A sample whose
pixel was measured farther away than the sample (by more than 3 % of its depth: the sensor's
noise, as the wall rule allows) lies in space the sensor saw through. Printed per frame: hulls,
their volume, the share of that volume seen through, the largest such share of one hull, and
the whole decomposition's seconds. Samples that project outside the image or onto a hole (no
measurement) are not counted either way.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = (ROOT / ".." / "shared" / "data").resolve()
#: A sample counts as seen through when its pixel was measured this share of its depth beyond it.
DEPTH_NOISE = 0.03


def organised_points(path: Path) -> tuple[np.ndarray, np.ndarray, int, int]:
    """(h * w, 3) float points of an organised PCD in pixel order (NaN where nothing was
    measured), (3,) where its sensor stood (``pointcvx.scene.frame_sensor``), its width and
    height."""
    from pointcvx.io.pointfiles import read_scan
    from pointcvx.scene import frame_sensor

    meta: dict = {}
    points = read_scan(path, "pcd", meta)[0]
    sensor = frame_sensor(meta)
    if sensor is None:
        raise SystemExit(f"{path}: not an organised frame")
    w, h = meta["organized"]
    return np.asarray(points, dtype=np.float64), sensor, w, h


def fit_pinhole(points: np.ndarray, w: int) -> tuple[float, float, float, float]:
    """(fx, cx, fy, cy) of the pinhole that projects the measured (h * w, 3) ``points`` onto
    their pixels (least squares)."""
    ok = np.isfinite(points).all(axis=1) & (points[:, 2] > 0)
    idx = np.flatnonzero(ok)
    col, row = idx % w, idx // w
    p = points[ok]
    fx, cx = np.polyfit(p[:, 0] / p[:, 2], col, 1)
    fy, cy = np.polyfit(p[:, 1] / p[:, 2], row, 1)
    return fx, cx, fy, cy


def seen_through(samples: np.ndarray, depth: np.ndarray, w: int, h: int, pinhole) -> tuple[int, int]:
    """(samples judged, samples seen through) for (m, 3) ``samples`` (relative to the sensor) in
    the frame's (h * w,) depths."""
    fx, cx, fy, cy = pinhole
    z = samples[:, 2]
    front = z > 0
    u = np.rint(fx * samples[front, 0] / z[front] + cx).astype(np.int64)
    v = np.rint(fy * samples[front, 1] / z[front] + cy).astype(np.int64)
    zs = z[front]
    on = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    d = np.full(len(zs), np.nan)
    d[on] = depth[v[on] * w + u[on]]
    judged = np.isfinite(d)
    through = judged & (d > zs * (1 + DEPTH_NOISE))
    return int(judged.sum()), int(through.sum())


def seen_through_share(path: Path, hulls, samples: int = 4000, seed: int = 0) -> tuple[float, float]:
    """(share of the ``hulls``' total volume the frame at ``path`` saw through, the largest
    share of one hull), each hull (a :class:`pointcvx.result.ConvexHull`, input units) judged
    by ``samples`` uniform draws inside it (``decomposition.hull.sample_hull_interior``)."""
    from pointcvx.decomposition.hull import convex_hull, sample_hull_interior

    points, sensor, w, h = organised_points(path)
    points = points - sensor  # the pinhole's centre
    pinhole = fit_pinhole(points, w)
    depth = points[:, 2].copy()
    rng = np.random.default_rng(seed)
    volume = through_volume = worst = 0.0
    for hull in hulls:
        inside = sample_hull_interior(convex_hull(hull.vertices), samples, rng) - sensor
        judged, through = seen_through(inside, depth, w, h, pinhole)
        share = through / judged if judged else 0.0
        volume += hull.volume
        through_volume += hull.volume * share
        worst = max(worst, share)
    return (through_volume / volume if volume else 0.0), worst


def frame_row(path: Path, samples: int, seed: int) -> dict:
    import pointcvx

    t = time.perf_counter()
    result = pointcvx.decompose(str(path), seed=seed)
    seconds = time.perf_counter() - t
    share, worst = seen_through_share(path, result.hulls, samples, seed)
    return {"frame": path.stem, "hulls": len(result.hulls),
            "volume_m3": sum(h.volume for h in result.hulls), "seen_through": share,
            "worst_hull": worst, "seconds": seconds}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("frames", nargs="*", type=Path)
    ap.add_argument("--samples", type=int, default=4000, help="samples drawn inside each hull")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    frames = args.frames or [p for p in sorted((DATA / "raw_scans").glob("*.pcd"))
                             if b"HEIGHT 1\n" not in p.read_bytes()[:2048]]
    print("| frame | hulls | hull volume m^3 | volume seen through | worst hull | seconds |")
    print("|---|---|---|---|---|---|")
    for path in frames:
        r = frame_row(path, args.samples, args.seed)
        print(f"| {r['frame']} | {r['hulls']} | {r['volume_m3']:.4f} | {r['seen_through']:.3f} | "
              f"{r['worst_hull']:.3f} | {r['seconds']:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
