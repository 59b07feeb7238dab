"""Matched granularity: bisect a baseline's parameter in log space until its hull count lands as
close as possible to pointcvx's."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from .launch import Run


def search_parameter(run: Callable[[float], Run], lo: float, hi: float, target: int, max_runs: int,
                     reuse: Sequence[Run] = (), evaluate: Callable[[Run], None] | None = None,
                     ) -> tuple[Run | None, list[Run]]:
    """Bisect a parameter in log space so that the hull count lands as close to ``target`` as
    possible; the count must fall as the parameter grows.

    Parameters
    ----------
    run : callable
        ``run(x)`` decomposes with parameter ``x`` and returns the run.
    lo, hi : float
        The search interval (positive); the first probe is its geometric middle.
    target : int
        The hull count aimed at.
    max_runs : int
        Probes at most (stops early on an exact hit).
    reuse : sequence of runs
        Finished runs; a probe at one's parameter takes it instead of running again.
    evaluate : callable, optional
        Scores a run (fills ``run.metrics``); used to break ties by lower concavity.

    Returns
    -------
    (best run or None if every probe failed, list of the runs tried in order)
    """
    tried: list[Run] = []
    lo, hi = math.log(lo), math.log(hi)
    for _ in range(max_runs):
        x = math.exp((lo + hi) / 2.0)
        r = next((r for r in reuse if r.param is not None and math.isclose(r.param, x, rel_tol=1e-6)),
                 None)
        if r is not None:
            r.reused = True
        else:
            r = run(x)
        tried.append(r)
        if r.ok and r.hulls == target:
            break
        if not r.ok or r.hulls > target:  # too many hulls (or too slow): coarser
            lo = math.log(x)
        else:
            hi = math.log(x)
    ok = [r for r in tried if r.ok]
    if not ok:
        return None, tried
    gap = min(abs(r.hulls - target) for r in ok)
    best = [r for r in ok if abs(r.hulls - target) == gap]
    if len(best) > 1 and evaluate is not None:
        for r in best:
            evaluate(r)

        def concavity(r: Run) -> float:
            c = (r.metrics or {}).get("concavity", math.nan)
            return c if math.isfinite(c) else math.inf

        best.sort(key=concavity)
    return best[0], tried
