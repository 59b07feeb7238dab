"""The driver of a batch: pick the assets left to do, run them on a pool, replace dead or stuck
workers, write each result as it comes, and end with the reports."""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from collections import deque
from collections.abc import Callable, Sequence
from datetime import datetime, timezone
from pathlib import Path

from ...errors import InputError, OutputError, PointcvxError, first_line
from .assets import Asset, asset_seed, find_assets
from .guard import GRACE, MEMORY_SHARE, machine_memory_mb
from .options import BatchOptions
from .pools import LocalPool, RayPool, import_ray, ray_session
from .records import (
    MANIFEST,
    BatchReport,
    Manifest,
    is_done,
    output_path,
    report_row,
    report_summary,
    write_reports,
)

log = logging.getLogger(__name__)

ENGINES = ("local", "ray")
"""Where the workers run: a local pool of spawned processes, or Ray actors."""
LOCK = ".batch.lock"
"""The file in the output folder that one batch at a time holds locked."""
START_TIMEOUT = 300.0
"""Seconds without any worker started (ready) before the batch gives up."""

Progress = Callable[[int, int, dict], None]
"""progress(finished, total, record): called after each asset this run finishes."""


def _lock(outdir: Path):
    """Lock ``outdir`` for this batch (the open lock file; closing it unlocks), or raise
    :class:`OutputError` if another batch holds it."""
    import fcntl

    f = open(outdir / LOCK, "a")
    try:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        f.close()
        raise OutputError(f"{outdir}: another pointcvx batch is writing into this folder") from None
    return f


def _drive(pool, jobs: int, work: list[Asset], options: BatchOptions, config: str,
           on_result: Callable[[Asset, dict], None], stats: dict) -> None:
    """Run every asset of ``work`` on ``pool``'s ``jobs`` workers; ``on_result(asset, outcome)``
    with ``{"record": ..., "files": ...}``, also for assets whose worker died or hung.
    ``stats["startup"]``: seconds until the first worker was ready."""
    queue = deque(work)
    state = ["starting"] * jobs
    running: dict[int, tuple[Asset, float]] = {}
    start_failures = [0] * jobs
    hard_limit = options.timeout + 2 * GRACE
    t_start = time.monotonic()
    for i in range(jobs):
        pool.start(i)
    last_alive = time.monotonic()

    def failed(asset: Asset, error: str, seconds: float, worker: str = "") -> dict:
        rec = {"id": asset.id, "path": asset.path, "status": "failed", "error": error,
               "seconds": round(seconds, 3), "seed": asset_seed(options.seed, asset.id),
               "worker": worker, "config": config, "peak_mb": None}
        return {"record": rec, "files": {}}

    labels = [""] * jobs

    def respawn(i: int) -> None:  # a fresh worker in slot i, if any asset is left for it
        state[i] = "starting" if queue else "gone"
        if queue:
            pool.start(i)

    while queue or running:
        for i in range(jobs):
            if state[i] == "idle" and queue:
                asset = queue.popleft()
                pool.submit(i, {"id": asset.id, "path": asset.path, "config": config})
                running[i] = (asset, time.monotonic())
                state[i] = "busy"
        for ev in pool.poll(0.2):
            i = ev.slot
            if ev.kind == "ready":
                state[i], labels[i], start_failures[i] = "idle", str(ev.value), 0
                stats.setdefault("startup", time.monotonic() - t_start)
            elif ev.kind == "result":
                asset, _ = running.pop(i)
                state[i] = "idle"
                on_result(asset, ev.value)
                if ev.value.get("recycle"):
                    pool.kill(i)
                    respawn(i)
            else:  # "died" or "error"
                if i in running:
                    asset, t0 = running.pop(i)
                    took = time.monotonic() - t0
                    reason = str(ev.value)
                    if took > options.timeout and "timeout" not in reason:
                        reason = f"timeout after {options.timeout:g} s ({reason})"
                    on_result(asset, failed(asset, reason, took, labels[i]))
                elif state[i] == "starting":
                    start_failures[i] += 1
                    if ev.kind == "error" or start_failures[i] >= 3:
                        raise PointcvxError(f"batch worker cannot start: {ev.value}")
                respawn(i)
        now = time.monotonic()
        for i, (asset, t0) in list(running.items()):
            if now - t0 > hard_limit:
                log.warning("%s: worker %s still busy %.0f s past the timeout: killed", asset.id,
                            labels[i], now - t0 - options.timeout)
                pool.kill(i)
                running.pop(i)
                on_result(asset, failed(asset, f"timeout after {options.timeout:g} s (worker killed)",
                                        now - t0, labels[i]))
                respawn(i)
        if any(s in ("idle", "busy") for s in state) or not queue:
            last_alive = now
        elif now - last_alive > START_TIMEOUT:
            raise PointcvxError(f"no batch worker started in {START_TIMEOUT:g} s "
                                "(not enough CPUs in the Ray cluster for --jobs x --threads?)")


