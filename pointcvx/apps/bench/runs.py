"""Every run of one shape: which rows it still needs, the worker runs that fill them (pointcvx
first, then each baseline fixed and matched to pointcvx's hull count; each fixed run also as a
one-shot process), their scores and hull files (:class:`ShapeBench`)."""

from __future__ import annotations

import math
import shutil
import tempfile
from pathlib import Path

import numpy as np

from ...errors import PointcvxError, first_line
from ...io.files import atomic_path
from ..common import stop_if_orphaned
from .launch import Run, launch, worker_env
from .mesh import prepare_mesh, write_mesh_obj
from .methods import (
    COACD_RANGE,
    VHACD_RANGE,
    coacd_params,
    fixed_params,
    param_name,
    pointcvx_params,
    vhacd_params,
    vhacdx_params,
)
from .oneshot import time_oneshot
from .options import BenchOptions
from .results import COLUMNS, METRICS, key_of, num
from .search import search_parameter
from .shapes import ShapeEntry


def _fmt_t(t: float) -> str:
    return f"{t:g}"


class ShapeBench:
    """Runs and scores every pending row of one shape (in the calling process).

    ``done`` maps :func:`~.results.key_of` to the rows this shape already has (from an earlier
    invocation); they are not run again, and a finished fixed-setting run among them seeds the
    matched search.
    """

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
        """The planned rows not in ``done``."""
        e = self.entry
        return [p for p in self.planned() if key_of(e.dataset, e.shape, *p) not in self.done]

    # -------------------------------------------------------------- rows
    def _row(self, method: str, setting: str, threshold: str, pname: str, run: Run | None,
             error: str = "", **extra) -> dict:
        """The row of one run (or of none, with ``error``); ``pname`` fills ``param_name``."""
        e = self.entry
        row = {c: "" for c in COLUMNS}
        row.update(dataset=e.dataset, category=e.category, shape=e.shape, method=method,
                   setting=setting, threshold=threshold, param_name=pname,
                   modality=self.modality)
        if run is not None:
            row.update(param=run.param, hulls=run.hulls if run.hulls is not None else "",
                       seconds=run.seconds, peak_mb=run.peak_mb, error=run.error)
            if run.metrics:
                row.update({k: run.metrics[k] for k in METRICS[1:]})
            if run.ok and not run.error:
                row["hull_file"] = self._place(run, method, setting, threshold)
        if error:
            row["error"] = error
        row.update(extra)
        return row

    def _place(self, run: Run, method: str, setting: str, threshold: str) -> str:
        """Copy the run's hulls to OUTDIR/hulls/<method>/<setting>/<shape>.obj (atomically)."""
        suffix = f"@t{threshold}" if threshold and len(self.opts.thresholds) > 1 else ""
        target = self.outdir / "hulls" / method / setting / f"{self.entry.shape}{suffix}.obj"
        target.parent.mkdir(parents=True, exist_ok=True)
        if run.hull_file is not None and run.hull_file.resolve() != target.resolve():
            with atomic_path(target) as tmp:
                shutil.copyfile(run.hull_file, tmp)
        return target.relative_to(self.outdir).as_posix()

    # -------------------------------------------------------------- running
    def launch(self, method: str, params: dict, param: float) -> Run:
        """Run ``method`` with ``params`` in a fresh worker process."""
        assert self.tmp is not None
        stop_if_orphaned()
        self.count += 1
        stem = self.tmp / f"{method}-{self.count:03d}"
        job = {
            "method": method, "input": self.input, "arrays": self.arrays, "params": params,
            "hulls": str(stem.with_suffix(".obj")), "result": str(stem.with_suffix(".json")),
            "points": str(stem.with_suffix(".npy")) if method == "pointcvx" and self.mesh is None else None,
            "threads": self.opts.threads if method == "pointcvx" else None,
        }
        return launch(job, stem, self.opts.timeout, param, self.entry.shape)

    def oneshot(self, method: str, params: dict, run: Run) -> dict:
        """The one-shot columns of the fixed-setting ``run``: ``method`` with ``params`` again,
        as a whole process the way a user runs it (:func:`~.oneshot.time_oneshot`), right after
        the warm run so that both see the same machine; {} when the bench does not time one-shot
        runs or the warm run failed. A one-shot run that gives another hull count than the warm
        one (same method, settings and seed) keeps its time and says so in ``oneshot_error``."""
        if not self.opts.oneshot or not run.ok or run.error:
            return {}
        assert self.tmp is not None
        stop_if_orphaned()
        self.count += 1
        stem = self.tmp / f"{method}-{self.count:03d}-oneshot"
        job = {"method": method, "input": self.input, "params": params,
               "hulls": str(stem.with_suffix(".obj"))}
        env = worker_env(self.opts.threads if method == "pointcvx" else None)
        seconds, hulls, error = time_oneshot(job, stem, self.opts.timeout, env)
        if not error and hulls != run.hulls:
            error = f"one-shot: {hulls} hulls, the warm run {run.hulls}"
        return {"oneshot_seconds": seconds, "oneshot_error": error}

    def evaluate(self, run: Run) -> None:
        """Score ``run``'s hulls (once); an evaluation failure goes to ``run.error``."""
        if not run.ok or run.metrics is not None or run.error:
            return
        from ...evaluate import evaluate, evaluate_points, load_hulls

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
            run.error = f"evaluation failed: {first_line(exc, 200, typed=True)}"
            return
        run.metrics = {k: float(ev.get(k, math.nan)) for k in METRICS}

    # -------------------------------------------------------------- the shape
    def run(self) -> list[dict]:
        """Run every pending row in a temporary folder under OUTDIR (removed after); the new rows."""
        pending = self.pending()
        if not pending:
            return []
        self.tmp = Path(tempfile.mkdtemp(prefix=".bench-", dir=self.outdir)).absolute()
        try:
            return self._run(pending)
        finally:
            shutil.rmtree(self.tmp, ignore_errors=True)

    def _run(self, pending: list[tuple[str, str, str]]) -> list[dict]:
        from ...io import detect

        e, o = self.entry, self.opts
        try:
            found = detect(e.path)
            self.modality = found.modality
            if found.modality in ("mesh", "cad"):
                self.mesh = prepare_mesh(e.path, found.modality, found.format, o.seed)
                obj = self.tmp / "shape.obj"
                v, f = np.asarray(self.mesh.vertices), np.asarray(self.mesh.faces)
                write_mesh_obj(obj, v, f)
                np.savez(self.tmp / "shape.npz", vertices=v, faces=f)
                self.input, self.arrays = str(obj), str(self.tmp / "shape.npz")
        except PointcvxError as exc:
            return [self._row(m, s, t, param_name(m), None, error=f"load failed: {exc}")
                    for m, s, t in pending]
        rows: list[dict] = []
        todo = set(pending)
        targets: dict[str, int | None] = {}
        for t in o.thresholds if "pointcvx" in o.methods else ():
            ts = _fmt_t(t)
            k = key_of(e.dataset, e.shape, "pointcvx", "fixed", ts)
            if ("pointcvx", "fixed", ts) not in todo:
                old = self.done[k]
                targets[ts] = int(float(old["hulls"])) if not old.get("error") and old.get("hulls") else None
                continue
            params = pointcvx_params(o, t)
            run = self.launch("pointcvx", params, t)
            once = self.oneshot("pointcvx", params, run)
            self.evaluate(run)
            targets[ts] = run.hulls if run.ok and not run.error else None
            rows.append(self._row("pointcvx", "fixed", ts, "threshold", run, **once))
        if self.mesh is None:
            for m, s, t in pending:
                if m != "pointcvx":
                    rows.append(self._row(m, s, t, param_name(m), None, error="skipped: needs a mesh"))
            return rows
        fixed: dict[str, Run] = {}
        for b in o.baselines:
            if (b, "fixed", "") not in todo:
                old = self._reusable(self.done[key_of(e.dataset, e.shape, b, "fixed", "")])
                if old is not None:
                    fixed[b] = old
                continue
            param, params = fixed_params(o, b)
            run = self.launch(b, params, param)
            once = self.oneshot(b, params, run)
            self.evaluate(run)
            rows.append(self._row(b, "fixed", "", param_name(b), run, **once))
            if run.ok and not run.error:
                fixed[b] = run
        for ts, target in targets.items():
            for b in o.baselines:
                if (b, "matched", ts) not in todo:
                    continue
                if target is None:
                    rows.append(self._row(b, "matched", ts, param_name(b), None,
                                          error="pointcvx failed: no hull count to match"))
                    continue
                best, tried = self._match(b, target, fixed.get(b))
                extra = {"target_hulls": target, "search_runs": len(tried),
                         "search_seconds": sum(r.seconds for r in tried if not r.reused)}
                if best is None:
                    last = tried[-1].error if tried else "no run"
                    rows.append(self._row(b, "matched", ts, param_name(b), None,
                                          error=f"every search run failed ({last})", **extra))
                    continue
                self.evaluate(best)
                rows.append(self._row(b, "matched", ts, param_name(b), best, **extra))
        return rows

    def _reusable(self, row: dict) -> Run | None:
        """A finished fixed-setting row (from an earlier invocation) as a run the matched search
        can reuse, or None."""
        if row.get("error") or not row.get("hull_file") or not row.get("hulls"):
            return None
        path = self.outdir / row["hull_file"]
        if not path.is_file():
            return None
        metrics = {k: num(row.get(k)) for k in METRICS}
        return Run(row["method"], num(row["param"]), True, hulls=int(num(row["hulls"])),
                   seconds=num(row["seconds"]), peak_mb=num(row["peak_mb"]), hull_file=path,
                   metrics=metrics)

    def _match(self, method: str, target: int, fixed: Run | None) -> tuple[Run | None, list[Run]]:
        """(the run whose hull count is closest to ``target``, every run tried)."""
        o = self.opts
        reuse = [fixed] if fixed is not None else []
        if method == "vhacdx":
            run = next((r for r in reuse if r.param == target), None)
            if run is not None:
                run.reused = True
            else:
                run = self.launch("vhacdx", vhacdx_params(o, target), target)
            return (run if run.ok else None), [run]
        lo, hi = COACD_RANGE if method == "coacd" else VHACD_RANGE
        make = coacd_params if method == "coacd" else vhacd_params
        return search_parameter(lambda x: self.launch(method, make(o, x), x), lo, hi, target,
                                o.search_runs, reuse, evaluate=self.evaluate)


def bench_shape(entry: dict, options: dict, outdir: str, done: dict[str, dict]) -> list[dict]:
    """Run every pending row of one shape; the rows, in :data:`~.results.COLUMNS` order.

    Top-level (picklable) so that ``--jobs`` can run shapes in a spawned process pool.
    """
    return ShapeBench(ShapeEntry(**entry), BenchOptions.from_dict(options), Path(outdir), done).run()
