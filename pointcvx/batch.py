"""``pointcvx batch``: decompose many shapes, resumably, on a local process pool or a Ray cluster.

Inputs are folders (searched recursively for shape files, see
:data:`pointcvx.bench.SHAPE_SUFFIXES`), glob patterns, single files, or manifest files (``.txt``,
``.lst``, ``.list``: one path per line, ``#`` comments; ``.json``: a list of paths or of
``{"path": ..., "id": ...}`` objects; relative paths are relative to the manifest). Every file
becomes an *asset* with a stable id (:func:`find_assets`): its path relative to the folder, the
glob's fixed prefix or the manifest, without the suffix, e.g. ``objects/mug``.

Per asset, in a long-lived worker process (:func:`run_asset`, the same function for both
engines):

- :func:`pointcvx.decompose` with the batch's settings and a seed derived from the batch seed and
  the asset id (:func:`asset_seed`): an asset's hulls depend neither on the worker count nor on
  the order in which assets run (each worker also uses a fixed number of threads, ``threads``;
  docs/batch.md records one STEP part that can differ in long-lived Ray workers);
- a guard (:class:`_Guard`): past ``timeout`` seconds or over ``max_memory_mb`` of resident
  memory, the decomposition is interrupted and the asset recorded as failed; a worker that does
  not stop within :data:`GRACE` seconds exits, and the driver kills any worker still busy
  :data:`GRACE` seconds after that. A worker that dies (killed, out of memory, crashed) costs only
  the asset it was running, recorded as failed; a fresh worker replaces it;
- the hulls are laid out in memory (:func:`pointcvx.export.plan`, the formats of ``pointcvx
  decompose --format``) and sent back: the driver writes them (atomically) under
  ``OUTDIR/hulls/<id>.<ext>``. With Ray, workers on other machines therefore need to read the
  inputs at the same paths (a shared file system) but never write to ``OUTDIR``.

The model of ``features="model"`` is loaded once per worker, when the worker starts
(:func:`pointcvx.pipeline.load_cached_model`), and kept for every asset it runs.

The driver is the only writer of ``OUTDIR``:

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
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import ctypes
import dataclasses
import gc
import glob
import hashlib
import io
import json
import logging
import math
import os
import re
import socket
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from .errors import InputError, MissingExtraError, OutputError, PointcvxError

log = logging.getLogger(__name__)

MANIFEST = "batch_manifest.jsonl"
REPORT_CSV = "batch_report.csv"
REPORT_JSON = "batch_report.json"
HULLS = "hulls"
LOCK = ".batch.lock"
MANIFEST_SUFFIXES = frozenset({".txt", ".lst", ".list", ".json"})
"""An input file with one of these suffixes is a manifest (a list of assets), not a shape."""
ENGINES = ("local", "ray")

GRACE = 10.0
"""Seconds a worker gets to stop an asset past its limit before it exits; the driver kills a
worker still busy with the asset :data:`GRACE` seconds after that."""
EXIT_TIMEOUT, EXIT_MEMORY = 124, 125
"""Exit statuses of a worker that had to exit to stop an asset over its time or memory limit."""
MEMORY_SHARE = 0.8
"""Default memory limit: this share of the machine's memory, split evenly between its workers."""
START_TIMEOUT = 300.0
"""Seconds without any worker started (ready) before the batch gives up."""

COLUMNS = ("id", "status", "error", "hulls", "max_concavity", "mean_concavity", "points", "seconds",
           "cpu_seconds", "peak_mb", "seed", "worker", "output", "path", "finished")
"""Columns of ``batch_report.csv`` (``status``: done, failed or pending)."""

Progress = Callable[[int, int, dict], None]
"""progress(finished, total, record): called after each asset this run finishes."""


