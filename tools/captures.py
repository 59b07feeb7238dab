"""Real captures at default settings: what isolation removed, the objects of scenes, hulls, time,
and a picture of each (docs/captures.md).

    python tools/captures.py OUTDIR [CAPTURE ...]     # default: ../shared/data/raw_scans/* and
                                                      # ../shared/data/dev/splats/*
    python tools/captures.py OUTDIR --extra "--close-bases on"   # the same with more flags

For each capture: ``pointcvx decompose CAPTURE -o OUTDIR/NAME.json --preview OUTDIR/NAME.html``
as a user runs it (its own process, default settings, seed 0), then one markdown row from the
JSON report: points decomposed, non-finite points dropped, points removed as support plane, as
walls (depth frames) and as clutter, objects (a scene) or 1, hulls, max concavity, the threshold
it was cut at (the largest of its objects': above 0.1 where an object's samples are too sparse
to resolve 0.1), whole-process seconds. The PNG beside each page is the picture.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = (ROOT / ".." / "shared" / "data").resolve()


def captures() -> list[Path]:
    return sorted((DATA / "raw_scans").glob("*.pcd")) + sorted((DATA / "dev" / "splats").iterdir())


def run(capture: Path, out: Path, extra: list[str] = ()) -> dict:
    name = capture.name.replace(".", "_")
    report = out / f"{name}.json"
    t = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "pointcvx", "decompose", str(capture), "-o", str(report),
                          "--preview", str(out / f"{name}.html"), "--overwrite", "-q", *extra],
                         capture_output=True, text=True, cwd=ROOT)
    seconds = time.perf_counter() - t
    if res.returncode != 0:
        return {"name": capture.name, "error": (res.stderr.strip().splitlines() or ["?"])[-1]}
    rep = json.loads(report.read_text())
    iso = rep.get("isolation", {}).get("removed", {})
    params = rep.get("parameters", {})
    cut_at = max([o["resolved_threshold"] for o in rep.get("objects") or [] if "resolved_threshold" in o]
                 + [params.get("resolved_threshold") or params.get("threshold", 0.1)])
    return {"name": capture.name, "points": rep["totals"]["points"],
            "non_finite": rep.get("parameters", {}).get("non_finite_dropped"),
            "support": iso.get("support", 0), "walls": iso.get("walls", 0), "clutter": iso.get("clutter", 0),
            "objects": len(rep.get("objects") or []) or 1, "hulls": rep["totals"]["hulls"],
            "concavity": rep["totals"]["max_concavity"], "cut_at": cut_at, "seconds": seconds}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("output", help="folder for the reports, pages and pictures")
    ap.add_argument("captures", nargs="*", help="capture files (default: raw_scans and dev/splats)")
    ap.add_argument("--extra", default="", help="more decompose flags, one string (\"--close-bases on\")")
    args = ap.parse_args(argv)
    extra = shlex.split(args.extra)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    print("| capture | points | removed: support | removed: walls | removed: clutter | objects | hulls "
          "| max concavity | cut at | seconds |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for capture in [Path(c) for c in args.captures] or captures():
        row = run(capture, out, extra)
        if "error" in row:
            print(f"| {row['name']} | error: {row['error']} | | | | | | | | |", flush=True)
            continue
        print(f"| {row['name']} | {row['points']} | {row['support']} | {row['walls']} | {row['clutter']} "
              f"| {row['objects']} "
              f"| {row['hulls']} | {row['concavity']:.4f} | {row['cut_at']:.3g} | {row['seconds']:.1f} |",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
