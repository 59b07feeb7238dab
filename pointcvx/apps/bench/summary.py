"""The summary of a benchmark's rows: ``summary.md`` (means and medians per dataset and category,
paired win/tie/loss counts against each baseline, ratios of median times, one-shot and warm) and
the lines ``pointcvx bench`` prints at the end."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .options import BASELINES, METHODS
from .results import BenchReport, num

TIE_RTOL = 1e-3
"""Two metric values within this relative difference are a tie in the win/tie/loss counts."""


def is_ok(row: dict) -> bool:
    """Whether ``row`` ran without error."""
    return not row.get("error")


def mean_median(rows: list[dict], key: str) -> tuple[float, float]:
    """(mean, median) of column ``key`` over the finite values of ``rows``; NaNs when none."""
    vals = np.array([num(r.get(key)) for r in rows], dtype=np.float64)
    vals = vals[np.isfinite(vals)]
    if not len(vals):
        return math.nan, math.nan
    return float(vals.mean()), float(np.median(vals))


def _f(x: float, digits: int = 4) -> str:
    return "–" if not math.isfinite(x) else f"{x:.{digits}g}"


def win_tie_loss(rows: Sequence[dict], baseline: str, metric: str, threshold: str | None = None,
                 ) -> tuple[int, int, int]:
    """Paired per-shape counts (wins, ties, losses) of pointcvx against ``baseline``'s matched
    rows on ``metric`` (lower is better; ties within :data:`TIE_RTOL`)."""
    ours = {(r["dataset"], r["shape"], r["threshold"]): num(r.get(metric)) for r in rows
            if r["method"] == "pointcvx" and is_ok(r)}
    w = t = lo = 0
    for r in rows:
        if r["method"] != baseline or r["setting"] != "matched" or not is_ok(r):
            continue
        if threshold is not None and r["threshold"] != threshold:
            continue
        a = ours.get((r["dataset"], r["shape"], r["threshold"]), math.nan)
        b = num(r.get(metric))
        if not (math.isfinite(a) and math.isfinite(b)):
            continue
        if abs(a - b) <= TIE_RTOL * max(abs(a), abs(b)):
            t += 1
        elif a < b:
            w += 1
        else:
            lo += 1
    return w, t, lo


def method_groups(rows: Sequence[dict]) -> list[tuple[str, str, str]]:
    """The distinct (method, setting, threshold) of ``rows``: methods in :data:`METHODS` order,
    fixed before matched, thresholds ascending."""
    seen = []
    for r in rows:
        k = (r["method"], r["setting"], r["threshold"])
        if k not in seen:
            seen.append(k)
    order = {m: i for i, m in enumerate(METHODS)}
    return sorted(seen, key=lambda k: (order.get(k[0], 99), k[1] != "fixed", num(k[2])))


def _section(rows: list[dict], level: str) -> list[str]:
    out = ["", f"{level} Means and medians", "",
           "| method | setting | threshold | ok | errors | skipped | hulls mean | hulls median "
           "| concavity mean | concavity median | reconstruction mean | reconstruction median "
           "| seconds mean | seconds median | peak MB mean | peak MB median |",
           "|" + "---|" * 16]
    for m, s, t in method_groups(rows):
        g = [r for r in rows if (r["method"], r["setting"], r["threshold"]) == (m, s, t)]
        ok = [r for r in g if is_ok(r)]
        skipped = sum(1 for r in g if r.get("error", "").startswith("skipped"))
        cells = [m, s, t or "–", str(len(ok)), str(len(g) - len(ok) - skipped), str(skipped)]
        for key in ("hulls", "concavity", "reconstruction", "seconds", "peak_mb"):
            mean, med = mean_median(ok, key)
            cells += [_f(mean), _f(med)]
        out.append("| " + " | ".join(cells) + " |")
    baselines = [b for b in BASELINES if any(r["method"] == b for r in rows)]
    thresholds = sorted({r["threshold"] for r in rows if r["method"] == "pointcvx"}, key=num)
    matched = any(r["setting"] == "matched" for r in rows)
    if baselines and thresholds and matched:
        out += ["", f"{level} pointcvx against each baseline at matched granularity", "",
                "Per shape, pointcvx wins (W) when its value is lower; ties within "
                f"{TIE_RTOL:g} relative.", "",
                "| baseline | threshold | pairs | concavity W / T / L | reconstruction W / T / L |",
                "|---|---|---|---|---|"]
        for b in baselines:
            for t in thresholds:
                c = win_tie_loss(rows, b, "concavity", t)
                rec = win_tie_loss(rows, b, "reconstruction", t)
                out.append(f"| {b} | {t} | {max(sum(c), sum(rec))} | {c[0]} / {c[1]} / {c[2]} "
                           f"| {rec[0]} / {rec[1]} / {rec[2]} |")
    if baselines and thresholds:
        out += ["", f"{level} Time: median seconds of the baseline / median seconds of pointcvx", "",
                "| baseline | setting | threshold | baseline median s | pointcvx median s | ratio |",
                "|---|---|---|---|---|---|"]
        for b in baselines:
            for m, s, t in method_groups(rows):
                if m != b:
                    continue
                ref_t = t if t else thresholds[0]
                ours = [r for r in rows if r["method"] == "pointcvx" and r["threshold"] == ref_t and is_ok(r)]
                theirs = [r for r in rows if (r["method"], r["setting"], r["threshold"]) == (m, s, t)
                          and is_ok(r)]
                a, bm = mean_median(ours, "seconds")[1], mean_median(theirs, "seconds")[1]
                ratio = bm / a if math.isfinite(a) and math.isfinite(bm) and a > 0 else math.nan
                out.append(f"| {b} | {s} | {t or ref_t} | {_f(bm)} | {_f(a)} | {_f(ratio, 3)} |")
    out += _oneshot_table(rows, level)
    return out


def _ratio(a: float, b: float) -> float:
    return a / b if math.isfinite(a) and math.isfinite(b) and b > 0 else math.nan


def _oneshot_table(rows: list[dict], level: str) -> list[str]:
    """Median one-shot and warm seconds of every fixed setting that has one-shot runs, and each
    over pointcvx's (at the first threshold for the baselines); [] when no row has one."""
    timed = [r for r in rows if is_ok(r) and math.isfinite(num(r.get("oneshot_seconds")))]
    if not timed:
        return []
    groups = [g for g in method_groups(timed) if g[1] == "fixed"]
    thresholds = sorted({t for m, _, t in groups if m == "pointcvx"}, key=num)
    ref = {}
    for t in thresholds:
        ours = [r for r in timed if r["method"] == "pointcvx" and r["threshold"] == t]
        ref[t] = (mean_median(ours, "oneshot_seconds")[1], mean_median(ours, "seconds")[1])
    out = ["", f"{level} Time: one-shot (whole process) and warm (the method's call)", "",
           "One-shot: the method run once on one file as a fresh process, the way a user runs it "
           "(`pointcvx decompose`; thin Python wrappers of the baselines), timed from its start "
           "to its exit: start-up, imports, model loading, reading and writing included. Warm: the "
           "method's call alone, in a process that has imported everything and, for pointcvx, "
           "loaded its model and run one small decomposition first. Medians over the runs that "
           "have both; x pointcvx: the median over pointcvx's.", "",
           "| method | setting | threshold | runs | one-shot median s | warm median s "
           "| one-shot x pointcvx | warm x pointcvx |",
           "|---|---|---|---|---|---|---|---|"]
    for m, s, t in groups:
        g = [r for r in timed if (r["method"], r["setting"], r["threshold"]) == (m, s, t)]
        once, warm = mean_median(g, "oneshot_seconds")[1], mean_median(g, "seconds")[1]
        ref_once, ref_warm = ref.get(t or (thresholds[0] if thresholds else ""), (math.nan, math.nan))
        out.append(f"| {m} | {s} | {t or '–'} | {len(g)} | {_f(once)} | {_f(warm)} "
                   f"| {_f(_ratio(once, ref_once), 3)} | {_f(_ratio(warm, ref_warm), 3)} |")
    return out