# ------------------------------------------------------------------------------------ settings
@dataclass
class BatchOptions:
    """Settings of one batch.

    Attributes
    ----------
    format : str
        Output format per asset, one of :data:`pointcvx.export.FORMATS` (default ``obj``).
    threshold, max_hulls, features, model, views, merge, split, n_points, target, max_hull_vertices,
    subsurface
        :func:`pointcvx.decompose`'s settings.
    seed : int
        Batch seed; each asset runs with :func:`asset_seed` of it.
    load_options : dict
        Further loader settings (:class:`pointcvx.LoadOptions` fields, e.g. ``cad_mesh_size``).
    timeout : float
        Wall-clock seconds allowed to one asset.
    max_memory_mb : float, optional
        Resident memory (MB) a worker may reach while running an asset (it includes the worker's
        own libraries and model, about 0.5 GB); default: :data:`MEMORY_SHARE` of the machine's
        memory divided by its workers. 0 turns the guard off.
    threads : int
        Threads of each worker (BLAS, torch). Fixed, not derived from the worker count, so that
        results do not depend on it.
    """

    format: str = "obj"
    threshold: float = 0.1
    max_hulls: int = 64
    features: str = "auto"
    model: str | None = None
    views: int = 1
    merge: bool = True
    split: str = "auto"
    n_points: int = 20000
    seed: int = 0
    target: str | None = None
    max_hull_vertices: int | None = None
    subsurface: float | None = None
    load_options: dict = field(default_factory=dict)
    timeout: float = 600.0
    max_memory_mb: float | None = None
    threads: int = 1

    def check(self) -> None:
        """Raise :class:`InputError` on any unusable setting (before any worker starts)."""
        from .export import FORMATS
        from .pipeline import FEATURE_METHODS, check_subsurface
        from .recursive import SPLIT_METHODS

        if self.format not in FORMATS:
            raise InputError(f"unknown output format {self.format!r}; expected one of {', '.join(FORMATS)}")
        if self.features not in FEATURE_METHODS:
            raise InputError(f"unknown feature method {self.features!r}; expected one of {FEATURE_METHODS}")
        if self.split not in SPLIT_METHODS:
            raise InputError(f"unknown split method {self.split!r}; expected one of {SPLIT_METHODS}")
        if not (self.threshold > 0 and math.isfinite(self.threshold)):
            raise InputError(f"threshold must be positive, got {self.threshold}")
        for name in ("max_hulls", "views", "n_points", "threads"):
            if int(getattr(self, name)) < 1:
                raise InputError(f"{name} must be at least 1, got {getattr(self, name)}")
        if not (self.timeout > 0):
            raise InputError(f"timeout must be positive, got {self.timeout}")
        if self.max_memory_mb is not None and self.max_memory_mb < 0:
            raise InputError(f"max memory must be positive (0: no limit), got {self.max_memory_mb}")
        from .io import LoadOptions

        try:
            LoadOptions.from_kwargs(n_points=self.n_points, seed=self.seed, **self.load_options)
        except TypeError as exc:
            raise InputError(str(exc)) from None
        check_subsurface(self.subsurface)
        if self.target is not None or self.max_hull_vertices is not None:
            from .simplify import hull_limits

            hull_limits(self.target, self.max_hull_vertices)
        if self.features == "model" or (self.features == "auto" and self.model is not None):
            from .pipeline import bundled_model_path

            path = Path(self.model) if self.model is not None else bundled_model_path()
            if path is None:
                raise InputError("--features model needs --model CKPT: this build ships no model")
            if not path.is_file():
                raise InputError(f"{path}: no such model checkpoint")

    def decompose_kwargs(self, seed: int) -> dict:
        """Keyword arguments of :func:`pointcvx.decompose` for an asset with ``seed``."""
        return {"threshold": float(self.threshold), "max_hulls": int(self.max_hulls),
                "features": self.features, "model": self.model, "views": int(self.views),
                "merge": bool(self.merge), "split": self.split, "n_points": int(self.n_points),
                "seed": int(seed), "target": self.target, "max_hull_vertices": self.max_hull_vertices,
                "subsurface": self.subsurface,
                **self.load_options}

    def fingerprint(self) -> str:
        """16 hex digits naming the settings that change an asset's output (not the engine,
        workers, limits): a ``done`` asset with another fingerprint is done again. The model's
        content is part of it."""
        from .io import LoadOptions

        keys = {k: v for k, v in dataclasses.asdict(self).items()
                if k not in ("timeout", "max_memory_mb", "threads", "model")}
        defaults = dataclasses.asdict(LoadOptions())
        keys["load_options"] = {k: v for k, v in self.load_options.items()
                                if k not in defaults or defaults[k] != v}
        if self.features in ("model", "auto"):  # "auto" uses the model on splats
            from .pipeline import bundled_model_path

            path = Path(self.model) if self.model is not None else bundled_model_path()
            keys["model"] = _file_digest(path) if path is not None and path.is_file() else str(path)
        text = json.dumps(keys, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def _file_digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()[:16]


def asset_seed(seed: int, asset_id: str) -> int:
    """The seed of asset ``asset_id`` in a batch seeded ``seed``: a 31-bit integer from SHA-256,
    the same on every machine, whatever the worker count or order."""
    digest = hashlib.sha256(f"{int(seed)}/{asset_id}".encode()).digest()
    return int.from_bytes(digest[:4], "little") & 0x7FFFFFFF


# ------------------------------------------------------------------------------------ inputs
@dataclass(frozen=True)
class Asset:
    """One shape of a batch: its stable ``id`` (a relative POSIX path without suffix, also the
    name of its outputs under ``OUTDIR/hulls``) and its file ``path`` (absolute)."""

    id: str
    path: str


def _shape_suffixes() -> frozenset[str]:
    from .bench import SHAPE_SUFFIXES

    return SHAPE_SUFFIXES


def _is_glob(text: str) -> bool:
    return any(c in text for c in "*?[")


def _glob_base(pattern: str) -> Path:
    parts = Path(pattern).parts
    fixed = []
    for part in parts:
        if _is_glob(part):
            break
        fixed.append(part)
    return Path(*fixed) if fixed else Path(".")


def _clean_id(text: str) -> str:
    parts = []
    for comp in re.split(r"[\\/]+", text):
        comp = re.sub(r"[^A-Za-z0-9._-]+", "_", comp).strip()
        if comp in ("", ".", ".."):
            continue
        if comp.startswith("."):
            comp = "_" + comp[1:]
        parts.append(comp)
    return "/".join(parts) or "asset"


def _rel_id(path: Path, base: Path | None) -> str:
    """``path`` relative to ``base`` when under it, else its folder's name and its name (e.g.
    ``objects/mug``), without the suffix."""
    rel = None
    if base is not None:
        with contextlib.suppress(ValueError):
            rel = path.resolve().relative_to(base.resolve())
    if rel is None:
        rel = Path(*path.absolute().parts[-2:])
    return _clean_id(rel.with_suffix("").as_posix() if rel.suffix else rel.as_posix())


def _scan_folder(root: Path, exclude: Path | None) -> list[Path]:
    suffixes = _shape_suffixes()
    out = []
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root)
        if any(part.startswith(".") for part in rel.parts) or p.suffix.lower() not in suffixes:
            continue
        if exclude is not None and p.resolve().is_relative_to(exclude):
            continue
        if p.is_file():
            out.append(p)
    return out


