"""The worker side of a batch: prepare a process (threads, imports, model) and run one asset in
it, the same function in a local pool process and in a Ray actor."""

from __future__ import annotations

import contextlib
import dataclasses
import gc
import os
import socket
import time
from pathlib import Path
from typing import Any

from ...errors import first_line
from ..common import Orphaned, limit_threads, peak_kb, stop_if_orphaned
from .assets import asset_seed
from .guard import MEMORY_SHARE, AssetTimeout, Guard, machine_memory_mb, reset_peak
from .options import BatchOptions
from .records import output_path


def worker_label() -> str:
    """``host:pid`` of this process, the ``worker`` of its records."""
    return f"{socket.gethostname()}:{os.getpid()}"


def init_worker(options: BatchOptions, workers_here: int | None = None) -> BatchOptions:
    """Prepare this process to run assets: fix its thread count, import what
    :func:`pointcvx.decompose` imports lazily and, for ``features="model"``, load the model (kept
    for every later asset) (:func:`pointcvx.pipeline.preload`: imported here, not during, and
    interrupted with, an asset). Returns ``options`` with ``max_memory_mb`` resolved (default:
    this machine's share for ``workers_here`` workers, or for one worker per ``threads`` CPUs)."""
    from ...pipeline import preload

    limit_threads(options.threads)
    preload(options.decompose.features, options.decompose.model)
    if options.max_memory_mb is None:
        n = workers_here or max(1, (os.cpu_count() or 1) // max(1, options.threads))
        total = machine_memory_mb()
        limit = MEMORY_SHARE * total / n if total else 0.0
        options = dataclasses.replace(options, max_memory_mb=limit)
    return options


def run_asset(asset: dict, options: BatchOptions, outdir: str) -> dict:
    """Decompose one asset in this (worker) process; never raises for the asset's own problems.

    Parameters
    ----------
    asset : dict
        ``{"id": str, "path": str}`` (:class:`~pointcvx.apps.batch.assets.Asset` as a dict) and
        optionally ``"config"``, the settings' fingerprint
        (:meth:`~pointcvx.apps.batch.BatchOptions.fingerprint`, computed once by the driver).
    options : BatchOptions
        The batch's settings, ``max_memory_mb`` resolved (:func:`init_worker`).
    outdir : str
        The batch's output folder, as the driver sees it (used only to name the files).

    Returns
    -------
    dict
        ``{"record": manifest record, "files": {path relative to outdir: str or bytes},
        "recycle": bool}``; the record's ``status`` is ``done`` or ``failed`` (with ``error``, one
        line); ``recycle``: a limit interrupted the asset, so the worker's state may be broken
        (half-done imports...) and the driver replaces it.
    """
    from ...export import main_file, output_folder, plan

    seed = asset_seed(options.seed, asset["id"])
    record: dict[str, Any] = {"id": asset["id"], "path": asset["path"], "status": "failed", "error": "",
                              "seed": seed, "worker": worker_label(),
                              "config": asset.get("config") or options.fingerprint()}
    files: dict[str, str | bytes] = {}
    gc.collect()  # start every asset from the same clean heap, whatever ran before in this worker
    measured = reset_peak()
    guard = Guard(options.timeout, options.max_memory_mb)
    t0, cpu0 = time.perf_counter(), time.process_time()
    try:
        try:
            guard.start()
            from ...pipeline import decompose

            result = decompose(asset["path"], **options.decompose_kwargs(seed))
            target = output_path(outdir, asset["id"], options.format)
            planned = plan(result, target, options.format)
            main = main_file(target, options.format)
        finally:
            guard.stop()
        if guard.reason:  # the limit's exception was swallowed somewhere: still a failure
            raise AssetTimeout(guard.reason)
        root = Path(outdir)
        files = {p.relative_to(root).as_posix(): data for p, data in planned.items()}
        summary = result.summary()
        record.update(status="done", hulls=summary["hulls"], max_concavity=summary["max_concavity"],
                      mean_concavity=summary["mean_concavity"], points=summary["points"],
                      output=(main if main is not None else output_folder(target, options.format))
                      .relative_to(root)
                      .as_posix(), files=sorted(files))
    # An asset may fail in any way (bad file, library error, limits): record it and go on.
    except Exception as exc:  # noqa: BLE001
        guard.stop()
        record["error"] = guard.reason or first_line(exc, typed=True)
        files = {}
    record["seconds"] = round(time.perf_counter() - t0, 3)
    record["cpu_seconds"] = round(time.process_time() - cpu0, 3)
    record["peak_mb"] = round(peak_kb() / 1024.0, 1) if measured else None
    # Interrupted anywhere (an import, a library's state): this process is not trusted any more.
    return {"record": record, "files": files, "recycle": bool(guard.reason)}


def local_worker(conn, options: dict, outdir: str, workers_here: int) -> None:
    """Body of a local pool process: start, say ready, then run assets until told to stop."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the driver's: it stops the workers

    try:
        opts = init_worker(BatchOptions.from_dict(options), workers_here)
    except Exception as exc:  # noqa: BLE001 - reported to the driver in one line
        with contextlib.suppress(OSError):
            conn.send(("error", first_line(exc, typed=True)))
        return
    try:
        conn.send(("ready", worker_label()))
    except OSError:
        return
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError):
            return
        if task is None:
            return
        try:
            stop_if_orphaned()
        except Orphaned:
            return
        out = run_asset(task, opts, outdir)
        try:
            conn.send(("result", out))
        except OSError:
            return


class BatchActor:
    """The Ray actor of ``--engine ray`` (wrapped with ``ray.remote`` by
    :class:`~pointcvx.apps.batch.pools.RayPool`): one per
    worker, holding the settings and the loaded model, running :func:`run_asset`."""

    def __init__(self, options: dict, outdir: str):
        self.outdir = outdir
        self.error = ""
        try:
            self.options = init_worker(BatchOptions.from_dict(options))
        except Exception as exc:  # noqa: BLE001 - reported by ready()
            self.error = first_line(exc, typed=True)

    def ready(self) -> tuple[str, str]:
        return ("error", self.error) if self.error else ("ready", worker_label())

    def run(self, asset: dict) -> dict:
        return run_asset(asset, self.options, self.outdir)
