"""``pointcvx bench``: pointcvx against CoACD and V-HACD on folders of shapes.

For every shape of every dataset (a folder, searched recursively, or one file):

1. The shape is read once, normalised to [-1, 1]^3 (:meth:`pointcvx.Normalization.to_unit_cube`
   of the vertices its faces use, as :func:`pointcvx.evaluate.evaluate` does) and written to a
   temporary OBJ: every method decomposes that same mesh. CAD parts (STEP, IGES) are tessellated
   first (``pointcvx.load(path, normalize=False).mesh``). Splats and point clouds have no mesh:
   only pointcvx runs on them (scored by :func:`pointcvx.evaluate.evaluate_points`); the
   baselines' rows say ``skipped: needs a mesh``.
2. Each (method, shape, setting) run is a fresh ``python -m pointcvx.apps.bench.worker`` process
   with a wall-clock timeout. The worker reports the method call's wall time (no interpreter
   start, no imports, no I/O) and its peak resident memory (``VmHWM`` on Linux; it includes the
   worker's interpreter and imports). A timeout or a crash becomes an error row; the bench goes
   on. This is the warm time: the worker first does what a long-running process does once
   (imports, model weights, one small decomposition).
3. Each fixed-setting run is then timed once more as a one-shot process, the way a user runs the
   method on one file (:mod:`.oneshot`): ``python -m pointcvx decompose SHAPE -o OUT.obj`` at the
   bench's settings, and thin Python wrappers for the baselines, timed from the process's start
   to its exit (``oneshot_seconds``; off with ``oneshot=False``).
4. The hulls are scored in the calling process with :func:`pointcvx.evaluate.evaluate` (hull
   count, concavity, Chamfer reconstruction, volume IoU, coverage), outside the timed call.

Settings
--------
fixed
    pointcvx at each threshold; CoACD at :data:`COACD_THRESHOLD`; V-HACD (pybullet, V-HACD 2.x)
    at :data:`VHACD_RESOLUTION` and its default concavity :data:`VHACD_CONCAVITY` (the paper's
    settings); vhacdx (V-HACD 4.x) at its defaults (:data:`VHACDX_MAX_HULLS` hulls at most,
    resolution :data:`VHACDX_RESOLUTION`).
matched
    The baseline's hull count is brought as close as possible to pointcvx's count ``H`` on the
    same shape: bisection in log space of CoACD's ``threshold`` over :data:`COACD_RANGE` and of
    V-HACD's ``concavity`` over :data:`VHACD_RANGE` (both ranges centred on the fixed setting,
    whose run is reused as the first probe; the hull count falls as the parameter grows), at
    most ``search_runs`` probes; the probe closest to ``H`` is kept (ties: lower concavity).
    vhacdx takes ``maxConvexHulls=H`` directly. A probe that fails (timeout, crash) counts as
    "too many hulls" and the search moves to coarser settings.

Outputs (all written atomically) in OUTDIR: ``results.csv`` (one row per dataset, shape, method,
setting and pointcvx threshold; see :data:`COLUMNS`), ``summary.md`` (means and medians per
dataset and category, paired win/tie/loss counts of pointcvx against each baseline at matched
granularity, ratios of median times, one-shot and warm), ``granularity.png`` (when matplotlib
is installed) and the hulls of every row under ``hulls/<method>/<setting>/<shape>.obj``.
Running again with the same OUTDIR skips the rows already in ``results.csv`` (unless
``overwrite``).

Modules, in the order a benchmark uses them: :mod:`.options` (:class:`BenchOptions`),
:mod:`.shapes` (finding the shapes), :mod:`.mesh` (the normalised mesh), :mod:`.methods` (each
method's parameters), :mod:`.launch` and :mod:`.worker` (one run in its own process),
:mod:`.oneshot` (the same run as a user's whole process), :mod:`.search` (matched
granularity), :mod:`.runs` (every run of one shape), :mod:`.results` (``results.csv``),
:mod:`.summary` and :mod:`.plot` (``summary.md``, ``granularity.png``), :mod:`.driver`
(:func:`run_bench`). The names below are imported from them on first use.
"""

from __future__ import annotations

import importlib

#: Public name -> the module of this package that defines it, imported on first use (PEP 562):
#: a worker or one-shot process that runs one module (``python -m pointcvx.apps.bench.oneshot``)
#: loads no other.
_NAMES = {
    "Progress": "driver", "run_bench": "driver",
    "Run": "launch",
    "COACD_RANGE": "methods", "COACD_THRESHOLD": "methods", "VHACD_CONCAVITY": "methods",
    "VHACD_RANGE": "methods", "VHACD_RESOLUTION": "methods", "VHACDX_MAX_HULLS": "methods",
    "VHACDX_RESOLUTION": "methods",
    "BASELINES": "options", "METHODS": "options", "PACKAGES": "options", "BenchOptions": "options",
    "plot_granularity": "plot",
    "COLUMNS": "results", "METRICS": "results", "BenchReport": "results", "read_results": "results",
    "write_results": "results",
    "ShapeBench": "runs", "bench_shape": "runs",
    "search_parameter": "search",
    "ShapeEntry": "shapes", "find_shapes": "shapes",
    "TIE_RTOL": "summary", "final_summary": "summary", "summarize": "summary",
    "win_tie_loss": "summary",
}


def __getattr__(name: str):
    if name not in _NAMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_NAMES[name]}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_NAMES))


__all__ = [
    "BASELINES",
    "COACD_RANGE",
    "COACD_THRESHOLD",
    "COLUMNS",
    "METHODS",
    "METRICS",
    "PACKAGES",
    "TIE_RTOL",
    "VHACDX_MAX_HULLS",
    "VHACDX_RESOLUTION",
    "VHACD_CONCAVITY",
    "VHACD_RANGE",
    "VHACD_RESOLUTION",
    "BenchOptions",
    "BenchReport",
    "Progress",
    "Run",
    "ShapeBench",
    "ShapeEntry",
    "bench_shape",
    "final_summary",
    "find_shapes",
    "plot_granularity",
    "read_results",
    "run_bench",
    "search_parameter",
    "summarize",
    "win_tie_loss",
    "write_results",
]