def read_manifest_file(path: str | os.PathLike) -> list[tuple[str, str | None]]:
    """The entries of a manifest file: (path or pattern as written, id or None).

    ``.json``: a list of strings or of ``{"path": ..., "id": ...}`` objects; anything else:
    text, one entry per line, blank lines and ``#`` comments skipped.

    Raises
    ------
    InputError
        Unreadable, not text, bad JSON, or no entry.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{p}: not a manifest (not UTF-8 text)") from None
    except OSError as exc:
        raise InputError(f"{p}: cannot read the manifest ({exc.strerror or exc})") from None
    entries: list[tuple[str, str | None]] = []
    if p.suffix.lower() == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputError(f"{p}: not a JSON manifest ({exc.msg} at line {exc.lineno})") from None
        if not isinstance(data, list):
            raise InputError(f"{p}: a JSON manifest must be a list of paths or of "
                             "{\"path\": ..., \"id\": ...} objects")
        for i, item in enumerate(data):
            if isinstance(item, str) and item.strip():
                entries.append((item.strip(), None))
            elif isinstance(item, dict) and isinstance(item.get("path"), str) and item["path"].strip():
                ident = item.get("id")
                if ident is not None and (not isinstance(ident, str) or not ident.strip()):
                    raise InputError(f"{p}: entry {i}: 'id' must be a non-empty string")
                entries.append((item["path"].strip(), ident.strip() if ident else None))
            else:
                raise InputError(f"{p}: entry {i} is neither a path nor an object with a 'path'")
    else:
        if "\x00" in text:
            raise InputError(f"{p}: not a manifest (binary content)")
        for line in text.splitlines():
            line = line.strip()
            if line and not line.startswith("#"):
                entries.append((line, None))
    if not entries:
        raise InputError(f"{p}: the manifest lists no asset")
    return entries


def _expand(spec: str, base: Path | None, exclude: Path | None, in_manifest: bool
            ) -> list[tuple[Path, str]]:
    """(file, candidate id) pairs of one input or manifest entry."""
    p = Path(spec)
    if base is not None and not p.is_absolute():
        p = base / p
    if p.is_dir():
        files = _scan_folder(p, exclude)
        if not files and not in_manifest:
            raise InputError(f"{p}: no shape file in this folder (looked for "
                             f"{', '.join(sorted(_shape_suffixes()))})")
        return [(f, _rel_id(f, p)) for f in files]
    if p.is_file():
        if not in_manifest and p.suffix.lower() in MANIFEST_SUFFIXES:
            out = []
            for entry, ident in read_manifest_file(p):
                found = _expand(entry, p.parent, exclude, True)
                if ident is not None:
                    found = [(f, _clean_id(ident) if len(found) == 1 else f"{_clean_id(ident)}/{i}")
                             for f, i in found]
                out += found
            if not out:
                raise InputError(f"{p}: the manifest's entries match no file")
            return out
        return [(p, _rel_id(p, base) if in_manifest else _clean_id(p.stem))]
    text = str(p)
    if _is_glob(text):
        root = _glob_base(text)
        suffixes = _shape_suffixes()
        files = [Path(f) for f in sorted(glob.glob(text, recursive=True))
                 if Path(f).is_file() and Path(f).suffix.lower() in suffixes
                 and (exclude is None or not Path(f).resolve().is_relative_to(exclude))]
        if not files and not in_manifest:
            raise InputError(f"{spec}: no shape file matches this pattern")
        return [(f, _rel_id(f, root)) for f in files]
    if in_manifest:  # a listed file that is missing: the asset fails, the batch goes on
        return [(p, _rel_id(p, base))]
    raise InputError(f"{spec}: no such file, folder or pattern")


def find_assets(inputs: Sequence[str | os.PathLike], exclude: str | os.PathLike | None = None
                ) -> list[Asset]:
    """The assets of ``inputs`` (folders, globs, files, manifest files), in order, each file once.

    Ids: a folder's files are named by their path relative to it, a glob's by their path relative
    to its fixed prefix, a manifest's entries by their ``id`` or their path relative to the
    manifest's folder (outside it: their folder's name and their name, e.g. ``objects/mug``), a
    file given directly by its stem; always without the suffix and with characters
    other than ``A-Za-z0-9._-/`` replaced by ``_``. A clash (case-insensitive) renames the later
    asset ``<id>_<ext>`` then ``<id>-2``, ``<id>-3``... Anything under ``exclude`` (the output
    folder) is left out of folders and globs. A manifest may list files that do not exist (the
    asset fails when it runs); a missing command-line input is an error.

    Raises
    ------
    InputError
        A missing input, an empty folder, a glob matching nothing, an unreadable manifest, or no
        asset at all.
    """
    if not inputs:
        raise InputError("no input given: pass folders, files, glob patterns or a manifest file")
    skip = Path(exclude).resolve() if exclude is not None else None
    assets: list[Asset] = []
    seen_paths: set[Path] = set()
    taken: set[str] = set()
    for spec in inputs:
        for path, ident in _expand(str(spec), None, skip, False):
            key = path.resolve()
            if key in seen_paths:
                continue
            seen_paths.add(key)
            unique = ident
            if unique.casefold() in taken:
                ext = path.suffix.lstrip(".").lower()
                unique = f"{ident}_{_clean_id(ext)}" if ext else ident
                i = 2
                while unique.casefold() in taken:
                    unique = f"{ident}-{i}"
                    i += 1
            taken.add(unique.casefold())
            assets.append(Asset(unique, str(path.absolute())))
    if not assets:
        raise InputError("no asset found in the inputs")
    return assets


# ------------------------------------------------------------------------------------ worker side
class AssetTimeout(PointcvxError):
    """An asset ran past its time limit."""


class AssetMemoryError(PointcvxError):
    """A worker's resident memory went over its limit while running an asset."""


