"""``pointcvx batch``: decompose many shapes, resumably, on a local process pool or a Ray cluster.

Inputs are folders (searched recursively for shape files, see
:data:`pointcvx.apps.common.SHAPE_SUFFIXES`), glob patterns, single files, or manifest files (``.txt``,
``.lst``, ``.list``: one path per line, ``#`` comments; ``.json``: a list of paths or of
``{"path": ..., "id": ...}`` objects; relative paths are relative to the manifest). Every file
becomes an *asset* with a stable id (:func:`find_assets`): its path relative to the folder, the
glob's fixed prefix or the manifest, without the suffix, e.g. ``objects/mug``.

Per asset, in a long-lived worker process (:func:`run_asset`, the same function for both
engines):

- :func:`pointcvx.decompose` with the batch's settings and a seed derived from the batch seed and
  the asset id (:func:`asset_seed`): an asset's hulls depend neither on the worker count nor on
  the order in which assets run (each worker also uses a fixed number of threads, ``threads``;
  see docs/batch.md);
- a guard (:class:`Guard`): past ``timeout`` seconds or over ``max_memory_mb`` of resident
  memory, the decomposition is interrupted and the asset recorded as failed; a worker that does
  not stop within :data:`GRACE` seconds exits, and the driver kills any worker still busy
  :data:`GRACE` seconds after that. A worker that dies (killed, out of memory, crashed) costs only
  the asset it was running, recorded as failed; a fresh worker replaces it;
- the hulls are laid out in memory (:func:`pointcvx.export.plan`, the formats of ``pointcvx
  decompose --format``) and sent back: the driver writes them (atomically) under
  ``OUTDIR/hulls/<id>.<ext>``. With Ray, workers on other machines therefore need to read the
  inputs at the same paths (a shared file system) but never write to ``OUTDIR``.

The model of ``features="model"`` is loaded once per worker, when the worker starts
(:func:`init_worker`), and kept for every asset it runs.

The driver (:func:`run_batch`) is the only writer of ``OUTDIR``:

``batch_manifest.jsonl``
    One JSON line per finished asset, appended (and fsynced) as it finishes: ``id``, ``path``,
    ``status`` (``done`` or ``failed``), ``error`` (one line), ``seconds`` (wall) and
    ``cpu_seconds`` (the worker's CPU time, all its threads) of the asset, ``hulls``,
    ``max_concavity``, ``mean_concavity``, ``peak_mb`` (the worker's peak resident memory during
    this asset), ``seed``, ``worker`` (host:pid), ``output`` and ``files`` (relative to OUTDIR),
    ``config`` (a fingerprint of the settings that change results) and ``finished`` (UTC). The
    last line of an asset wins; a line cut short by a crash is ignored. The hull files are
    written before their line, so ``done`` always means the files are there.
``batch_report.csv``, ``batch_report.json``
    The state of every asset of this batch (one row each, :data:`COLUMNS`) and, in the JSON, a
    summary: counts, wall time, assets per minute, mean hulls and concavity.

Re-running the same command resumes: assets recorded ``done`` with the same settings (and whose
files still exist) are skipped; failed ones are tried again (unless ``retry_failed=False``,
``--skip-failed``); ``overwrite`` (``--overwrite``) redoes everything.

Modules, in the order a batch uses them: :mod:`.options` (the settings), :mod:`.assets` (inputs
to assets), :mod:`.guard` (per-asset limits), :mod:`.worker` (one asset in a worker),
:mod:`.pools` (local processes, Ray actors), :mod:`.records` (manifest and reports),
:mod:`.driver` (:func:`run_batch`).
"""

from __future__ import annotations

from .assets import MANIFEST_SUFFIXES, Asset, asset_seed, find_assets, read_manifest_file
from .driver import ENGINES, LOCK, START_TIMEOUT, Progress, run_batch
from .guard import (
    EXIT_MEMORY,
    EXIT_TIMEOUT,
    GRACE,
    MEMORY_SHARE,
    AssetMemoryError,
    AssetTimeout,
    Guard,
    machine_memory_mb,
    reset_peak,
    rss_mb,
)
from .options import BatchOptions
from .pools import LocalPool, RayPool, import_ray, ray_session
from .records import COLUMNS, HULLS, MANIFEST, REPORT_CSV, REPORT_JSON, BatchReport, Manifest, output_path
from .worker import BatchActor, init_worker, local_worker, run_asset, worker_label

__all__ = [
    "COLUMNS", "ENGINES", "EXIT_MEMORY", "EXIT_TIMEOUT", "GRACE", "HULLS", "LOCK", "MANIFEST",
    "MANIFEST_SUFFIXES", "MEMORY_SHARE", "REPORT_CSV", "REPORT_JSON", "START_TIMEOUT",
    "Asset", "AssetMemoryError", "AssetTimeout", "BatchActor", "BatchOptions", "BatchReport", "Guard",
    "LocalPool", "Manifest", "Progress", "RayPool",
    "asset_seed", "find_assets", "import_ray", "init_worker", "local_worker", "machine_memory_mb",
    "output_path", "ray_session", "read_manifest_file", "reset_peak", "rss_mb", "run_asset", "run_batch",
    "worker_label",
]
