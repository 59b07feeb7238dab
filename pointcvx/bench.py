"""``pointcvx bench``: pointcvx against CoACD and V-HACD on folders of shapes.

For every shape of every dataset (a folder, searched recursively, or one file):

1. The shape is read once, normalised to [-1, 1]^3 (:meth:`pointcvx.Normalization.to_unit_cube`
   of the vertices its faces use, as :func:`pointcvx.metrics.evaluate` does) and written to a
   temporary OBJ: every method decomposes that same mesh. CAD parts (STEP, IGES) are tessellated
   first (``pointcvx.load(path, normalize=False).mesh``). Splats and point clouds have no mesh:
   only pointcvx runs on them (scored by :func:`pointcvx.metrics.evaluate_points`); the
   baselines' rows say ``skipped: needs a mesh``.
2. Each (method, shape, setting) run is a fresh ``python -m pointcvx._bench_worker`` process with
   a wall-clock timeout. The worker reports the method call's wall time (no interpreter start,
   no imports, no I/O) and its peak resident memory (``VmHWM`` on Linux; it includes the
   worker's interpreter and imports, about 40 MB). A timeout or a crash becomes an error row;
   the bench goes on.
3. The hulls are scored in the calling process with :func:`pointcvx.metrics.evaluate` (hull
   count, concavity, Chamfer reconstruction, volume IoU, coverage), outside the timed call.

Settings
--------
fixed
    pointcvx at each ``--threshold``; CoACD at threshold 0.1; V-HACD (pybullet, V-HACD 2.x) at
    resolution 1,000,000 and its default concavity 0.001 (the paper's settings); vhacdx (V-HACD
    4.x) at its defaults (64 hulls at most, resolution 400,000).
matched
    The baseline's hull count is brought as close as possible to pointcvx's count ``H`` on the
    same shape: bisection in log space of CoACD's ``threshold`` over [0.01, 1] and of V-HACD's
    ``concavity`` over [1e-5, 0.1] (both ranges centred on the fixed setting, whose run is reused
    as the first probe; the hull count falls as the parameter grows), at most 6 probes; the probe
    closest to ``H`` is kept (ties: lower concavity). vhacdx takes ``maxConvexHulls=H`` directly.
    A probe that fails (timeout, crash) counts as "too many hulls" and the search moves to
    coarser settings.

Outputs (all written atomically) in OUTDIR: ``results.csv`` (one row per dataset, shape, method,
setting and pointcvx threshold; see :data:`COLUMNS`), ``summary.md`` (means and medians per
dataset and category, paired win/tie/loss counts of pointcvx against each baseline at matched
granularity, ratio of median times), ``granularity.png`` (when matplotlib is installed) and the
hulls of every row under ``hulls/<method>/<setting>/<shape>.obj``. Running again with the same
OUTDIR skips the rows already in ``results.csv`` (unless ``overwrite``).
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import io
import json
import logging
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError, OutputError, PointcvxError
from .io.files import atomic_path
from .progress import LazyBar

log = logging.getLogger(__name__)

METHODS = ("pointcvx", "coacd", "vhacd", "vhacdx")
"""Every method name ``--methods`` accepts."""
BASELINES = ("coacd", "vhacd", "vhacdx")
_PACKAGES = {"coacd": "coacd", "vhacd": "pybullet", "vhacdx": "vhacdx"}

SHAPE_SUFFIXES = frozenset({
    ".obj", ".ply", ".stl", ".off", ".glb", ".gltf", ".step", ".stp", ".iges", ".igs",
    ".spz", ".splat", ".pcd", ".xyz", ".pts", ".las", ".laz",
})
"""File name endings taken from a dataset folder (README, .md, .txt, .json... are skipped)."""

COACD_THRESHOLD = 0.1
COACD_RANGE = (0.01, 1.0)
VHACD_RESOLUTION = 1_000_000
VHACD_CONCAVITY = 0.001  # pybullet.vhacd's default
VHACD_RANGE = (1e-5, 0.1)
VHACDX_MAX_HULLS = 64  # vhacdx.compute_vhacd's defaults
VHACDX_RESOLUTION = 400_000
TIE_RTOL = 1e-3
"""Two metric values within this relative difference are a tie in the win/tie/loss counts."""

COLUMNS = (
    "dataset", "category", "shape", "method", "setting", "param", "hulls", "concavity",
    "reconstruction", "iou", "coverage", "seconds", "peak_mb", "error",
    "param_name", "threshold", "target_hulls", "search_runs", "search_seconds", "modality",
    "hull_file",
)
"""Columns of ``results.csv``. ``threshold`` is the pointcvx threshold the row belongs to (empty
for fixed-setting baselines); ``target_hulls`` the hull count a matched row aimed at;
``search_runs`` the parameter values tried (the reused fixed-setting run included);
``search_seconds`` the method time of all of them; ``hull_file`` is relative to OUTDIR."""
_METRICS = ("hulls", "concavity", "reconstruction", "iou", "coverage")
_NUMERIC = ("param", "hulls", "concavity", "reconstruction", "iou", "coverage", "seconds", "peak_mb",
            "threshold", "target_hulls", "search_runs", "search_seconds")

Progress = Callable[[int, int, str], None]
"""progress(done, total, shape): called after each shape."""


@dataclass
class BenchOptions:
    """Settings of one benchmark.

    Attributes
    ----------
    methods : tuple of str
        Among :data:`METHODS`.
    thresholds : tuple of float
        pointcvx concavity thresholds; matched baselines follow each.
    match : bool
        Also run the baselines at matched granularity.
    timeout : float
        Wall-clock seconds allowed to each run (each search probe included).
    features, model, max_hulls, n_points, seed
        pointcvx's :func:`~pointcvx.decompose` settings (``seed`` also seeds CoACD and the
        evaluation).
    eval_samples : int
        Surface samples of :func:`pointcvx.metrics.evaluate` (the paper: 20,000); five times as
        many volume samples for the IoU.
    vhacd_resolution : int, optional
        Voxel resolution of both V-HACD flavours (default: 1,000,000 for pybullet, 400,000 for
        vhacdx).
    search_runs : int
        Probes of a matched-granularity search.
    threads : int, optional
        Threads of pointcvx's worker (default: all; set when several shapes run at once).
    """

    methods: tuple[str, ...] = ("pointcvx", "coacd", "vhacd")
    thresholds: tuple[float, ...] = (0.1,)
    match: bool = True
    timeout: float = 600.0
    features: str = "auto"
    model: str | None = None
    max_hulls: int = 64
    n_points: int = 20000
    seed: int = 0
    eval_samples: int = 20000
    vhacd_resolution: int | None = None
    search_runs: int = 6
    threads: int | None = None

    def check(self) -> None:
        """Raise :class:`InputError` on any unusable setting."""
        if not self.methods:
            raise InputError("no method to run: pass --methods, e.g. pointcvx,coacd,vhacd")
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown:
            raise InputError(f"unknown method {unknown[0]!r}; expected some of {', '.join(METHODS)}")
        for m in self.methods:
            if m in _PACKAGES and importlib.util.find_spec(_PACKAGES[m]) is None:
                raise InputError(f"method {m!r} needs the package '{_PACKAGES[m]}': "
                                 "pip install 'pointcvx[baselines]'")
        if not self.thresholds or not all(t > 0 and math.isfinite(t) for t in self.thresholds):
            raise InputError(f"thresholds must be positive, got {list(self.thresholds)}")
        if not self.timeout > 0:
            raise InputError(f"timeout must be positive, got {self.timeout}")
        from .pipeline import FEATURE_METHODS

        if self.features not in FEATURE_METHODS:
            raise InputError(f"unknown feature method {self.features!r}; expected one of {FEATURE_METHODS}")
        if self.features in ("model", "auto") and "pointcvx" in self.methods:
            if self.model is not None and not Path(self.model).is_file():
                raise InputError(f"{self.model}: no such model checkpoint")
            if self.model is None and self.features == "model":
                from .pipeline import bundled_model_path

                if bundled_model_path() is None:
                    raise InputError("--features model needs --model CKPT: this build ships no model")
        for name in ("max_hulls", "n_points", "eval_samples", "search_runs"):
            if getattr(self, name) < 1:
                raise InputError(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.vhacd_resolution is not None and self.vhacd_resolution < 1:
            raise InputError(f"vhacd resolution must be positive, got {self.vhacd_resolution}")

    @property
    def baselines(self) -> list[str]:
        return [m for m in self.methods if m in BASELINES]


# ------------------------------------------------------------------------------------ shapes
@dataclass
class ShapeEntry:
    """One shape of a dataset: its file, the dataset's name, its category (parent folder name)
    and a name unique within the benchmark (used for hull files)."""

    path: str
    dataset: str
    category: str
    shape: str


def find_shapes(datasets: Sequence[str | os.PathLike], limit: int | None = None,
                exclude: str | os.PathLike | None = None) -> list[ShapeEntry]:
    """The shape files of ``datasets`` (folders, searched recursively in sorted order, or files),
    at most ``limit`` per dataset. Hidden files and folders, and anything under ``exclude`` (the
    output folder), are left out.

    Raises
    ------
    InputError
        A dataset path that does not exist, or a folder without any shape file.
    """
    if not datasets:
        raise InputError("no dataset given: pass a folder of shapes or a shape file")
    if limit is not None and limit < 1:
        raise InputError(f"limit must be at least 1, got {limit}")
    entries: list[ShapeEntry] = []
    seen: set[Path] = set()
    names: set[str] = set()
    for d in datasets:
        root = Path(d)
        if not root.exists():
            raise InputError(f"{root}: no such file or folder")
        if root.is_dir():
            name = root.resolve().name
            skip = Path(exclude).resolve() if exclude is not None else None
            files = sorted(p for p in root.rglob("*") if p.is_file() and _is_shape_file(p, root)
                           and (skip is None or not p.resolve().is_relative_to(skip)))
            if not files:
                raise InputError(f"{root}: no shape file in this folder (looked for "
                                 f"{', '.join(sorted(SHAPE_SUFFIXES))})")
        else:
            name = root.resolve().parent.name
            files = [root]
        taken = 0
        for p in files:
            if p.resolve() in seen:
                continue
            if limit is not None and taken >= limit:
                break
            seen.add(p.resolve())
            category = p.resolve().parent.name
            shape = _unique_name(p, category, name, names)
            names.add(shape)
            entries.append(ShapeEntry(str(p), name, category, shape))
            taken += 1
    return entries


def _is_shape_file(p: Path, root: Path) -> bool:
    hidden = any(part.startswith(".") for part in p.relative_to(root).parts)
    return not hidden and p.suffix.lower() in SHAPE_SUFFIXES


def _unique_name(p: Path, category: str, dataset: str, taken: set[str]) -> str:
    for name in (p.stem, f"{category}-{p.stem}", f"{category}-{p.name}", f"{dataset}-{category}-{p.name}"):
        if name not in taken:
            return name
    i = 2
    while f"{p.stem}-{i}" in taken:
        i += 1
    return f"{p.stem}-{i}"


def _prepare_mesh(path: str, modality: str, fmt: str, seed: int):
    """The shape's mesh (only the vertices its faces use) normalised to [-1, 1]^3, as a
    ``trimesh.Trimesh``."""
    import trimesh

    from .cloud import Normalization

    if modality == "mesh":
        from .io.mesh import read_mesh

        mesh = read_mesh(path, fmt)
    else:
        from .io import load

        mesh = load(path, normalize=False, seed=seed).mesh
        if mesh is None:
            raise InputError(f"{path}: the {modality} loader returned no mesh")
    faces = np.asarray(mesh.faces, dtype=np.int64)
    used, inverse = np.unique(faces, return_inverse=True)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)[used]
    if not np.isfinite(vertices).all():
        raise InputError(f"{path}: the mesh has non-finite vertices")
    norm = Normalization.to_unit_cube(vertices)
    return trimesh.Trimesh(norm.forward(vertices), inverse.reshape(-1, 3), process=False)


def _write_mesh_obj(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    with open(path, "w") as f:
        np.savetxt(f, vertices, fmt="v %.9g %.9g %.9g")
        np.savetxt(f, faces + 1, fmt="f %d %d %d")


# ------------------------------------------------------------------------------------ one shape
@dataclass
class _Run:
    """One finished (or failed) worker run."""

    method: str
    param: float
    ok: bool
    hulls: int | None = None
    seconds: float = math.nan
    peak_mb: float = math.nan
    error: str = ""
    hull_file: Path | None = None
    metrics: dict | None = None
    reused: bool = False


def _key(dataset: str, shape: str, method: str, setting: str, threshold: str) -> str:
    return "\t".join((dataset, shape, method, setting, threshold))


def _row_key(row: dict) -> str:
    return _key(row["dataset"], row["shape"], row["method"], row["setting"], row.get("threshold", ""))


def _fmt_t(t: float) -> str:
    return f"{t:g}"


class _ShapeBench:
    """Runs and scores every pending row of one shape (in the calling process)."""

    def __init__(self, entry: ShapeEntry, opts: BenchOptions, outdir: Path, done: dict[str, dict]):
        self.entry, self.opts, self.outdir, self.done = entry, opts, outdir, done
        self.tmp: Path | None = None
        self.mesh = None
        self.modality = ""
        self.input = str(Path(entry.path).absolute())
        self.arrays: str | None = None
        self.count = 0

    # -------------------------------------------------------------- plan
    def planned(self) -> list[tuple[str, str, str]]:
        """(method, setting, threshold) of every row this shape should have."""
        o = self.opts
        out = []
        if "pointcvx" in o.methods:
            out += [("pointcvx", "fixed", _fmt_t(t)) for t in o.thresholds]
        out += [(b, "fixed", "") for b in o.baselines]
        if o.match and "pointcvx" in o.methods:
            out += [(b, "matched", _fmt_t(t)) for t in o.thresholds for b in o.baselines]
        return out

    def pending(self) -> list[tuple[str, str, str]]:
        e = self.entry
        return [p for p in self.planned() if _key(e.dataset, e.shape, *p) not in self.done]

    # -------------------------------------------------------------- rows
    def _row(self, method: str, setting: str, threshold: str, param_name: str, run: _Run | None,
             error: str = "", **extra) -> dict:
        e = self.entry
        row = {c: "" for c in COLUMNS}
        row.update(dataset=e.dataset, category=e.category, shape=e.shape, method=method,
                   setting=setting, threshold=threshold, param_name=param_name,
                   modality=self.modality)
        if run is not None:
            row.update(param=run.param, hulls=run.hulls if run.hulls is not None else "",
                       seconds=run.seconds, peak_mb=run.peak_mb, error=run.error)
            if run.metrics:
                row.update({k: run.metrics[k] for k in _METRICS[1:]})
            if run.ok and not run.error:
                row["hull_file"] = self._place(run, method, setting, threshold)
        if error:
            row["error"] = error
        row.update(extra)
        return row

    def _place(self, run: _Run, method: str, setting: str, threshold: str) -> str:
        """Copy the run's hulls to OUTDIR/hulls/<method>/<setting>/<shape>.obj (atomically)."""
        suffix = f"@t{threshold}" if threshold and len(self.opts.thresholds) > 1 else ""
        target = self.outdir / "hulls" / method / setting / f"{self.entry.shape}{suffix}.obj"
        target.parent.mkdir(parents=True, exist_ok=True)
        if run.hull_file is not None and run.hull_file.resolve() != target.resolve():
            with atomic_path(target) as tmp:
                shutil.copyfile(run.hull_file, tmp)
        return target.relative_to(self.outdir).as_posix()

    # -------------------------------------------------------------- running
    def launch(self, method: str, params: dict, param: float) -> _Run:
        """Run ``method`` with ``params`` in a fresh worker process."""
        assert self.tmp is not None
        _stop_if_orphaned()
        self.count += 1
        stem = self.tmp / f"{method}-{self.count:03d}"
        job = {
            "method": method, "input": self.input, "arrays": self.arrays, "params": params,
            "hulls": str(stem.with_suffix(".obj")), "result": str(stem.with_suffix(".json")),
            "points": str(stem.with_suffix(".npy")) if method == "pointcvx" and self.mesh is None else None,
            "threads": self.opts.threads if method == "pointcvx" else None,
        }
        job_file = stem.with_suffix(".job.json")
        job_file.write_text(json.dumps(job))
        env = dict(os.environ)
        root = str(Path(__file__).resolve().parents[1])
        env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        t0 = time.perf_counter()
        log_file = stem.with_suffix(".log")
        try:
            with open(log_file, "wb") as out:
                proc = subprocess.run(
                    [sys.executable, "-m", "pointcvx._bench_worker", str(job_file)],
                    stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                    timeout=self.opts.timeout, env=env, cwd=str(self.tmp), check=False,
                )
        except subprocess.TimeoutExpired:
            wall = time.perf_counter() - t0
            log.info("%s: %s timed out after %.1f s", self.entry.shape, method, wall)
            return _Run(method, param, False, seconds=wall,
                        error=f"timeout after {self.opts.timeout:g} s")
        result_file = Path(job["result"])
        if not result_file.is_file():
            tail = _last_line(log_file)
            how = f"signal {-proc.returncode}" if proc.returncode < 0 else f"exit status {proc.returncode}"
            return _Run(method, param, False, seconds=time.perf_counter() - t0,
                        error=f"worker crashed ({how})" + (f": {tail}" if tail else ""))
        res = json.loads(result_file.read_text())
        peak = res.get("peak_kb")
        run = _Run(method, param, bool(res.get("ok")), hulls=res.get("hulls"),
                   seconds=float(res.get("seconds", math.nan)),
                   peak_mb=peak / 1024.0 if peak is not None else math.nan,
                   error=res.get("error", "") if not res.get("ok") else "",
                   hull_file=Path(job["hulls"]) if res.get("ok") else None)
        log.debug("%s: %s %s -> %s hulls, %.2f s, %.0f MB %s", self.entry.shape, method, params,
                  run.hulls, run.seconds, run.peak_mb, run.error)
        return run

    def evaluate(self, run: _Run) -> None:
        """Score ``run``'s hulls (once); an evaluation failure goes to ``run.error``."""
        if not run.ok or run.metrics is not None or run.error:
            return
        from .metrics import evaluate, evaluate_points, load_hulls

        n = self.opts.eval_samples
        try:
            hulls = load_hulls(run.hull_file)
            if self.mesh is not None:
                ev = evaluate(self.mesh, hulls, n_samples=n, n_volume_samples=5 * n, seed=self.opts.seed)
            else:
                points = np.load(run.hull_file.with_suffix(".npy"))
                ev = evaluate_points(points, hulls, n_samples=n, seed=self.opts.seed)
        # The metrics run geometry code (hulls, booleans, sampling) on whatever a method returned;
        # any failure there is recorded in the row rather than ending the benchmark.
        except Exception as exc:  # noqa: BLE001
            run.error = f"evaluation failed: {type(exc).__name__}: {_first_line(exc)}"
            return
        run.metrics = {k: float(ev.get(k, math.nan)) for k in _METRICS}

    # -------------------------------------------------------------- the shape
    def run(self) -> list[dict]:
        pending = self.pending()
        if not pending:
            return []
        self.tmp = Path(tempfile.mkdtemp(prefix=".bench-", dir=self.outdir)).absolute()
        try:
            return self._run(pending)
        finally:
            shutil.rmtree(self.tmp, ignore_errors=True)

    def _run(self, pending: list[tuple[str, str, str]]) -> list[dict]:
        from .io import detect

        e, o = self.entry, self.opts
        try:
            found = detect(e.path)
            self.modality = found.modality
            if found.modality in ("mesh", "cad"):
                self.mesh = _prepare_mesh(e.path, found.modality, found.format, o.seed)
                obj = self.tmp / "shape.obj"
                v, f = np.asarray(self.mesh.vertices), np.asarray(self.mesh.faces)
                _write_mesh_obj(obj, v, f)
                np.savez(self.tmp / "shape.npz", vertices=v, faces=f)
                self.input, self.arrays = str(obj), str(self.tmp / "shape.npz")
        except PointcvxError as exc:
            return [self._row(m, s, t, _param_name(m), None, error=f"load failed: {exc}")
                    for m, s, t in pending]
        rows: list[dict] = []
        todo = set(pending)
        targets: dict[str, int | None] = {}
        for t in o.thresholds if "pointcvx" in o.methods else ():
            ts = _fmt_t(t)
            k = _key(e.dataset, e.shape, "pointcvx", "fixed", ts)
            if ("pointcvx", "fixed", ts) not in todo:
                old = self.done[k]
                targets[ts] = int(float(old["hulls"])) if not old.get("error") and old.get("hulls") else None
                continue
            run = self.launch("pointcvx", self._pointcvx_params(t), t)
            self.evaluate(run)
            targets[ts] = run.hulls if run.ok and not run.error else None
            rows.append(self._row("pointcvx", "fixed", ts, "threshold", run))
        if self.mesh is None:
            for m, s, t in pending:
                if m != "pointcvx":
                    rows.append(self._row(m, s, t, _param_name(m), None, error="skipped: needs a mesh"))
            return rows
        fixed: dict[str, _Run] = {}
        for b in o.baselines:
            if (b, "fixed", "") not in todo:
                old = self._reusable(self.done[_key(e.dataset, e.shape, b, "fixed", "")])
                if old is not None:
                    fixed[b] = old
                continue
            param, params = self._fixed_params(b)
            run = self.launch(b, params, param)
            self.evaluate(run)
            rows.append(self._row(b, "fixed", "", _param_name(b), run))
            if run.ok and not run.error:
                fixed[b] = run
        for ts, target in targets.items():
            for b in o.baselines:
                if (b, "matched", ts) not in todo:
                    continue
                if target is None:
                    rows.append(self._row(b, "matched", ts, _param_name(b), None,
                                          error="pointcvx failed: no hull count to match"))
                    continue
                best, tried = self._match(b, target, fixed.get(b))
                extra = {"target_hulls": target, "search_runs": len(tried),
                         "search_seconds": sum(r.seconds for r in tried if not r.reused)}
                if best is None:
                    last = tried[-1].error if tried else "no run"
                    rows.append(self._row(b, "matched", ts, _param_name(b), None,
                                          error=f"every search run failed ({last})", **extra))
                    continue
                self.evaluate(best)
                rows.append(self._row(b, "matched", ts, _param_name(b), best, **extra))
        return rows

    def _reusable(self, row: dict) -> _Run | None:
        """A finished fixed-setting row (from an earlier invocation) as a run the matched search
        can reuse, or None."""
        if row.get("error") or not row.get("hull_file") or not row.get("hulls"):
            return None
        path = self.outdir / row["hull_file"]
        if not path.is_file():
            return None
        metrics = {k: _num(row.get(k)) for k in _METRICS}
        return _Run(row["method"], _num(row["param"]), True, hulls=int(_num(row["hulls"])),
                    seconds=_num(row["seconds"]), peak_mb=_num(row["peak_mb"]), hull_file=path,
                    metrics=metrics)

    def _pointcvx_params(self, threshold: float) -> dict:
        o = self.opts
        return {"threshold": float(threshold), "max_hulls": o.max_hulls, "features": o.features,
                "model": o.model, "n_points": o.n_points, "seed": o.seed}

    def _vhacd_params(self, concavity: float) -> dict:
        res = self.opts.vhacd_resolution or VHACD_RESOLUTION
        return {"resolution": int(res), "concavity": float(concavity)}

    def _vhacdx_params(self, max_hulls: int) -> dict:
        res = self.opts.vhacd_resolution or VHACDX_RESOLUTION
        return {"maxConvexHulls": int(max_hulls), "resolution": int(res)}

    def _coacd_params(self, threshold: float) -> dict:
        return {"threshold": float(threshold), "seed": self.opts.seed}

    def _fixed_params(self, method: str) -> tuple[float, dict]:
        if method == "coacd":
            return COACD_THRESHOLD, self._coacd_params(COACD_THRESHOLD)
        if method == "vhacd":
            return VHACD_CONCAVITY, self._vhacd_params(VHACD_CONCAVITY)
        return VHACDX_MAX_HULLS, self._vhacdx_params(VHACDX_MAX_HULLS)

    def _match(self, method: str, target: int, fixed: _Run | None) -> tuple[_Run | None, list[_Run]]:
        """(the run whose hull count is closest to ``target``, every run tried)."""
        reuse = [fixed] if fixed is not None else []
        if method == "vhacdx":
            run = next((r for r in reuse if r.param == target), None)
            if run is not None:
                run.reused = True
            else:
                run = self.launch("vhacdx", self._vhacdx_params(target), target)
            return (run if run.ok else None), [run]
        lo, hi = COACD_RANGE if method == "coacd" else VHACD_RANGE
        make = self._coacd_params if method == "coacd" else self._vhacd_params
        return search_parameter(lambda x: self.launch(method, make(x), x), lo, hi, target,
                                self.opts.search_runs, reuse, evaluate=self.evaluate)


