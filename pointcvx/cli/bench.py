"""``pointcvx bench``: pointcvx against CoACD and V-HACD on folders of shapes
(:mod:`pointcvx.apps.bench`)."""

from __future__ import annotations

import argparse

from ..errors import InputError
from ..flags import add_flags, options_from_args
from ..options import DECOMPOSE_POINTS, DecomposeOptions, LoadOptions


def _methods(text: str) -> tuple[str, ...]:
    return tuple(dict.fromkeys(m.strip().lower() for m in text.split(",") if m.strip()))


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "bench",
        help="compare pointcvx with CoACD and V-HACD on folders of shapes",
        description="Decompose every shape of DATASET (a folder, searched recursively, or a file) "
        "with each method, each run in its own process with a timeout, on the same mesh "
        "normalised to [-1,1]^3; score the hulls with the paper's protocol (as `pointcvx "
        "evaluate`). Baselines run at the paper's fixed settings (CoACD threshold 0.1, V-HACD "
        "resolution 1,000,000) and, with --match, at pointcvx's hull count (parameter search). "
        "Each run is timed warm (the method's call in a process that has loaded everything) "
        "and, for the fixed settings, as a one-shot process (start-up included). "
        "Writes OUTDIR/results.csv, summary.md, granularity.png and hulls/; rerunning resumes.",
    )
    p.add_argument("datasets", nargs="+", metavar="DATASET", help="folder of shapes, or a shape file")
    p.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="output folder")
    p.add_argument("--methods", type=_methods, default=("pointcvx", "coacd", "vhacd"),
                   help="comma-separated among pointcvx, coacd, vhacd (V-HACD 2.x via pybullet), "
                        "vhacdx (V-HACD 4.x) (default pointcvx,coacd,vhacd)")
    p.add_argument("--thresholds", type=_floats, default=None, metavar="T1,T2,...",
                   help="run pointcvx at each threshold (the matched baselines follow each); "
                        "replaces --threshold")
    p.add_argument("--match", action=argparse.BooleanOptionalAction, default=True,
                   help="also run each baseline at pointcvx's hull count (default on)")
    p.add_argument("--oneshot", action=argparse.BooleanOptionalAction, default=True,
                   help="also time each fixed-setting run as a whole process, the way a user runs "
                        "the method on one file (`pointcvx decompose`, thin wrappers of the "
                        "baselines): results.csv's oneshot_seconds (default on)")
    p.add_argument("--timeout", type=float, default=600.0, metavar="SECONDS",
                   help="wall-clock limit of each run (default 600)")
    p.add_argument("--limit", type=int, default=None, metavar="N", help="at most N shapes per dataset")
    p.add_argument("--jobs", type=int, default=1, metavar="N", help="shapes run at once (default 1)")
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
    # pointcvx's settings; its --seed also seeds CoACD and the metrics, its own --timeout bounds each run
    add_flags(p, DecomposeOptions, skip=("timeout",))
    add_flags(p, LoadOptions, defaults={"n_points": DECOMPOSE_POINTS})
    p.set_defaults(func=run)
    return p


def bench_options(args: argparse.Namespace):
    """The :class:`~pointcvx.apps.bench.BenchOptions` of parsed ``pointcvx bench`` arguments."""
    from ..apps.bench import BenchOptions

    dec = options_from_args(args, DecomposeOptions, skip=("timeout",))
    if isinstance(dec.threshold, str):
        raise InputError("bench compares shapes normalised to [-1, 1]^3: give --threshold as a number "
                         f"in that frame, not the length {dec.threshold!r}")
    return BenchOptions(
        methods=tuple(args.methods),
        thresholds=tuple(args.thresholds) if args.thresholds else (dec.threshold,),
        match=bool(args.match), timeout=float(args.timeout), decompose=dec,
        load=options_from_args(args, LoadOptions), eval_samples=args.eval_samples,
        vhacd_resolution=args.vhacd_resolution, search_runs=args.search_runs,
        oneshot=bool(args.oneshot),
    )


def run(args: argparse.Namespace) -> int:
    """Run ``pointcvx bench``; 0 when every row ran (errors inside rows included)."""
    from ..apps.bench import final_summary, run_bench
    from ..progress import LazyBar

    opts = bench_options(args)
    bar = LazyBar(not args.quiet, "bench", "shape")
    try:
        report = run_bench(args.datasets, args.output, opts, limit=args.limit, jobs=args.jobs,
                           overwrite=args.overwrite,
                           progress=lambda done, total, shape: bar.set(done, total, shape))
    finally:
        bar.close()
    if not args.quiet:
        print(final_summary(report))
    return 0
