"""Throughput of ``pointcvx batch`` (assets per minute) with 1 and 2 workers, locally and on Ray.

    python tools/batch_throughput.py -o OUTDIR [--data ../shared/data/dev] [--engines local,ray]
                                     [--jobs 1,2] [--features model] [--every K]
                                     [-- EXTRA BATCH ARGS]

Writes ``OUTDIR/assets.txt``, a manifest of 24 shapes of ``dev/`` (:data:`SHAPES`: objects,
characters, scans, CAD meshes and STEP parts, splats), then runs, for every engine and worker
count, ``python -m pointcvx batch OUTDIR/assets.txt -o OUTDIR/<engine>-<jobs> --engine E --jobs J
--threads 1 --features F -q --json`` in a fresh process (a fresh output folder, so nothing is
skipped; Ray: a local instance started by the batch itself) and records, from its
``batch_report.json`` and its own clock:

``wall_s``
    the batch's wall time: worker start (interpreter, imports, model; Ray: the local instance
    too) and every asset;
``startup_s``
    until the first worker was ready;
``assets_per_min``
    assets / ``wall_s``;
``steady_per_min``
    assets / (``wall_s`` - ``startup_s``): the rate once workers run, what a long batch sees;
``per_worker_per_min``
    ``steady_per_min`` / workers;
``mean_asset_s``
    mean seconds of one asset in its worker;
``mean_cpu_s``, ``cpu_per_min``
    mean CPU seconds of one asset (its worker's process time, one thread) and 60 / that: the
    assets one fully available core finishes per minute, a figure that other work on the machine
    does not change much (wall times do);
``command_s``
    the whole command (interpreter start and exit included);
``load_before``
    the machine's 1-minute load average before the run (other work on the same cores slows it).

Results: ``OUTDIR/throughput.csv`` and a markdown table on stdout.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = (ROOT / ".." / "shared" / "data" / "dev").resolve()
SHAPES = [
    "objects/mug.obj", "objects/duck.obj", "objects/Kettle.obj", "objects/truck.obj",
    "objects/lamp.obj", "objects/lego.obj", "objects/kiva_pod.stl", "objects/airplane.ply",
    "characters/spot.obj", "characters/teddy.obj", "characters/dog.stl", "characters/knight.off",
    "characters/beast.obj",
    "scans/bunny.obj", "scans/fertility.off", "scans/max_planck.obj", "scans/horse.ply",
    "cad/abc3.stl", "cad/fandisk.obj", "cad/bm2_ec_lever-A.stp", "cad/linkrods.step",
    "splats/donut.ply", "splats/guitar.compressed.ply", "splats/biker.spz",
]
"""24 shapes of every category of ``dev/`` (about 1 to 5 s each with the bundled model)."""
COLUMNS = ("engine", "jobs", "features", "assets", "done", "failed", "wall_s", "startup_s",
           "assets_per_min", "steady_per_min", "per_worker_per_min", "mean_asset_s", "mean_cpu_s",
           "cpu_per_min", "command_s", "load_before", "load_after", "cpus")


def run_one(manifest: Path, out: Path, engine: str, jobs: int, features: str, extra: list[str]) -> dict:
    cmd = [sys.executable, "-m", "pointcvx", "batch", str(manifest), "-o", str(out), "--engine", engine,
           "--jobs", str(jobs), "--threads", "1", "--features", features, "-q", "--overwrite", *extra]
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    command_s = time.perf_counter() - t0
    report = out / "batch_report.json"
    if not report.is_file():
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    s = json.loads(report.read_text())["summary"]
    n = s["run"]
    steady = 60.0 * n / max(1e-9, s["wall_seconds"] - (s["startup_seconds"] or 0.0))
    return {"engine": engine, "jobs": jobs, "features": features, "assets": n, "done": s["done"],
            "failed": s["failed"], "wall_s": round(s["wall_seconds"], 1),
            "startup_s": round(s["startup_seconds"] or 0.0, 1),
            "assets_per_min": round(s["assets_per_minute"], 2), "steady_per_min": round(steady, 2),
            "per_worker_per_min": round(steady / jobs, 2), "mean_asset_s": round(s["mean_seconds"], 2),
            "mean_cpu_s": round(s["mean_cpu_seconds"], 2),
            "cpu_per_min": round(60.0 / s["mean_cpu_seconds"], 2),
            "command_s": round(command_s, 1), "load_before": round(load, 2),
            "load_after": round(os.getloadavg()[0], 2), "cpus": os.cpu_count()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-o", "--output", required=True, help="output folder")
    parser.add_argument("--data", default=str(DATA), help="the dev/ folder of the shared data")
    parser.add_argument("--engines", default="local,ray", help="comma-separated (default local,ray)")
    parser.add_argument("--jobs", default="1,2", help="worker counts (default 1,2)")
    parser.add_argument("--features", default="model", choices=["model", "optimize"])
    parser.add_argument("--every", type=int, default=1, metavar="K",
                        help="use every K-th shape of SHAPES only (all categories still in; default 1)")
    parser.add_argument("extra", nargs="*", help="more `pointcvx batch` arguments (after --)")
    args = parser.parse_args(argv)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    data = Path(args.data)
    shapes = SHAPES[::args.every]
    missing = [s for s in shapes if not (data / s).is_file()]
    if missing:
        raise SystemExit(f"{data}: missing {', '.join(missing)}")
    manifest = out / "assets.txt"
    manifest.write_text("".join(f"{(data / s).resolve()}\n" for s in shapes))
    rows = []
    for engine in args.engines.split(","):
        for jobs in (int(j) for j in args.jobs.split(",")):
            row = run_one(manifest, out / f"{engine}-{jobs}", engine, jobs, args.features, args.extra)
            print(json.dumps(row), file=sys.stderr, flush=True)
            rows.append(row)
            with open(out / "throughput.csv", "w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
                w.writeheader()
                w.writerows(rows)
    print("| engine | workers | assets | failed | wall s | startup s | assets/min | steady assets/min "
          "| per worker/min | mean s/asset | mean CPU s/asset | assets/min per free core "
          "| load before/after |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['engine']} | {r['jobs']} | {r['assets']} | {r['failed']} | {r['wall_s']} | "
              f"{r['startup_s']} | {r['assets_per_min']} | {r['steady_per_min']} | "
              f"{r['per_worker_per_min']} | {r['mean_asset_s']} | {r['mean_cpu_s']} | {r['cpu_per_min']} | "
              f"{r['load_before']} / {r['load_after']} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
