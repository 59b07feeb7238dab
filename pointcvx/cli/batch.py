"""``pointcvx batch``: many shapes on a local process pool or Ray (:mod:`pointcvx.apps.batch`)."""

from __future__ import annotations

import argparse
import json
import time

from ..flags import add_flags, options_from_args
from ..options import DECOMPOSE_POINTS, DecomposeOptions, LoadOptions
from .choices import LazyChoices


def add_parser(sub) -> argparse.ArgumentParser:
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
    p.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="output folder")
    p.add_argument("--engine", choices=LazyChoices("pointcvx.apps.batch.driver", "ENGINES"),
                   default="local", metavar="ENGINE",
                   help="%(choices)s: local process pool (default) or Ray (pip install 'pointcvx[ray]')")
    p.add_argument("--jobs", type=_positive(int), default=None, metavar="N",
                   help="workers (default: CPUs / --threads, of this machine or the Ray cluster)")
    p.add_argument("--address", default=None, metavar="ADDR",
                   help="Ray cluster to join (auto, HOST:PORT, ray://HOST:PORT); default: start a "
                   "local Ray instance for this batch")
    p.add_argument("--threads", type=_positive(int), default=1, metavar="T",
                   help="threads per worker (default 1; fixed so results do not depend on --jobs)")
    p.add_argument("--timeout", type=_positive(float), default=600.0, metavar="SECONDS",
                   help="wall-clock limit per asset (default 600)")
    p.add_argument("--max-memory", type=float, default=None, metavar="MB",
                   help="resident memory limit of a worker while it runs an asset (default: 80%% "
                   "of the machine's memory / workers; 0: none)")
    p.add_argument("--format", choices=LazyChoices("pointcvx.export", "FORMATS"), default="obj",
                   metavar="FORMAT",
                   help="output format per asset: %(choices)s (default obj: one OBJ, an 'o' per hull)")
    add_flags(p, DecomposeOptions, skip=("timeout",))  # its own --timeout bounds each asset
    p.add_argument("--skip-failed", action="store_true",
                   help="do not retry the assets the manifest records as failed")
    p.add_argument("--overwrite", action="store_true", help="forget the manifest and redo every asset")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar, no summary")
    p.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    add_flags(p, LoadOptions, defaults={"n_points": DECOMPOSE_POINTS})
    p.set_defaults(func=run)
    return p


def _positive(kind: type):
    """An argparse type: a positive number of ``kind``, else a usage error."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not value > 0 or value != value or value == float("inf"):
            raise argparse.ArgumentTypeError(f"must be positive, got {text}")
        return value

    parse.__name__ = kind.__name__
    return parse


def batch_options(args: argparse.Namespace):
    """The :class:`~pointcvx.apps.batch.BatchOptions` of parsed ``pointcvx batch`` arguments."""
    from ..apps.batch import BatchOptions

    dec = options_from_args(args, DecomposeOptions, skip=("timeout",))  # --timeout is batch's own
    return BatchOptions(dec, options_from_args(args, LoadOptions), format=args.format,
                        timeout=args.timeout, max_memory_mb=args.max_memory, threads=args.threads)


def summary_text(report) -> str:
    """The lines ``pointcvx batch`` prints at the end."""
    from ..apps.batch import REPORT_CSV

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


def run(args: argparse.Namespace) -> int:
    """Run ``pointcvx batch``: 0 when every asset is done, 1 when some failed."""
    from ..apps.batch import run_batch
    from ..progress import LazyBar

    opts = batch_options(args)
    bar = LazyBar(not args.quiet, "batch", "asset")
    failures = 0
    t0 = time.perf_counter()

    def progress(done: int, total: int, rec: dict) -> None:
        nonlocal failures
        failures += rec.get("status") == "failed"
        per_min = 60.0 * done / max(1e-9, time.perf_counter() - t0)
        bar.set(done, total, f"avg {per_min:.1f}/min" + (f", {failures} failed" if failures else ""))

    try:
        report = run_batch(args.inputs, args.output, opts, engine=args.engine, jobs=args.jobs,
                           address=args.address, retry_failed=not args.skip_failed,
                           overwrite=args.overwrite, progress=progress)
    finally:
        bar.close()
    if not args.quiet:
        print(json.dumps(report.summary, indent=2) if args.json else summary_text(report))
    return 0 if not report.failed and not report.summary["pending"] else 1
