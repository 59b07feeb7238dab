"""The benchmark driver: every shape of every dataset, one after another or in a process pool,
resuming from ``results.csv`` (:func:`run_bench`)."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path

from ...errors import InputError, OutputError
from .options import BenchOptions
from .plot import plot_granularity
from .results import BenchReport, read_results, row_key, write_atomic, write_results
from .runs import ShapeBench, bench_shape
from .shapes import ShapeEntry, find_shapes
from .summary import summarize

Progress = Callable[[int, int, str], None]
"""progress(done, total, shape): called after each shape."""


def run_bench(
    datasets: Sequence[str | os.PathLike],
    outdir: str | os.PathLike,
    options: BenchOptions | None = None,
    *,
    limit: int | None = None,
    jobs: int = 1,
    overwrite: bool = False,
    progress: Progress | None = None,
) -> BenchReport:
    """Benchmark pointcvx and the baselines on ``datasets``; write the results into ``outdir``.

    Parameters
    ----------
    datasets : sequence of path
        Folders of shapes (searched recursively) or shape files.
    outdir : path
        Output folder (created): ``results.csv``, ``summary.md``, ``granularity.png``, ``hulls/``.
    options : BenchOptions, optional
        Methods and settings (default: ``BenchOptions()``: pointcvx, CoACD and V-HACD, fixed
        and matched).
    limit : int, optional
        At most this many shapes per dataset.
    jobs : int
        Shapes run at once (spawned processes; each still runs one method at a time).
    overwrite : bool
        Start over instead of skipping the rows already in ``outdir/results.csv``.
    progress : callable, optional
        ``progress(done, total, shape)`` after each shape.

    Returns
    -------
    BenchReport

    Raises
    ------
    InputError
        Bad settings, a missing dataset or baseline package.
    OutputError
        ``outdir`` cannot be created.
    """
    opts = options or BenchOptions()
    opts.check()
    if jobs < 1:
        raise InputError(f"jobs must be at least 1, got {jobs}")
    out = Path(outdir).absolute()
    entries = find_shapes(datasets, limit, exclude=out)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{out}: cannot create the output folder ({exc.strerror})") from None
    results = out / "results.csv"
    rows = [] if overwrite else read_results(results)
    done = {row_key(r): r for r in rows}
    if jobs > 1 and opts.threads is None:
        opts = dataclasses.replace(opts, threads=max(1, (os.cpu_count() or 1) // jobs))
    options_d = opts.to_dict()
    work = []
    for e in entries:
        mine = {k: v for k, v in done.items() if k.startswith(f"{e.dataset}\t{e.shape}\t")}
        if ShapeBench(e, opts, out, mine).pending():
            work.append((e, mine))
    total, finished, new = len(entries), len(entries) - len(work), 0
    if progress is not None and finished:
        progress(finished, total, "")

    def collect(e: ShapeEntry, new_rows: list[dict]) -> None:
        nonlocal finished, new
        rows.extend(new_rows)
        new += len(new_rows)
        write_results(results, rows)
        finished += 1
        if progress is not None:
            progress(finished, total, e.shape)

    if jobs == 1 or len(work) <= 1:
        for e, mine in work:
            collect(e, bench_shape(asdict(e), options_d, str(out), mine))
    else:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor, as_completed

        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=jobs, mp_context=ctx) as pool:
            futures = {pool.submit(bench_shape, asdict(e), options_d, str(out), mine): e
                       for e, mine in work}
            for fut in as_completed(futures):
                collect(futures[fut], fut.result())
    if not results.exists():
        write_results(results, rows)
    files = [results]
    write_atomic(out / "summary.md", summarize(rows))
    files.append(out / "summary.md")
    if plot_granularity(rows, out / "granularity.png"):
        files.append(out / "granularity.png")
    return BenchReport(rows, new, out, files)
