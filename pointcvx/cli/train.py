"""``pointcvx prepare`` and ``pointcvx train``: the training set and the feed-forward model."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import EXIT_INPUT, InputError
from ..progress import LazyBar, StageBars


def add_parsers(sub) -> None:
    prep = sub.add_parser(
        "prepare",
        help="build a training set for the feed-forward model",
        description="Write one .npz per training shape into OUTDIR: watertight conversion, surface "
        "samples with normals, convex-pair triplets and SDF samples. Shapes are procedural "
        "non-convex solids plus the meshes of ../shared/data/train/random_urdfs (never the "
        "benchmark or dev shapes). Resumable: shapes already written are skipped; failures are "
        "recorded in OUTDIR/manifest.json.",
    )
    prep.add_argument("outdir", help="folder for the prepared shapes")
    prep.add_argument("--procedural", type=int, default=200, metavar="N",
                      help="procedural shapes to generate (default 200)")
    prep.add_argument("--urdfs", metavar="DIR", default=None,
                      help="folder of training meshes (default ../shared/data/train/random_urdfs)")
    prep.add_argument("--no-urdfs", action="store_true", help="procedural shapes only")
    prep.add_argument("--max-urdfs", type=int, default=None, metavar="N", help="use at most N meshes")
    prep.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    prep.add_argument("--seed", type=int, default=0)
    prep.add_argument("--points", type=int, default=20000, metavar="N",
                      help="surface samples per shape, also the triplet pool (default 20000)")
    prep.add_argument("--anchors", type=int, default=512, metavar="N",
                      help="convex-pair anchors per shape (default 512)")
    prep.add_argument("--negatives", type=int, default=256, metavar="N",
                      help="negatives per anchor, half hard and half uniform (default 256)")
    prep.add_argument("--sdf-samples", type=int, default=12288, metavar="N",
                      help="SDF supervision points per shape, 2/3 near the surface (default 12288)")
    prep.add_argument("--compact", action="store_true",
                      help="float16 arrays and no duplicate pool: about a third of the bytes")
    prep.add_argument("-q", "--quiet", action="store_true", help="no progress bar, no summary")
    prep.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    prep.set_defaults(func=run_prepare)

    tr = sub.add_parser(
        "train",
        help="train the feed-forward feature model",
        description="Train the feed-forward model on a folder written by `pointcvx prepare`, with "
        "on-the-fly augmentation (rotations, point counts, noise, partial views, normal flips, "
        "splat-like jitter). Checkpoints (last.pt, step_*.pt) and log.csv go to --output; an "
        "existing run there is resumed. Runs unchanged under torchrun for several GPUs or nodes "
        "(DistributedDataParallel; rank 0 writes).",
    )
    tr.add_argument("data", help="folder written by `pointcvx prepare`")
    tr.add_argument("-o", "--output", required=True, metavar="RUN", help="run folder (checkpoints, log)")
    tr.add_argument("--config", default="small",
                    help="preset (small, paper) or a JSON config file (default small)")
    tr.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a config field, e.g. --set transformer.layers=2 (repeatable)")
    tr.add_argument("--steps", type=int, required=True, help="train up to this global step")
    tr.add_argument("--schedule-steps", type=int, default=None, metavar="N",
                    help="length of the cosine learning-rate schedule (default --steps); lets a run "
                    "stop early and be continued later on the same schedule")
    tr.add_argument("--points", type=int, default=4096, help="input points per shape (4096)")
    tr.add_argument("--device", default=None, help="cpu, cuda, cuda:1 ... (default: best available)")
    tr.add_argument("--workers", type=int, default=0, metavar="N",
                    help="processes that read and augment the next batches ahead (default 0: none); "
                    "the batches are the same for any count")
    tr.add_argument("--seed", type=int, default=0)
    tr.add_argument("--no-resume", action="store_true", help="start over even if RUN has a checkpoint")
    tr.add_argument("--init", metavar="CKPT", default=None,
                    help="start a new run from these weights (fine-tuning; fresh optimiser and schedule)")
    tr.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    tr.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    tr.set_defaults(func=run_train)


def run_prepare(args: argparse.Namespace) -> int:
    from ..training.data import prepare_dataset

    for flag, value, low in (("--points", args.points, 64), ("--anchors", args.anchors, 1),
                             ("--negatives", args.negatives, 2), ("--sdf-samples", args.sdf_samples, 0)):
        if value < low:
            raise InputError(f"{flag} must be at least {low}, got {value}")
    bars = StageBars(not args.quiet)
    manifest = prepare_dataset(
        args.outdir, args.procedural, use_urdfs=not args.no_urdfs, seed=args.seed, jobs=args.jobs,
        urdf_root=args.urdfs, max_urdfs=args.max_urdfs, compact=args.compact,
        progress=lambda done, total, entry: bars("prepare", done, total),
        n_points=args.points, n_anchors=args.anchors, n_candidates=max(512, 2 * args.negatives),
        n_hard=args.negatives // 2, n_uniform=args.negatives - args.negatives // 2,
        n_sdf_near=args.sdf_samples * 2 // 3, n_sdf_uniform=args.sdf_samples - args.sdf_samples * 2 // 3,
    )
    bars.close()
    ok = sum(1 for e in manifest.values() if e.get("ok"))
    if not args.quiet:
        print(f"{ok} of {len(manifest)} shapes prepared in {args.outdir}")
    return 0 if ok else EXIT_INPUT


def run_train(args: argparse.Namespace) -> int:
    from ..model.config import ModelConfig
    from ..model.train import train
    from ..training.augment import AugmentConfig
    from ..training.data import TripletDataset

    if Path(args.config).is_file():
        config = ModelConfig.from_json(Path(args.config).read_text())
    else:
        try:
            config = ModelConfig.preset(args.config)
        except (KeyError, ValueError):
            raise InputError(f"unknown config {args.config!r}: use small, paper or a JSON file") from None
    try:
        config = config.with_overrides([f"train.seed={args.seed}", *args.set])
    except (KeyError, ValueError) as exc:
        raise InputError(f"bad --set: {exc}") from None
    if args.init is not None and not Path(args.init).is_file():
        raise InputError(f"{args.init}: no such checkpoint")
    data = Path(args.data)
    if not data.is_dir():
        raise InputError(f"{data}: no such folder (make one with `pointcvx prepare`)")
    dataset = TripletDataset(data, augment=True, seed=args.seed,
                             config=AugmentConfig(n_points=args.points))
    if len(dataset) == 0:
        raise InputError(f"{data}: no prepared shapes (run `pointcvx prepare {data}` first)")
    run = Path(args.output)
    if args.no_resume and (run / "last.pt").exists():
        (run / "last.pt").unlink()
    bar = LazyBar(not args.quiet, "train", "step", leave=True)
    try:
        train(config, dataset, args.steps, run, resume=not args.no_resume, device=args.device,
              init=args.init, total_steps=args.schedule_steps, workers=args.workers,
              progress=lambda step, steps, losses: bar.set(step, steps, f"loss {losses['loss']:.3f}"))
    except ValueError as exc:
        raise InputError(str(exc)) from None
    finally:
        bar.close()
    if not args.quiet:
        print(f"trained to step {args.steps}: {run / 'last.pt'}")
    return 0
