"""Per-category tables of a ``pointcvx bench`` run: means per method and setting, and pointcvx
against each matched baseline shape by shape (wins / ties / losses, time ratios).

    python tools/bench_categories.py OUTDIR/results.csv

Categories are the ``dataset`` column; "all meshes" pools every shape the baselines ran on
(splats have no mesh). Means skip empty cells (a splat has no concavity against a closed
surface). Ties: within 0.1 % of the larger value, as in ``pointcvx bench``'s summary.
"""

from __future__ import annotations

import csv
import statistics as st
import sys

METHODS = [("pointcvx", "fixed", "pointcvx"), ("coacd", "matched", "CoACD matched"),
           ("coacd", "fixed", "CoACD 0.1"), ("vhacd", "matched", "V-HACD matched"),
           ("vhacd", "fixed", "V-HACD 1M")]


def value(row: dict, key: str) -> float:
    return float(row[key]) if row[key] != "" else float("nan")


def mean(values) -> float:
    kept = [v for v in values if v == v]
    return st.mean(kept) if kept else float("nan")


def runs(rows: list[dict], category: str | None, method: str, setting: str) -> dict:
    """(dataset, shape) -> row of one method and setting (``category`` None: every mesh)."""
    out = {(r["dataset"], r["shape"]): r for r in rows
           if (category is None or r["dataset"] == category) and r["method"] == method
           and r["setting"] == setting}
    return out if category is not None else {k: r for k, r in out.items() if r["modality"] != "splat"}


def wins(ours: dict, theirs: dict, key: str) -> str:
    w = t = lost = 0
    for shape, row in ours.items():
        if shape not in theirs:
            continue
        a, b = value(row, key), value(theirs[shape], key)
        if abs(a - b) <= 1e-3 * max(abs(a), abs(b)):
            t += 1
        elif a < b:
            w += 1
        else:
            lost += 1
    return f"{w}/{t}/{lost}"


def main(path: str) -> None:
    rows = [r for r in csv.DictReader(open(path, newline="")) if not r["error"]]
    categories = list(dict.fromkeys(r["dataset"] for r in rows))
    print("| category | shapes | method | hulls | concavity | reconstruction | median s | peak MB (median) |")
    print("|---|---|---|---|---|---|---|---|")
    for cat in [*categories, None]:
        for method, setting, label in METHODS:
            d = runs(rows, cat, method, setting)
            if not d:
                continue
            r = d.values()
            print(f"| {cat or 'all meshes'} | {len(d)} | {label} | {mean(value(x, 'hulls') for x in r):.2f} "
                  f"| {mean(value(x, 'concavity') for x in r):.4f} "
                  f"| {mean(value(x, 'reconstruction') for x in r):.4f} "
                  f"| {st.median(value(x, 'seconds') for x in r):.2f} "
                  f"| {st.median(value(x, 'peak_mb') for x in r):.0f} |")
    print()
    print("| category | vs CoACD: concavity W/T/L | reconstruction W/T/L | time ratio "
          "| per-shape time ratio, median (min-max) | vs V-HACD: concavity W/T/L "
          "| reconstruction W/T/L | time ratio |")
    print("|---|---|---|---|---|---|---|---|")
    for cat in [*categories, None]:
        ours = {k: r for k, r in runs(rows, cat, "pointcvx", "fixed").items() if r["modality"] != "splat"}
        coacd, vhacd = runs(rows, cat, "coacd", "matched"), runs(rows, cat, "vhacd", "matched")
        if not ours or not coacd or not vhacd:
            continue
        mine = st.median(value(r, "seconds") for r in ours.values())
        per = [value(coacd[s], "seconds") / value(ours[s], "seconds") for s in ours if s in coacd]
        print(f"| {cat or 'all meshes'} | {wins(ours, coacd, 'concavity')} "
              f"| {wins(ours, coacd, 'reconstruction')} "
              f"| {st.median(value(r, 'seconds') for r in coacd.values()) / mine:.1f}x "
              f"| {st.median(per):.1f} ({min(per):.2f}-{max(per):.1f}) "
              f"| {wins(ours, vhacd, 'concavity')} | {wins(ours, vhacd, 'reconstruction')} "
              f"| {st.median(value(r, 'seconds') for r in vhacd.values()) / mine:.2f}x |")


if __name__ == "__main__":
    main(sys.argv[1])