def summarize(rows: Sequence[dict]) -> str:
    """``summary.md``: per dataset, then per category within it, the means and medians of hulls,
    concavity, reconstruction, seconds and peak MB per method and setting; pointcvx's paired
    win/tie/loss counts against each baseline at matched granularity; the ratio of median times
    baseline / pointcvx."""
    rows = list(rows)
    lines = ["# pointcvx bench", "",
             f"{len(rows)} rows, {len({(r['dataset'], r['shape']) for r in rows})} shapes. All shapes "
             "normalised to [-1, 1]^3; lower is better for concavity, reconstruction, seconds "
             "and peak MB. Means and medians are over the rows without error."]
    for ds in dict.fromkeys(r["dataset"] for r in rows):
        drows = [r for r in rows if r["dataset"] == ds]
        n = len({r["shape"] for r in drows})
        lines += ["", f"## Dataset `{ds}` ({n} shapes)"]
        lines += _section(drows, "###")
        cats = list(dict.fromkeys(r["category"] for r in drows))
        if len(cats) > 1:
            for cat in cats:
                crows = [r for r in drows if r["category"] == cat]
                lines += ["", f"### Category `{cat}` ({len({r['shape'] for r in crows})} shapes)"]
                lines += _section(crows, "####")
    return "\n".join(lines) + "\n"


def final_summary(report: BenchReport) -> str:
    """The lines `pointcvx bench` prints at the end: rows written and medians per method."""
    rows = report.rows
    lines = [f"{report.new_rows} new rows, {len(rows)} in {report.outdir / 'results.csv'}"]
    width = max((len(f"{m} {s} {t}") for m, s, t in method_groups(rows)), default=10)
    for m, s, t in method_groups(rows):
        g = [r for r in rows if (r["method"], r["setting"], r["threshold"]) == (m, s, t)]
        ok = [r for r in g if is_ok(r)]
        name = f"{m} {s} {t}".strip()
        med = {k: mean_median(ok, k)[1]
               for k in ("hulls", "concavity", "reconstruction", "seconds", "oneshot_seconds")}
        once = med["oneshot_seconds"]
        once = f"  one-shot s {_f(once, 3)}" if math.isfinite(once) else ""
        lines.append(f"  {name:<{width}}  {len(ok):>4}/{len(g):<4} ok  hulls {_f(med['hulls'], 3):>5}  "
                     f"concavity {_f(med['concavity'])}  reconstruction {_f(med['reconstruction'])}  "
                     f"warm s {_f(med['seconds'], 3)}{once}  (medians)")
    lines.append(f"summary: {report.outdir / 'summary.md'}")
    return "\n".join(lines)
