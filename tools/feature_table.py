"""Markdown table comparing two feature sources from CSVs written by ``tools/eval_dataset.py``.

    python tools/feature_table.py NAME OPTIMIZE.csv MODEL.csv [NAME OPTIMIZE.csv MODEL.csv ...]

For each dataset NAME: the means of hull count, concavity, reconstruction, feature time and total
time per shape for both sources over the shapes both decomposed, the feature-time speed-up, and
paired per-shape counts of where the model is at least as good (concavity, reconstruction).
"""

from __future__ import annotations

import csv
import sys

import numpy as np

COLUMNS = ("hulls", "concavity", "reconstruction", "t_features", "seconds")


def read(path: str) -> dict[str, dict]:
    with open(path, newline="") as f:
        return {r["shape"]: r for r in csv.DictReader(f) if not r.get("error")}


def rows_for(name: str, opt_csv: str, model_csv: str) -> list[str]:
    a, b = read(opt_csv), read(model_csv)
    shapes = sorted(set(a) & set(b))
    if not shapes:
        return [f"| {name} | - | 0 | | | | | | |"]
    mean = {}
    for tag, rows in (("optimize", a), ("model", b)):
        mean[tag] = {c: float(np.mean([float(rows[s][c]) for s in shapes])) for c in COLUMNS}
    wins_c = sum(float(b[s]["concavity"]) <= float(a[s]["concavity"]) + 1e-9 for s in shapes)
    wins_r = sum(float(b[s]["reconstruction"]) <= float(a[s]["reconstruction"]) + 1e-9 for s in shapes)
    speed = mean["optimize"]["t_features"] / max(mean["model"]["t_features"], 1e-9)
    out = []
    for tag in ("optimize", "model"):
        m = mean[tag]
        extra = (f"{speed:.0f}x faster features; model <= optimize on {wins_c}/{len(shapes)} "
                 f"(concavity), {wins_r}/{len(shapes)} (reconstruction)") if tag == "model" else ""
        out.append(f"| {name} | {tag} | {len(shapes)} | {m['hulls']:.2f} | {m['concavity']:.4f} | "
                   f"{m['reconstruction']:.4f} | {m['t_features']:.2f} s | {m['seconds']:.2f} s | {extra} |")
    return out


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if not args or len(args) % 3:
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    print("| dataset | features | shapes | #hulls | concavity | reconstruction | feature time "
          "| total time | paired |")
    print("|---|---|---|---|---|---|---|---|---|")
    for i in range(0, len(args), 3):
        print("\n".join(rows_for(*args[i : i + 3])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