def _rss_mb() -> float:
    """Resident memory of this process in MB (0 where it cannot be read)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return 0.0


def _reset_peak() -> bool:
    """Reset this process's peak resident memory (Linux ``clear_refs``); False if it cannot."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def machine_memory_mb() -> float:
    """Physical memory of this machine in MB (0 if unknown)."""
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (ValueError, OSError, AttributeError):
        return 0.0


class _Guard:
    """Watch the calling thread while it runs one asset: past ``timeout`` seconds or over
    ``max_mb`` of resident memory, raise :class:`AssetTimeout` / :class:`AssetMemoryError` in it
    (an asynchronous exception, delivered between two Python bytecodes); if it has not stopped
    :data:`GRACE` seconds later (stuck in native code), exit the process with
    :data:`EXIT_TIMEOUT` / :data:`EXIT_MEMORY` so that its driver records the failure and starts a
    fresh worker."""

    def __init__(self, timeout: float, max_mb: float | None, interval: float = 0.1):
        self.timeout, self.max_mb, self.interval = float(timeout), max_mb or None, interval
        self.reason = ""
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._fired = False
        self._thread: threading.Thread | None = None
        self._target = threading.get_ident()
        self.started = time.monotonic()

    def start(self) -> _Guard:
        self._target = threading.get_ident()
        self.started = time.monotonic()
        self._thread = threading.Thread(target=self._watch, name="pointcvx-batch-guard", daemon=True)
        self._thread.start()
        return self

    def _watch(self) -> None:
        while not self._stop.wait(self.interval):
            elapsed = time.monotonic() - self.started
            if elapsed > self.timeout:
                self._fire(AssetTimeout, f"timeout after {self.timeout:g} s", EXIT_TIMEOUT)
                return
            if self.max_mb is not None:
                rss = _rss_mb()
                if rss > self.max_mb:
                    self._fire(AssetMemoryError, f"memory limit: {rss:.0f} MB resident, over the "
                               f"limit of {self.max_mb:.0f} MB", EXIT_MEMORY)
                    return

    def _fire(self, exc_type: type, reason: str, code: int) -> None:
        with self._lock:
            if self._stop.is_set():
                return
            self._fired = True
            self.reason = reason
            ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(self._target),
                                                       ctypes.py_object(exc_type))
        log.warning("%s; stopping the asset", reason)
        if not self._stop.wait(GRACE):
            log.error("%s and the asset did not stop within %g s: the worker exits", reason, GRACE)
            with contextlib.suppress(Exception):
                sys.stderr.flush()
            os._exit(code)

    def stop(self) -> None:
        """Stop watching (idempotent); a limit's exception not yet delivered is withdrawn."""
        with self._lock:
            self._stop.set()
            if self._fired:
                ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(self._target), None)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    first = text.splitlines()[0] if text else ""
    return f"{type(exc).__name__}: {first}"[:300] if first else type(exc).__name__


