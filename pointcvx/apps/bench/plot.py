"""``granularity.png``: concavity and reconstruction against hull count, per method and setting
(needs matplotlib)."""

from __future__ import annotations

import io
import logging
import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .options import METHODS
from .results import num, write_atomic
from .summary import is_ok, mean_median, method_groups

log = logging.getLogger(__name__)


def plot_granularity(rows: Sequence[dict], path: str | os.PathLike) -> bool:
    """Write ``granularity.png``: concavity and reconstruction against hull count, one colour
    per method (dots: fixed setting, crosses: matched), with each method's medians per
    pointcvx threshold joined by a line. Returns False when matplotlib is not installed or
    there is nothing to plot."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.ticker import NullFormatter, ScalarFormatter
    except ImportError:
        log.info("matplotlib is not installed: no granularity.png")
        return False
    ok = [r for r in rows if is_ok(r) and math.isfinite(num(r.get("hulls")))]
    if not ok:
        return False
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    colours = {m: f"C{i}" for i, m in enumerate(METHODS)}
    for ax, metric in zip(axes, ("concavity", "reconstruction"), strict=True):
        for m, s, _t in method_groups(ok):
            g = [r for r in ok if (r["method"], r["setting"]) == (m, s)]
            x = np.array([num(r["hulls"]) for r in g])
            y = np.array([num(r.get(metric)) for r in g])
            keep = np.isfinite(y)
            if not keep.any():
                continue
            label = f"{m} ({s})"
            if label in [h.get_label() for h in ax.collections]:
                label = None
            ax.scatter(x[keep], y[keep], s=14, alpha=0.6, color=colours.get(m, "k"),
                       marker="o" if s == "fixed" else "x", label=label)
        for m in METHODS:
            g = [r for r in ok if r["method"] == m and r["threshold"]]
            ts = sorted({r["threshold"] for r in g}, key=num)
            if len(ts) < 2:
                continue
            pts = [(mean_median([r for r in g if r["threshold"] == t], "hulls")[1],
                    mean_median([r for r in g if r["threshold"] == t], metric)[1]) for t in ts]
            ax.plot(*zip(*pts, strict=True), "-", color=colours.get(m, "k"), lw=1.5)
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("hulls")
        ax.set_ylabel(metric)
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    plt.close(fig)
    write_atomic(Path(path), buf.getvalue())
    return True
