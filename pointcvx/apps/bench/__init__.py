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
   on.
3. The hulls are scored in the calling process with :func:`pointcvx.evaluate.evaluate` (hull
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
granularity, ratio of median times), ``granularity.png`` (when matplotlib is installed) and the
hulls of every row under ``hulls/<method>/<setting>/<shape>.obj``. Running again with the same
OUTDIR skips the rows already in ``results.csv`` (unless ``overwrite``).

Modules, in the order a benchmark uses them: :mod:`.options` (:class:`BenchOptions`),
:mod:`.shapes` (finding the shapes), :mod:`.mesh` (the normalised mesh), :mod:`.methods` (each
method's parameters), :mod:`.launch` and :mod:`.worker` (one run in its own process),
:mod:`.search` (matched granularity), :mod:`.runs` (every run of one shape), :mod:`.results`
(``results.csv``), :mod:`.summary` and :mod:`.plot` (``summary.md``, ``granularity.png``),
:mod:`.driver` (:func:`run_bench`).
"""

from __future__ import annotations

from .driver import Progress, run_bench
from .launch import Run
from .methods import (
    COACD_RANGE,
    COACD_THRESHOLD,
    VHACD_CONCAVITY,
    VHACD_RANGE,
    VHACD_RESOLUTION,
    VHACDX_MAX_HULLS,
    VHACDX_RESOLUTION,
)
from .options import BASELINES, METHODS, PACKAGES, BenchOptions
from .plot import plot_granularity
from .results import COLUMNS, METRICS, BenchReport, read_results, write_results
from .runs import ShapeBench, bench_shape
from .search import search_parameter
from .shapes import ShapeEntry, find_shapes
from .summary import TIE_RTOL, final_summary, summarize, win_tie_loss

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