def _worker_label() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def init_worker(options: BatchOptions, workers_here: int | None = None) -> BatchOptions:
    """Prepare this process to run assets: fix its thread count, import what
    :func:`pointcvx.decompose` imports lazily and, for ``features="model"``, load the model (kept
    for every later asset) (:func:`pointcvx.pipeline.preload`: imported here, not during, and
    interrupted with, an asset). Returns ``options`` with ``max_memory_mb`` resolved (default:
    this machine's share for ``workers_here`` workers, or for one worker per ``threads`` CPUs)."""
    from ._bench_worker import _limit_threads
    from .pipeline import preload

    _limit_threads(options.threads)
    preload(options.features, options.model)
    if options.max_memory_mb is None:
        n = workers_here or max(1, (os.cpu_count() or 1) // max(1, options.threads))
        total = machine_memory_mb()
        limit = MEMORY_SHARE * total / n if total else 0.0
        options = dataclasses.replace(options, max_memory_mb=limit)
    return options


def output_path(outdir: str | os.PathLike, asset_id: str, format: str) -> Path:
    """Where asset ``asset_id``'s hulls go: ``OUTDIR/hulls/<id><ext>`` (folder formats: the folder
    ``OUTDIR/hulls/<id>/``, see :mod:`pointcvx.export`)."""
    from .export import EXTENSIONS

    return Path(outdir) / HULLS / f"{asset_id}{EXTENSIONS[format]}"


def run_asset(asset: dict, options: BatchOptions, outdir: str) -> dict:
    """Decompose one asset in this (worker) process; never raises for the asset's own problems.

    Parameters
    ----------
    asset : dict
        ``{"id": str, "path": str}`` (:class:`Asset` as a dict) and optionally ``"config"``, the
        settings' fingerprint (:meth:`BatchOptions.fingerprint`, computed once by the driver).
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
    from .export import main_file, plan

    seed = asset_seed(options.seed, asset["id"])
    record: dict[str, Any] = {"id": asset["id"], "path": asset["path"], "status": "failed", "error": "",
                              "seed": seed, "worker": _worker_label(),
                              "config": asset.get("config") or options.fingerprint()}
    files: dict[str, str | bytes] = {}
    gc.collect()  # start every asset from the same clean heap, whatever ran before in this worker
    measured = _reset_peak()
    guard = _Guard(options.timeout, options.max_memory_mb)
    t0, cpu0 = time.perf_counter(), time.process_time()
    try:
        try:
            guard.start()
            from .pipeline import decompose

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
                      output=(main if main is not None else target.with_suffix("")).relative_to(root)
                      .as_posix(), files=sorted(files))
    # An asset may fail in any way (bad file, library error, limits): record it and go on.
    except Exception as exc:  # noqa: BLE001
        guard.stop()
        record["error"] = guard.reason or _first_line(exc)
        files = {}
    record["seconds"] = round(time.perf_counter() - t0, 3)
    record["cpu_seconds"] = round(time.process_time() - cpu0, 3)
    from ._bench_worker import peak_kb

    record["peak_mb"] = round(peak_kb() / 1024.0, 1) if measured else None
    # Interrupted anywhere (an import, a library's state): this process is not trusted any more.
    return {"record": record, "files": files, "recycle": bool(guard.reason)}


def _local_worker(conn, options: dict, outdir: str, workers_here: int) -> None:
    """Body of a local pool process: start, say ready, then run assets until told to stop."""
    import signal

    from .bench import BenchStopped, _stop_if_orphaned

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the driver's: it stops the workers

    try:
        opts = init_worker(BatchOptions(**options), workers_here)
    except Exception as exc:  # noqa: BLE001 - reported to the driver in one line
        with contextlib.suppress(OSError):
            conn.send(("error", _first_line(exc)))
        return
    try:
        conn.send(("ready", _worker_label()))
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
            _stop_if_orphaned()
        except BenchStopped:
            return
        out = run_asset(task, opts, outdir)
        try:
            conn.send(("result", out))
        except OSError:
            return


class BatchActor:
    """The Ray actor of ``--engine ray`` (wrapped with ``ray.remote`` by the driver): one per
    worker, holding the settings and the loaded model, running :func:`run_asset`."""

    def __init__(self, options: dict, outdir: str):
        self.outdir = outdir
        self.error = ""
        try:
            self.options = init_worker(BatchOptions(**options))
        except Exception as exc:  # noqa: BLE001 - reported by ready()
            self.error = _first_line(exc)

    def ready(self) -> tuple[str, str]:
        return ("error", self.error) if self.error else ("ready", _worker_label())

    def run(self, asset: dict) -> dict:
        return run_asset(asset, self.options, self.outdir)


# ------------------------------------------------------------------------------------ engines
@dataclass
class _Event:
    slot: int
    kind: str  # "ready", "result", "died" (worker gone), "error" (worker could not start)
    value: Any = None


class _LocalPool:
    """``jobs`` spawned processes running :func:`_local_worker`, one asset at a time each."""

    name = "local"

    def __init__(self, jobs: int, options: BatchOptions, outdir: str):
        import multiprocessing

        self.ctx = multiprocessing.get_context("spawn")
        self.jobs, self.outdir = jobs, outdir
        self.options = dataclasses.asdict(options)
        self.procs: list[Any] = [None] * jobs
        self.conns: list[Any] = [None] * jobs
        self.busy: set[int] = set()

    def start(self, i: int) -> None:
        parent, child = self.ctx.Pipe()
        proc = self.ctx.Process(target=_local_worker, args=(child, self.options, self.outdir, self.jobs),
                                name=f"pointcvx-batch-{i}")
        proc.start()
        child.close()
        self.procs[i], self.conns[i] = proc, parent

    def submit(self, i: int, task: dict) -> None:
        self.busy.add(i)
        try:
            self.conns[i].send(task)
        except OSError:  # it died since: poll() reports it
            pass

    def poll(self, timeout: float) -> list[_Event]:
        from multiprocessing.connection import wait

        watch = {}
        for i, (proc, conn) in enumerate(zip(self.procs, self.conns, strict=True)):
            if proc is not None:
                watch[conn] = i
                watch[proc.sentinel] = i
        events: list[_Event] = []
        ready = set()
        for obj in wait(list(watch), timeout):
            ready.add(watch[obj])
        for i in sorted(ready):
            proc, conn = self.procs[i], self.conns[i]
            try:
                while conn.poll():
                    kind, value = conn.recv()
                    events.append(_Event(i, kind, value))
                    self.busy.discard(i)
            except (EOFError, OSError):
                pass
            if any(e.slot == i and e.kind == "error" for e in events):
                self._drop(i)
                continue
            if not proc.is_alive():
                proc.join(timeout=1.0)
                events.append(_Event(i, "died", _exit_reason(proc.exitcode)))
                self._drop(i)
        return events

    def _drop(self, i: int) -> None:
        proc, conn = self.procs[i], self.conns[i]
        if proc is not None and proc.is_alive():
            proc.kill()
        if proc is not None:
            proc.join(timeout=5)
        if conn is not None:
            conn.close()
        self.procs[i] = self.conns[i] = None
        self.busy.discard(i)

    def kill(self, i: int) -> None:
        self._drop(i)

    def close(self) -> None:
        """Stop every worker: idle ones are told to exit, busy ones (an interrupted batch) are
        killed."""
        for i in list(self.busy):
            self._drop(i)
        for conn in self.conns:
            if conn is not None:
                with contextlib.suppress(OSError):
                    conn.send(None)
        deadline = time.monotonic() + 5.0
        for i, proc in enumerate(self.procs):
            if proc is not None:
                proc.join(timeout=max(0.0, deadline - time.monotonic()))
                self._drop(i)


def _exit_reason(code: int | None) -> str:
    if code == EXIT_TIMEOUT:
        return "worker exited to stop an asset past its timeout"
    if code == EXIT_MEMORY:
        return "worker exited to stop an asset over its memory limit"
    if code is not None and code < 0:
        import signal

        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        return f"worker died ({name})"
    return f"worker died (exit status {code})"


def _import_ray():
    try:
        import ray
    except ImportError:
        raise MissingExtraError("--engine ray", "ray", "ray") from None
    return ray


class _RayPool:
    """``jobs`` Ray actors (:class:`BatchActor`, ``threads`` CPUs each), one asset at a time each."""

    name = "ray"

    def __init__(self, jobs: int, options: BatchOptions, outdir: str):
        ray = _import_ray()
        self.ray = ray
        self.actor_cls = ray.remote(num_cpus=options.threads, max_restarts=0)(BatchActor)
        self.options = dataclasses.asdict(options)
        self.outdir = outdir
        self.actors: list[Any] = [None] * jobs
        self.refs: dict[Any, tuple[int, str]] = {}

    def start(self, i: int) -> None:
        actor = self.actor_cls.remote(self.options, self.outdir)
        self.actors[i] = actor
        self.refs[actor.ready.remote()] = (i, "ready")

    def submit(self, i: int, task: dict) -> None:
        self.refs[self.actors[i].run.remote(task)] = (i, "result")

    def poll(self, timeout: float) -> list[_Event]:
        ray = self.ray
        if not self.refs:
            time.sleep(timeout)
            return []
        ready, _ = ray.wait(list(self.refs), num_returns=1, timeout=timeout)
        if ready:
            more, _ = ray.wait([r for r in self.refs if r not in ready], num_returns=len(self.refs) - 1,
                               timeout=0) if len(self.refs) > 1 else ([], [])
            ready = ready + more
        events = []
        for ref in ready:
            i, kind = self.refs.pop(ref)
            try:
                value = ray.get(ref)
            except ray.exceptions.RayActorError as exc:
                events.append(_Event(i, "died", _ray_reason(exc)))
                self._drop(i)
                continue
            except ray.exceptions.RayError as exc:
                events.append(_Event(i, "died", f"worker failed: {_first_line(exc)}"))
                self._drop(i)
                continue
            if kind == "ready":
                events.append(_Event(i, value[0], value[1]))
                if value[0] == "error":
                    self._drop(i)
            else:
                events.append(_Event(i, "result", value))
        return events

    def _drop(self, i: int) -> None:
        actor = self.actors[i]
        if actor is not None:
            with contextlib.suppress(Exception):
                self.ray.kill(actor, no_restart=True)
        self.actors[i] = None
        for ref in [r for r, (j, _) in self.refs.items() if j == i]:
            del self.refs[ref]

    def kill(self, i: int) -> None:
        self._drop(i)

    def close(self) -> None:
        for i in range(len(self.actors)):
            self._drop(i)


def _ray_reason(exc: BaseException) -> str:
    text = str(exc)
    m = re.search(r"Worker exit detail: ([^.]+)", text)
    return "worker died" + (f" ({m.group(1).strip()})" if m else "")


@contextlib.contextmanager
def ray_session(address: str | None, num_cpus: int | None = None):
    """Connect to the Ray cluster at ``address`` (``auto``, ``ray://...``, ``HOST:PORT``), or start
    a local instance on the loopback interface (``num_cpus`` CPUs; stopped on exit), or use the one
    this process already joined. Yields the ``ray`` module."""
    started_here = False
    env_key = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
    saved_env = os.environ.get(env_key)
    if "ray" not in sys.modules and address is None:
        # A local instance serves only this batch: keep every Ray port on 127.0.0.1.
        os.environ[env_key] = "0"
    ray = _import_ray()
    try:
        if not ray.is_initialized():
            kwargs = {"log_to_driver": False, "logging_level": logging.ERROR}
            if address is None:
                kwargs.update(address="local", include_dashboard=False,
                              num_cpus=num_cpus or os.cpu_count() or 1)
            else:
                kwargs["address"] = address
            try:
                ray.init(**kwargs)
            except (ConnectionError, ValueError, RuntimeError) as exc:
                where = address or "a local instance"
                raise InputError(f"cannot start Ray on {where}: {_first_line(exc)}") from None
            started_here = True
        yield ray
    finally:
        if started_here:
            ray.shutdown()
        if address is None and saved_env is None:
            os.environ.pop(env_key, None)


# ------------------------------------------------------------------------------------ manifest
class Manifest:
    """``OUTDIR/batch_manifest.jsonl``: one JSON record per line, appended and fsynced; the last
    record of an asset wins; a line cut short (a crash while writing) is ignored and the next
    record starts on a fresh line."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._file = None

    def read(self) -> dict[str, dict]:
        """asset id -> its latest record ({} when there is no manifest)."""
        if not self.path.is_file():
            return {}
        latest: dict[str, dict] = {}
        bad = 0
        with open(self.path, encoding="utf-8", errors="replace") as f:
            for line in f:
                line = line.strip()
                if not line:
                    continue
                try:
                    rec = json.loads(line)
                except json.JSONDecodeError:
                    bad += 1
                    continue
                if isinstance(rec, dict) and isinstance(rec.get("id"), str):
                    latest[rec["id"]] = rec
                else:
                    bad += 1
        if bad:
            log.warning("%s: %d unreadable line(s) ignored", self.path, bad)
        return latest

    def open(self, truncate: bool = False) -> None:
        new = truncate or not self.path.is_file() or self.path.stat().st_size == 0
        self._file = open(self.path, "w" if truncate else "a", encoding="utf-8")
        if not new:
            with open(self.path, "rb") as f:
                f.seek(-1, os.SEEK_END)
                if f.read(1) != b"\n":
                    self._file.write("\n")

    def append(self, record: dict) -> None:
        assert self._file is not None
        self._file.write(json.dumps(record, default=_json_default) + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def _json_default(x):
    try:
        return x.item()  # numpy scalars
    except AttributeError:
        return str(x)


# ------------------------------------------------------------------------------------ driver
@dataclass
class BatchReport:
    """What :func:`run_batch` did: one row per asset (:data:`COLUMNS`), the summary and the
    report files."""

    rows: list[dict]
    summary: dict
    outdir: Path
    files: list[Path] = field(default_factory=list)

    @property
    def failed(self) -> list[dict]:
        return [r for r in self.rows if r["status"] == "failed"]


def _is_done(rec: dict | None, config: str, outdir: Path) -> bool:
    return (rec is not None and rec.get("status") == "done" and rec.get("config") == config
            and all((outdir / f).is_file() for f in rec.get("files") or ()))


def _lock(outdir: Path):
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


def _row(asset: Asset, rec: dict | None, outdir: Path) -> dict:
    row = {c: "" for c in COLUMNS}
    row.update(id=asset.id, path=asset.path, status="pending")
    if rec is not None:
        for c in COLUMNS:
            if c in rec and rec[c] is not None:
                row[c] = rec[c]
    return row


def _mean(values: list[float]) -> float | None:
    vals = [float(v) for v in values if v not in ("", None)]
    return round(sum(vals) / len(vals), 5) if vals else None


def _write_reports(outdir: Path, rows: list[dict], summary: dict) -> list[Path]:
    from .io.files import atomic_path

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for r in rows:
        w.writerow(["" if r.get(c) is None else r.get(c) for c in COLUMNS])
    out = []
    for name, text in ((REPORT_CSV, buf.getvalue()),
                       (REPORT_JSON, json.dumps({"summary": summary, "assets": rows}, indent=1,
                                                default=_json_default) + "\n")):
        with atomic_path(outdir / name) as tmp:
            tmp.write_text(text)
        out.append(outdir / name)
    return out


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
        Folders, files, glob patterns, manifest files (see :func:`find_assets`).
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
        _import_ray()
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
            if _is_done(rec, config, out):
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
            from .export import write_files

            rec = dict(outcome["record"])
            if rec.get("status") == "done":
                try:
                    write_files({out / rel: data for rel, data in outcome["files"].items()},
                                overwrite=True, protect=[asset.path])
                except (OutputError, OSError) as exc:
                    rec.update(status="failed", error=f"writing the hulls: {_first_line(exc)}")
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
                n_jobs = drive(_LocalPool, os.cpu_count() or 1, opts)
            elif work:
                with ray_session(address, num_cpus=(jobs * opts.threads if jobs else None)) as ray:
                    n_jobs = drive(_RayPool, int(ray.cluster_resources().get("CPU", 1)), opts)
        finally:
            wall = time.perf_counter() - t0
            rows = [_row(a, state[a.id], out) for a in assets]
            summary = _summary(rows, finished, skipped, wall, stats.get("startup"), engine, n_jobs, opts,
                               config, out)
            files = _write_reports(out, rows, summary)
    finally:
        manifest.close()
        lock.close()
    return BatchReport(rows, summary, out, files)


def _summary(rows: list[dict], finished: int, skipped: int, wall: float, startup: float | None, engine: str,
             jobs: int | None, opts: BatchOptions, config: str, out: Path) -> dict:
    done = [r for r in rows if r["status"] == "done"]
    return {
        "assets": len(rows),
        "done": len(done),
        "failed": sum(r["status"] == "failed" for r in rows),
        "pending": sum(r["status"] == "pending" for r in rows),
        "skipped": skipped,
        "run": finished,
        "wall_seconds": round(wall, 3),
        "assets_per_minute": round(60.0 * finished / wall, 3) if finished and wall > 0 else None,
        "startup_seconds": round(startup, 3) if startup is not None else None,
        "mean_hulls": _mean([r["hulls"] for r in done]),
        "mean_max_concavity": _mean([r["max_concavity"] for r in done]),
        "mean_seconds": _mean([r["seconds"] for r in done]),
        "mean_cpu_seconds": _mean([r["cpu_seconds"] for r in done]),
        "max_peak_mb": max((float(r["peak_mb"]) for r in done if r["peak_mb"] not in ("", None)),
                           default=None),
        "engine": engine,
        "jobs": jobs,
        "threads": opts.threads,
        "config": config,
        "outdir": str(out),
    }


# ------------------------------------------------------------------------------------ CLI
def add_parser(sub) -> argparse.ArgumentParser:
    """Add ``batch`` to ``sub`` (an argparse subparsers object); return it."""
    from .cli import _add_load_options, add_decomposition_options
    from .export import FORMATS

    p = sub.add_parser(
        "batch",
        help="decompose many shapes (folders, globs, manifests) on a process pool or Ray",
        description="Decompose every shape of INPUTS (folders searched recursively, glob patterns, "
        "files, or manifest files: .txt/.lst one path per line, .json a list) into OUTDIR/hulls/"
        "<id>.<ext>, each in a long-lived worker (local processes, or Ray actors with --engine "
        "ray) with a timeout and a memory limit; a failing asset is recorded and the batch goes "
        "on. OUTDIR/batch_manifest.jsonl records every asset; running the command again skips "
        "the assets done and retries the failed ones. Ends with OUTDIR/batch_report.csv and "
        ".json. Exit status 0 when every asset is done, 1 when some failed.",
    )
    p.add_argument("inputs", nargs="+", metavar="INPUT", help="folder, file, glob pattern or manifest")
    p.add_argument("-o", "--outdir", required=True, metavar="OUTDIR", help="output folder")
    p.add_argument("--engine", choices=ENGINES, default="local",
                   help="local process pool (default) or Ray (pip install 'pointcvx[ray]')")
    p.add_argument("--jobs", type=int, default=None, metavar="N",
                   help="workers (default: CPUs / --threads, of this machine or the Ray cluster)")
    p.add_argument("--address", default=None, metavar="ADDR",
                   help="Ray cluster to join (auto, HOST:PORT, ray://HOST:PORT); default: start a "
                   "local Ray instance for this batch")
    p.add_argument("--threads", type=int, default=1, metavar="T",
                   help="threads per worker (default 1; fixed so results do not depend on --jobs)")
    p.add_argument("--timeout", type=float, default=600.0, metavar="SECONDS",
                   help="wall-clock limit per asset (default 600)")
    p.add_argument("--max-memory", type=float, default=None, metavar="MB",
                   help="resident memory limit of a worker while it runs an asset (default: 80%% "
                   "of the machine's memory / workers; 0: none)")
    p.add_argument("--format", choices=list(FORMATS), default="obj",
                   help="output format per asset (default obj: one OBJ, an 'o' per hull)")
    add_decomposition_options(p)
    p.add_argument("--skip-failed", action="store_true",
                   help="do not retry the assets the manifest records as failed")
    p.add_argument("--overwrite", action="store_true", help="forget the manifest and redo every asset")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar, no summary")
    p.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    _add_load_options(p)
    p.set_defaults(func=cmd_batch, points=20000)
    return p


def options_from_args(args: argparse.Namespace) -> BatchOptions:
    """The :class:`BatchOptions` of parsed ``pointcvx batch`` arguments."""
    from .cli import _load_options

    load = {k: v for k, v in vars(_load_options(args)).items() if k not in ("n_points", "seed")}
    return BatchOptions(
        format=args.format, threshold=args.threshold, max_hulls=args.max_hulls, features=args.features,
        model=args.model, views=args.views, merge=not args.no_merge, split=args.split,
        n_points=args.points, seed=args.seed, target=args.target,
        max_hull_vertices=args.max_hull_vertices, subsurface=args.subsurface, load_options=load,
        timeout=args.timeout,
        max_memory_mb=args.max_memory, threads=args.threads,
    )


def summary_text(report: BatchReport) -> str:
    """The lines ``pointcvx batch`` prints at the end."""
    s = report.summary
    rate = f"{s['assets_per_minute']:.1f} assets/min" if s["assets_per_minute"] else "-"
    lines = [f"{s['assets']} assets: {s['done']} done ({s['skipped']} already done), {s['failed']} failed"
             + (f", {s['pending']} pending" if s["pending"] else "")
             + f"; {s['run']} run in {s['wall_seconds']:.1f} s ({rate}, {s['engine']}, "
             f"{s['jobs'] or 0} worker{'' if s['jobs'] == 1 else 's'})"]
    if s["mean_hulls"] is not None:
        lines.append(f"mean {s['mean_hulls']:.2f} hulls, mean max concavity {s['mean_max_concavity']:.4f}, "
                     f"mean {s['mean_seconds']:.2f} s per asset")
    for r in report.failed[:10]:
        lines.append(f"failed: {r['id']}: {r['error']}")
    if len(report.failed) > 10:
        lines.append(f"... and {len(report.failed) - 10} more failed")
    lines.append(f"report: {report.outdir / REPORT_CSV}")
    return "\n".join(lines)


def cmd_batch(args: argparse.Namespace) -> int:
    """Run ``pointcvx batch``: 0 when every asset is done, 1 when some failed."""
    from .progress import LazyBar

    opts = options_from_args(args)
    bar = LazyBar(not args.quiet, "batch", "asset")
    failures = 0
    t0 = time.perf_counter()

    def progress(done: int, total: int, rec: dict) -> None:
        nonlocal failures
        failures += rec.get("status") == "failed"
        per_min = 60.0 * done / max(1e-9, time.perf_counter() - t0)
        bar.set(done, total, f"avg {per_min:.1f}/min" + (f", {failures} failed" if failures else ""))

    try:
        report = run_batch(args.inputs, args.outdir, opts, engine=args.engine, jobs=args.jobs,
                           address=args.address, retry_failed=not args.skip_failed,
                           overwrite=args.overwrite, progress=progress)
    finally:
        bar.close()
    if not args.quiet:
        print(json.dumps(report.summary, indent=2) if args.json else summary_text(report))
    return 0 if not report.failed and not report.summary["pending"] else 1


def main(argv: list[str] | None = None) -> int:
    """``pointcvx batch`` on its own: ``main(["INPUT", "-o", "OUTDIR", ...])``; errors are raised
    (:class:`~pointcvx.errors.PointcvxError`), the ``pointcvx`` command prints them in one line."""
    from .cli import _Parser

    parser = _Parser(prog="pointcvx")
    sub = parser.add_subparsers(dest="command", parser_class=_Parser)
    add_parser(sub)
    args = parser.parse_args(["batch", *(sys.argv[1:] if argv is None else argv)])
    if args.verbose:
        logging.basicConfig(level=logging.DEBUG, format="pointcvx: %(levelname)s: %(message)s")
    return args.func(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