class BenchStopped(PointcvxError):
    """The benchmark that started this pool worker is gone: start no more runs."""


def _stop_if_orphaned() -> None:
    """Raise :class:`BenchStopped` in a ``--jobs`` pool worker whose parent benchmark died (killed
    or interrupted), so that an abandoned worker does not go on launching runs."""
    import multiprocessing

    parent = multiprocessing.parent_process()
    if parent is not None and not parent.is_alive():
        raise BenchStopped("the benchmark that started this worker has stopped")


def search_parameter(run: Callable[[float], _Run], lo: float, hi: float, target: int, max_runs: int,
                     reuse: Sequence[_Run] = (), evaluate: Callable[[_Run], None] | None = None,
                     ) -> tuple[_Run | None, list[_Run]]:
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
    tried: list[_Run] = []
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

        def concavity(r: _Run) -> float:
            c = (r.metrics or {}).get("concavity", math.nan)
            return c if math.isfinite(c) else math.inf

        best.sort(key=concavity)
    return best[0], tried


def _param_name(method: str) -> str:
    return {"pointcvx": "threshold", "coacd": "threshold", "vhacd": "concavity",
            "vhacdx": "maxConvexHulls"}[method]


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0][:200] if text else ""


def _last_line(path: Path) -> str:
    try:
        lines = [ln.strip() for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    return lines[-1][:200] if lines else ""


def bench_shape(entry: dict, options: dict, outdir: str, done: dict[str, dict]) -> list[dict]:
    """Run every pending row of one shape; the rows, in :data:`COLUMNS` order.

    Top-level (picklable) so that ``--jobs`` can run shapes in a spawned process pool.
    """
    return _ShapeBench(ShapeEntry(**entry), BenchOptions(**options), Path(outdir), done).run()


# ------------------------------------------------------------------------------------ files
def _num(value) -> float:
    if value is None or value == "":
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return "" if not math.isfinite(value) else f"{float(value):.6g}"
    return str(value)


def read_results(path: str | os.PathLike) -> list[dict]:
    """The rows of a ``results.csv`` (every value a string); [] when the file does not exist."""
    p = Path(path)
    if not p.is_file():
        return []
    with open(p, newline="") as f:
        reader = csv.DictReader(f)
        missing = [c for c in ("dataset", "shape", "method", "setting") if c not in (reader.fieldnames or [])]
        if missing:
            raise InputError(f"{p}: not a pointcvx bench results file (no {missing[0]!r} column); "
                             "pass --overwrite to start over")
        return [{c: (r.get(c) or "") for c in COLUMNS} for r in reader]


def _write_atomic(path: Path, data: str | bytes) -> None:
    from .io.files import atomic_path

    with atomic_path(path, overwrite=True) as tmp:
        if isinstance(data, bytes):
            tmp.write_bytes(data)
        else:
            tmp.write_text(data)


def write_results(path: str | os.PathLike, rows: Sequence[dict]) -> None:
    """Write ``rows`` as CSV with :data:`COLUMNS` (atomically)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for r in rows:
        w.writerow([_cell(r.get(c)) for c in COLUMNS])
    _write_atomic(Path(path), buf.getvalue())


# ------------------------------------------------------------------------------------ summary
def _ok(row: dict) -> bool:
    return not row.get("error")


def _stat(rows: list[dict], key: str) -> tuple[float, float]:
    vals = np.array([_num(r.get(key)) for r in rows], dtype=np.float64)
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
    ours = {(r["dataset"], r["shape"], r["threshold"]): _num(r.get(metric)) for r in rows
            if r["method"] == "pointcvx" and _ok(r)}
    w = t = lo = 0
    for r in rows:
        if r["method"] != baseline or r["setting"] != "matched" or not _ok(r):
            continue
        if threshold is not None and r["threshold"] != threshold:
            continue
        a = ours.get((r["dataset"], r["shape"], r["threshold"]), math.nan)
        b = _num(r.get(metric))
        if not (math.isfinite(a) and math.isfinite(b)):
            continue
        if abs(a - b) <= TIE_RTOL * max(abs(a), abs(b)):
            t += 1
        elif a < b:
            w += 1
        else:
            lo += 1
    return w, t, lo


def _groups(rows: Sequence[dict]) -> list[tuple[str, str, str]]:
    seen = []
    for r in rows:
        k = (r["method"], r["setting"], r["threshold"])
        if k not in seen:
            seen.append(k)
    order = {m: i for i, m in enumerate(METHODS)}
    return sorted(seen, key=lambda k: (order.get(k[0], 99), k[1] != "fixed", _num(k[2])))


def _section(rows: list[dict], level: str) -> list[str]:
    out = ["", f"{level} Means and medians", "",
           "| method | setting | threshold | ok | errors | skipped | hulls mean | hulls median "
           "| concavity mean | concavity median | reconstruction mean | reconstruction median "
           "| seconds mean | seconds median | peak MB mean | peak MB median |",
           "|" + "---|" * 16]
    for m, s, t in _groups(rows):
        g = [r for r in rows if (r["method"], r["setting"], r["threshold"]) == (m, s, t)]
        ok = [r for r in g if _ok(r)]
        skipped = sum(1 for r in g if r.get("error", "").startswith("skipped"))
        cells = [m, s, t or "–", str(len(ok)), str(len(g) - len(ok) - skipped), str(skipped)]
        for key in ("hulls", "concavity", "reconstruction", "seconds", "peak_mb"):
            mean, med = _stat(ok, key)
            cells += [_f(mean), _f(med)]
        out.append("| " + " | ".join(cells) + " |")
    baselines = [b for b in BASELINES if any(r["method"] == b for r in rows)]
    thresholds = sorted({r["threshold"] for r in rows if r["method"] == "pointcvx"}, key=_num)
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
            for m, s, t in _groups(rows):
                if m != b:
                    continue
                ref_t = t if t else thresholds[0]
                ours = [r for r in rows if r["method"] == "pointcvx" and r["threshold"] == ref_t and _ok(r)]
                theirs = [r for r in rows if (r["method"], r["setting"], r["threshold"]) == (m, s, t)
                          and _ok(r)]
                a, bm = _stat(ours, "seconds")[1], _stat(theirs, "seconds")[1]
                ratio = bm / a if math.isfinite(a) and math.isfinite(bm) and a > 0 else math.nan
                out.append(f"| {b} | {s} | {t or ref_t} | {_f(bm)} | {_f(a)} | {_f(ratio, 3)} |")
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
    ok = [r for r in rows if _ok(r) and math.isfinite(_num(r.get("hulls")))]
    if not ok:
        return False
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    colours = {m: f"C{i}" for i, m in enumerate(METHODS)}
    for ax, metric in zip(axes, ("concavity", "reconstruction"), strict=True):
        for m, s, _t in _groups(ok):
            g = [r for r in ok if (r["method"], r["setting"]) == (m, s)]
            x = np.array([_num(r["hulls"]) for r in g])
            y = np.array([_num(r.get(metric)) for r in g])
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
            ts = sorted({r["threshold"] for r in g}, key=_num)
            if len(ts) < 2:
                continue
            pts = [(_stat([r for r in g if r["threshold"] == t], "hulls")[1],
                    _stat([r for r in g if r["threshold"] == t], metric)[1]) for t in ts]
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
    _write_atomic(Path(path), buf.getvalue())
    return True


# ------------------------------------------------------------------------------------ driver
@dataclass
class BenchReport:
    """What :func:`run_bench` did: every row of ``results.csv`` and the files written."""

    rows: list[dict]
    new_rows: int
    outdir: Path
    files: list[Path] = field(default_factory=list)


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
        Methods and settings (default: pointcvx, CoACD and V-HACD, threshold 0.1, matched).
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
    done = {_row_key(r): r for r in rows}
    if jobs > 1 and opts.threads is None:
        opts = BenchOptions(**{**asdict(opts), "threads": max(1, (os.cpu_count() or 1) // jobs)})
    options_d = asdict(opts)
    work = []
    for e in entries:
        mine = {k: v for k, v in done.items() if k.startswith(f"{e.dataset}\t{e.shape}\t")}
        if _ShapeBench(e, opts, out, mine).pending():
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
    _write_atomic(out / "summary.md", summarize(rows))
    files.append(out / "summary.md")
    if plot_granularity(rows, out / "granularity.png"):
        files.append(out / "granularity.png")
    return BenchReport(rows, new, out, files)


# ------------------------------------------------------------------------------------ CLI
def _methods(text: str) -> tuple[str, ...]:
    return tuple(dict.fromkeys(m.strip().lower() for m in text.split(",") if m.strip()))


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def add_parser(sub) -> argparse.ArgumentParser:
    """Add the ``bench`` sub-command to ``sub`` (an argparse subparsers object); return it."""
    p = sub.add_parser(
        "bench",
        help="compare pointcvx with CoACD and V-HACD on folders of shapes",
        description="Decompose every shape of DATASET (a folder, searched recursively, or a file) "
        "with each method, each run in its own process with a timeout, on the same mesh "
        "normalised to [-1,1]^3; score the hulls with the paper's protocol (as `pointcvx "
        "evaluate`). Baselines run at the paper's fixed settings (CoACD threshold 0.1, V-HACD "
        "resolution 1,000,000) and, with --match, at pointcvx's hull count (parameter search). "
        "Writes OUTDIR/results.csv, summary.md, granularity.png and hulls/; rerunning resumes.",
    )
    p.add_argument("datasets", nargs="+", metavar="DATASET", help="folder of shapes, or a shape file")
    p.add_argument("-o", "--outdir", required=True, metavar="OUTDIR", help="output folder")
    p.add_argument("--methods", type=_methods, default=("pointcvx", "coacd", "vhacd"),
                   help="comma-separated among pointcvx, coacd, vhacd (V-HACD 2.x via pybullet), "
                        "vhacdx (V-HACD 4.x) (default pointcvx,coacd,vhacd)")
    p.add_argument("-t", "--threshold", type=float, default=0.1,
                   help="pointcvx concavity threshold (default 0.1)")
    p.add_argument("--thresholds", type=_floats, default=None, metavar="T1,T2,...",
                   help="run pointcvx at each threshold (the matched baselines follow each); "
                        "replaces --threshold")
    p.add_argument("--match", action=argparse.BooleanOptionalAction, default=True,
                   help="also run each baseline at pointcvx's hull count (default on)")
    p.add_argument("--timeout", type=float, default=600.0, metavar="SECONDS",
                   help="wall-clock limit of each run (default 600)")
    p.add_argument("--limit", type=int, default=None, metavar="N", help="at most N shapes per dataset")
    p.add_argument("--jobs", type=int, default=1, metavar="N", help="shapes run at once (default 1)")
    p.add_argument("--features", choices=["auto", "optimize", "model"], default="auto",
                   help="pointcvx features: optimised per shape, the feed-forward model, or auto "
                        "(the default: the model on splats, optimisation on the rest)")
    p.add_argument("--model", metavar="CKPT", help="model checkpoint for --features model")
    p.add_argument("-k", "--max-hulls", type=int, default=64, help="pointcvx hull budget (default 64)")
    p.add_argument("-n", "--points", type=int, default=20000, metavar="N",
                   help="pointcvx surface points (default 20000)")
    p.add_argument("--seed", type=int, default=0, help="seed of pointcvx, CoACD and the metrics (0)")
    p.add_argument("--eval-samples", type=int, default=20000, metavar="N",
                   help="surface samples of the metrics (default 20000, the paper's)")
    p.add_argument("--vhacd-resolution", type=int, default=None, metavar="R",
                   help="voxel resolution of V-HACD (default 1000000) and vhacdx (default 400000)")
    p.add_argument("--search-runs", type=int, default=6, metavar="N",
                   help="probes of each matched-granularity search (default 6)")
    p.add_argument("--overwrite", action="store_true",
                   help="start over instead of skipping the rows already in OUTDIR/results.csv")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar, no summary")
    p.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    p.set_defaults(func=cmd_bench)
    return p


def options_from_args(args: argparse.Namespace) -> BenchOptions:
    """The :class:`BenchOptions` of parsed ``pointcvx bench`` arguments."""
    return BenchOptions(
        methods=tuple(args.methods),
        thresholds=tuple(args.thresholds) if args.thresholds else (float(args.threshold),),
        match=bool(args.match), timeout=float(args.timeout), features=args.features,
        model=args.model, max_hulls=args.max_hulls, n_points=args.points, seed=args.seed,
        eval_samples=args.eval_samples, vhacd_resolution=args.vhacd_resolution,
        search_runs=args.search_runs,
    )


def _final_summary(report: BenchReport) -> str:
    rows = report.rows
    lines = [f"{report.new_rows} new rows, {len(rows)} in {report.outdir / 'results.csv'}"]
    width = max((len(f"{m} {s} {t}") for m, s, t in _groups(rows)), default=10)
    for m, s, t in _groups(rows):
        g = [r for r in rows if (r["method"], r["setting"], r["threshold"]) == (m, s, t)]
        ok = [r for r in g if _ok(r)]
        name = f"{m} {s} {t}".strip()
        med = {k: _stat(ok, k)[1] for k in ("hulls", "concavity", "reconstruction", "seconds")}
        lines.append(f"  {name:<{width}}  {len(ok):>4}/{len(g):<4} ok  hulls {_f(med['hulls'], 3):>5}  "
                     f"concavity {_f(med['concavity'])}  reconstruction {_f(med['reconstruction'])}  "
                     f"seconds {_f(med['seconds'], 3)}  (medians)")
    lines.append(f"summary: {report.outdir / 'summary.md'}")
    return "\n".join(lines)


def cmd_bench(args: argparse.Namespace) -> int:
    """Run ``pointcvx bench``; 0 when every row ran (errors inside rows included)."""
    opts = options_from_args(args)
    bar = LazyBar(not args.quiet, "bench", "shape")
    try:
        report = run_bench(args.datasets, args.outdir, opts, limit=args.limit, jobs=args.jobs,
                           overwrite=args.overwrite,
                           progress=lambda done, total, shape: bar.set(done, total, shape))
    finally:
        bar.close()
    if not args.quiet:
        print(_final_summary(report))
    return 0


def main(argv: list[str] | None = None) -> int:
    """``pointcvx bench`` on its own: ``main(["DATASET", "-o", "OUT", ...])``.

    Errors are raised (:class:`~pointcvx.errors.PointcvxError`); the ``pointcvx`` command turns
    them into one line and exit status 1.
    """
    parser = argparse.ArgumentParser(prog="pointcvx")
    sub = parser.add_subparsers(dest="command")
    add_parser(sub)
    args = parser.parse_args(["bench", *(sys.argv[1:] if argv is None else argv)])
    if args.verbose:
        logging.basicConfig(level=logging.DEBUG, format="pointcvx: %(levelname)s: %(message)s")
    return args.func(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
