"""Same behaviour across a refactor: decompose a fixed set of real shapes and compare hull files.

Decomposes three or more shapes of every modality (meshes of objects, characters and scanned
surfaces, CAD parts, Gaussian splats, point-cloud scans) at default settings and seed 0, each as
a user runs it (``python -m pointcvx decompose SHAPE -o OUT.obj`` in its own process), and
records the SHA-256 of every hull file. Run it once with the code before a change and once
after; ``--against`` compares and exits 1 on any difference.

    python tools/same_behaviour.py -o /tmp/before.json                 # on the old checkout
    python tools/same_behaviour.py -o /tmp/after.json --against /tmp/before.json

``--code DIR`` decomposes with the pointcvx package found in DIR (e.g. a ``git worktree`` of the
commit before the change) instead of this checkout's.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = (ROOT / ".." / "shared" / "data").resolve()

#: modality -> shapes (paths relative to shared/data, or to the checkout for bundled samples).
SHAPES = {
    "mesh (objects)": ["dev/objects/mug.obj", "dev/objects/duck.obj", "dev/objects/nut.ply"],
    "mesh (characters)": ["dev/characters/spot.obj", "dev/characters/dog.stl",
                          "dev/characters/knight.off"],
    "mesh (scanned)": ["dev/scans/bunny.obj", "dev/scans/fertility.off", "dev/scans/igea.ply"],
    "cad": ["dev/cad/bug3883_xr2-ct-214_l-bracket.stp", "dev/cad/linkrods.step",
            "dev/cad/xr1-tu-blt.stp", "dev/cad/abc1.stl"],
    "splat": ["dev/splats/guitar.compressed.ply", "dev/splats/biker.spz", "dev/splats/donut.ply"],
    "scan (points)": ["raw_scans/lamppost.pcd", "io:mug_scan.ply", "io:mug_scan.xyz"],
}


def shape_path(spec: str) -> Path:
    return ROOT / "io" / spec[3:] if spec.startswith("io:") else DATA / spec


def decompose_one(spec: str, outdir: Path, code: Path) -> dict:
    """Decompose one shape in a fresh process; its hull file's digest, hull count and time."""
    src = shape_path(spec)
    out = outdir / (spec.replace("/", "__").replace(":", "_") + ".obj")
    env = dict(os.environ, PYTHONPATH=str(code))
    t = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "pointcvx", "decompose", str(src), "-o", str(out),
                          "--seed", "0", "--json"], capture_output=True, text=True, env=env,
                         cwd=outdir, timeout=1800)
    seconds = time.perf_counter() - t
    if res.returncode != 0:
        return {"error": (res.stderr.strip().splitlines() or ["?"])[-1], "seconds": seconds}
    summary = json.loads(res.stdout)
    return {"sha256": hashlib.sha256(out.read_bytes()).hexdigest(), "hulls": summary["hulls"],
            "seconds": round(seconds, 2)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--output", required=True, help="JSON file of digests to write")
    ap.add_argument("--against", help="JSON written by an earlier run: compare, exit 1 on a difference")
    ap.add_argument("--code", default=str(ROOT), help="folder holding the pointcvx package to run")
    ap.add_argument("--jobs", type=int, default=2, help="shapes decomposed at once (default 2)")
    args = ap.parse_args(argv)
    specs = [s for group in SHAPES.values() for s in group]
    with tempfile.TemporaryDirectory(prefix="same-behaviour-") as tmp:
        with concurrent.futures.ThreadPoolExecutor(args.jobs) as pool:
            runs = dict(zip(specs, pool.map(lambda s: decompose_one(s, Path(tmp), Path(args.code)),
                                            specs), strict=True))
    Path(args.output).write_text(json.dumps(runs, indent=1, sort_keys=True) + "\n")
    failed = 0
    before = json.loads(Path(args.against).read_text()) if args.against else None
    for group, members in SHAPES.items():
        for spec in members:
            run = runs[spec]
            line = f"{group:<18} {spec:<42} "
            if "error" in run:
                line += f"ERROR {run['error']}"
                failed += 1
            else:
                line += f"{run['hulls']:>3} hulls {run['seconds']:>6.1f} s {run['sha256'][:12]}"
            if before is not None:
                same = before.get(spec, {}).get("sha256") == run.get("sha256") and "error" not in run
                line += "  same" if same else "  DIFFERENT"
                failed += not same
            print(line)
    if before is not None:
        print(f"{len(specs) - failed} of {len(specs)} hull files identical")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