def run_batch(
    inputs: Sequence[str | os.PathLike],
    outdir: str | os.PathLike,
    options: BatchOptions | None = None,
    *,
    engine: str = "local",
    jobs: int | None = None,
    address: str | None = None,
    retry_failed: bool = True,
    overwrite: bool = False,
    progress: Progress | None = None,
) -> BatchReport:
    """Decompose every asset of ``inputs`` into ``outdir``, skipping those already done.

    Parameters
    ----------
    inputs : sequence of path or str
        Folders, files, glob patterns, manifest files (see :func:`~pointcvx.apps.batch.assets.find_assets`).
    outdir : path
        Output folder (created): ``hulls/``, ``batch_manifest.jsonl``, ``batch_report.csv``,
        ``batch_report.json``.
    options : BatchOptions, optional
    engine : {"local", "ray"}
        A local pool of spawned processes, or Ray actors.
    jobs : int, optional
        Workers (default: local, this machine's CPUs divided by ``options.threads``; Ray, the
        cluster's CPUs divided by it).
    address : str, optional
        With Ray: the cluster to join (``auto``, ``HOST:PORT``, ``ray://HOST:PORT``); default: the
        instance this process already joined, else a local one started for this batch.
    retry_failed : bool
        Run again the assets the manifest records as failed (default); False keeps them failed.
    overwrite : bool
        Forget the manifest and redo every asset.
    progress : callable, optional
        ``progress(finished, total, record)`` after each asset of this run.

    Returns
    -------
    BatchReport

    Raises
    ------
    InputError
        Bad settings, no asset, a missing input, an unreadable manifest.
    OutputError
        ``outdir`` is a file, cannot be created, or another batch is writing into it.
    MissingExtraError
        ``engine="ray"`` without Ray installed.
    """
    opts = options or BatchOptions()
    opts.check()
    if engine not in ENGINES:
        raise InputError(f"unknown engine {engine!r}; expected one of {', '.join(ENGINES)}")
    if jobs is not None and jobs < 1:
        raise InputError(f"jobs must be at least 1, got {jobs}")
    if engine == "ray":
        import_ray()
    out = Path(outdir).absolute()
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder")
    assets = find_assets(inputs, exclude=out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{out}: cannot create the output folder ({exc.strerror})") from None
    lock = _lock(out)
    manifest = Manifest(out / MANIFEST)
    try:
        previous = {} if overwrite else manifest.read()
        config = opts.fingerprint()
        state: dict[str, dict | None] = {a.id: previous.get(a.id) for a in assets}
        work, skipped = [], 0
        for a in assets:
            rec = state[a.id]
            if is_done(rec, config, out):
                skipped += 1
            elif rec is not None and rec.get("status") == "failed" and not retry_failed \
                    and rec.get("config") == config:
                pass
            else:
                work.append(a)
        log.info("%d assets: %d already done, %d to run", len(assets), skipped, len(work))
        manifest.open(truncate=overwrite)
        t0 = time.perf_counter()
        finished = 0
        stats: dict[str, float] = {}

        def on_result(asset: Asset, outcome: dict) -> None:
            nonlocal finished
            from ...export import main_file, output_folder, write_files

            rec = dict(outcome["record"])
            if rec.get("status") == "done":
                target = output_path(out, asset.id, opts.format)
                folder = output_folder(target, opts.format)  # a folder format: written whole
                main = main_file(target, opts.format)
                about = {"format": opts.format, "main": main.name if main is not None else None}
                try:
                    write_files({out / rel: data for rel, data in outcome["files"].items()},
                                overwrite=True, protect=[asset.path], folder=folder,
                                about=about if folder is not None else None)
                except (OutputError, OSError) as exc:
                    rec.update(status="failed", error=f"writing the hulls: {first_line(exc, typed=True)}")
            rec["finished"] = datetime.now(timezone.utc).isoformat(timespec="seconds")
            manifest.append(rec)
            state[asset.id] = rec
            finished += 1
            if rec["status"] == "failed":
                log.info("%s: failed: %s", asset.id, rec.get("error"))
            if progress is not None:
                progress(finished, len(work), rec)

        def drive(pool_type, cpus: int, run_opts: BatchOptions) -> int:
            """Run ``work`` on ``--jobs`` workers (default: ``cpus`` / threads) of ``pool_type``."""
            n = min(jobs or max(1, cpus // opts.threads), len(work))
            if engine == "local" and run_opts.max_memory_mb is None and machine_memory_mb():
                run_opts = dataclasses.replace(run_opts,
                                               max_memory_mb=MEMORY_SHARE * machine_memory_mb() / n)
            pool = pool_type(n, run_opts, str(out))
            try:
                _drive(pool, n, work, run_opts, config, on_result, stats)
            finally:
                pool.close()
            return n

        n_jobs = jobs
        try:
            if work and engine == "local":
                n_jobs = drive(LocalPool, os.cpu_count() or 1, opts)
            elif work:
                with ray_session(address, num_cpus=(jobs * opts.threads if jobs else None)) as ray:
                    n_jobs = drive(RayPool, int(ray.cluster_resources().get("CPU", 1)), opts)
        finally:
            wall = time.perf_counter() - t0
            rows = [report_row(a, state[a.id], out) for a in assets]
            summary = report_summary(rows, finished, skipped, wall, stats.get("startup"), engine, n_jobs,
                                     opts, config, out)
            files = write_reports(out, rows, summary)
    finally:
        manifest.close()
        lock.close()
    return BatchReport(rows, summary, out, files)
