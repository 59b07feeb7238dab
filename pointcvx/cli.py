"""The ``pointcvx`` command line.

Every failure a user can cause ends in one line on stderr and a non-zero exit status:
1 for bad input or output problems, 2 for bad usage, 3 for an internal error, 130 if interrupted.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from pathlib import Path

import numpy as np

from . import __version__
from .errors import InputError, MissingLibraryError, OutputError, PointcvxError
from .export import EXTENSIONS as EXPORT_EXTENSIONS
from .export import FORMATS as EXPORT_FORMATS
from .progress import LazyBar
from .simplify import TARGETS as ENGINE_TARGETS
from .syslibs import install_hint, missing_library

log = logging.getLogger("pointcvx")

EXIT_INPUT, EXIT_USAGE, EXIT_INTERNAL, EXIT_INTERRUPT = 1, 2, 3, 130


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2
        self.exit(EXIT_USAGE, f"pointcvx: error: {message} (see pointcvx --help)\n")


def add_decomposition_options(p: argparse.ArgumentParser) -> None:
    """The decomposition options that ``decompose`` and ``batch`` share (engine caps, threshold,
    hull budget, feature source, split, merge)."""
    p.add_argument("--target", choices=list(ENGINE_TARGETS), default=None,
                   help="keep every hull within this engine's caps (physx: 255 vertices and 255 "
                        "triangles; physx-gpu: 64 and 64; newton: 64 vertices; unity: 255 "
                        "triangles; mujoco, bullet: none); reduced hulls still contain their part")
    p.add_argument("--max-hull-vertices", type=int, default=None, metavar="N",
                   help="at most N vertices per hull (with --target: the tighter cap wins)")
    p.add_argument("-t", "--threshold", type=float, default=0.1,
                   help="concavity threshold in the normalised [-1,1]^3 frame (default 0.1)")
    p.add_argument("-k", "--max-hulls", type=int, default=64, help="hull budget (default 64)")
    p.add_argument("--features", choices=["auto", "optimize", "model"], default="auto",
                   help="optimise a feature field per shape, or use the bundled model (loaded once "
                        "per process); auto (default): the model on splats, where it measured on par in "
                        "about half the time, optimisation on meshes, CAD and scans")
    p.add_argument("--model", metavar="CKPT",
                   help="feed-forward model checkpoint for --features model (from `pointcvx train`)")
    p.add_argument("--views", type=int, default=1, metavar="V",
                   help="with --features model: encode the shape in V orientations and use the "
                   "concatenated features (a test-time ensemble; default 1)")
    p.add_argument("--split", choices=["auto", "kmeans", "ward"], default="auto",
                   help="how a part is cut in two (auto: k-means on features + xyz)")
    p.add_argument("--no-merge", action="store_true", help="skip the merge pass")
    p.add_argument("--subsurface", type=float, default=None, metavar="DEPTH",
                   help="leave points deeper than DEPTH inside the solid (normalised frame; 0.05 "
                        "suits splats whose Gaussians form a layer under the surface) out of the "
                        "concavity measure; off by default, since the walls of folds narrower "
                        "than about 0.1 read as deep too")


def _add_load_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("loading (all inputs)")
    g.add_argument("-n", "--points", type=int, default=None, metavar="N",
                   help="cap the point count (meshes/CAD: samples to draw; default 20000 for "
                        "meshes, every point for splats and scans)")
    g.add_argument("--seed", type=int, default=0, help="seed of every random choice (default 0)")
    g.add_argument("--no-normalize", action="store_true",
                   help="keep input units instead of normalising to [-1, 1]^3")
    g = p.add_argument_group("meshes and CAD")
    g.add_argument("--orient-rays", type=int, default=8, metavar="K",
                   help="rays per side in the outward test of mesh faces (default 8)")
    g.add_argument("--cad-mesh-size", type=float, default=0.01, metavar="F",
                   help="CAD tessellation size as a fraction of the part's diagonal (default 0.01)")
    g = p.add_argument_group("Gaussian splats")
    g.add_argument("--min-opacity", type=float, default=0.1, metavar="A",
                   help="drop Gaussians with opacity below A (default 0.1)")
    g.add_argument("--floater-ratio", type=float, default=0.01, metavar="R",
                   help="drop clusters holding less than R of all Gaussians (default 0.01; 0 = off)")
    g.add_argument("--samples-per-gaussian", type=int, default=1, metavar="S",
                   help="points drawn from each Gaussian's ellipsoid (default 1: centres)")
    g = p.add_argument_group("scans (point clouds without normals)")
    g.add_argument("--outlier-neighbors", type=int, default=20, metavar="K",
                   help="neighbours for statistical outlier removal (default 20; 0 = off)")
    g.add_argument("--outlier-std", type=float, default=2.5, metavar="S",
                   help="std-dev ratio for statistical outlier removal (default 2.5)")
    g.add_argument("--voxel-size", type=float, default=None, metavar="V",
                   help="voxel down-sampling size in input units (default: off)")
    g.add_argument("--normal-neighbors", type=int, default=24, metavar="K",
                   help="neighbours used to estimate normals (default 24)")


def _load_options(args: argparse.Namespace):
    from .io import LoadOptions

    return LoadOptions(
        n_points=args.points, seed=args.seed, normalize=not args.no_normalize,
        orient_rays=args.orient_rays, cad_mesh_size=args.cad_mesh_size,
        min_opacity=args.min_opacity, floater_ratio=args.floater_ratio,
        samples_per_gaussian=args.samples_per_gaussian, outlier_neighbors=args.outlier_neighbors,
        outlier_std=args.outlier_std, voxel_size=args.voxel_size,
        normal_neighbors=args.normal_neighbors,
    )


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="pointcvx",
        description="Approximate convex decomposition of Gaussian splats, scans, meshes and CAD parts.",
        epilog="Exit status: 0 ok, 1 bad input or output, 2 bad usage, 3 internal error.",
    )
    parser.add_argument("--version", action="version", version=f"pointcvx {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    info = sub.add_parser(
        "info",
        help="load any input and report what was detected",
        description="Load PATH (mesh, CAD, splat or scan; the format is sniffed from the content), "
        "print what was detected (modality, format, counts, bounding box, how normals were "
        "obtained, what was filtered) and optionally write the oriented cloud as a PLY.",
    )
    info.add_argument("path", help="input file: OBJ/PLY/STL/OFF/GLB/GLTF mesh, STEP/IGES part, "
                                   "INRIA/compressed PLY, SPZ or .splat splat, PLY/PCD/XYZ/PTS/LAS scan")
    info.add_argument("-o", "--output", metavar="OUT.ply",
                      help="write the oriented cloud (points, normals, colours) to this PLY")
    info.add_argument("--normalized", action="store_true",
                      help="write OUT.ply in the normalised [-1, 1]^3 frame instead of input units")
    info.add_argument("--overwrite", action="store_true", help="replace OUT.ply if it exists")
    info.add_argument("--json", action="store_true", help="print the report as JSON")
    info.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    info.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    _add_load_options(info)
    info.set_defaults(func=cmd_info)

    dec = sub.add_parser(
        "decompose",
        help="split a shape into convex hulls",
        description="Decompose INPUT (any format `pointcvx info` reads) into convex hulls: "
        "convex-aware features, then recursive splitting of the most concave part until every "
        "part's concavity is under --threshold or --max-hulls hulls exist, then a merge pass. "
        "Writes the hulls in the input's units (an OBJ with one object per hull by default; STL, "
        "GLB/GLTF, URDF, MJCF, USD or a JSON report with --format or by OUT's suffix), optionally "
        "within an engine's per-hull caps (--target), and prints hulls, concavity and time.",
    )
    dec.add_argument("input", help="mesh, CAD part, Gaussian splat or scan")
    dec.add_argument("-o", "--output", metavar="OUT",
                     help="OUT.obj (one 'o' per hull), OUT.stl/DIR for one file per hull, OUT.glb/"
                          "OUT.gltf (a node per hull), OUT.urdf or OUT.xml/OUT.mjcf (folder OUT/ "
                          "with the robot file and an OBJ per hull), OUT.usda/OUT.usd (USD rigid "
                          "body, a collider per hull), OUT.json (report) "
                          "(default: ./INPUT_STEM_hulls.obj)")
    dec.add_argument("--format", choices=list(EXPORT_FORMATS), default=None,
                     help="output format (default: from OUT's suffix)")
    add_decomposition_options(dec)
    dec.add_argument("--per-hull", action="store_true", help="write one file per hull")
    dec.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    dec.add_argument("--json", action="store_true", help="print the summary as JSON")
    dec.add_argument("-q", "--quiet", action="store_true", help="no progress bar, no summary")
    dec.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    _add_load_options(dec)
    dec.set_defaults(func=cmd_decompose, points=20000)

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
    prep.set_defaults(func=cmd_prepare)

    tr = sub.add_parser(
        "train",
        help="train the feed-forward feature model",
        description="Train the feed-forward model on a folder written by `pointcvx prepare`, with "
        "on-the-fly augmentation (rotations, point counts, noise, partial views, normal flips, "
        "splat-like jitter). Checkpoints (last.pt, step_*.pt) and log.csv go to --out; an "
        "existing run there is resumed. Runs unchanged under torchrun for several GPUs or nodes "
        "(DistributedDataParallel; rank 0 writes).",
    )
    tr.add_argument("data", help="folder written by `pointcvx prepare`")
    tr.add_argument("-o", "--out", required=True, metavar="RUN", help="run folder (checkpoints, log)")
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
    tr.set_defaults(func=cmd_train)

    ev = sub.add_parser(
        "evaluate",
        help="score a decomposition against its shape (the paper's protocol)",
        description="Score HULLS (an OBJ with one object per hull, or any mesh file whose "
        "connected components are the hulls) against MESH, both normalised to [-1,1]^3 by "
        "MESH's bounding box: number of hulls; concavity = max over hulls of CoACD's concavity of "
        "MESH ∩ hull (20,000 samples per component); reconstruction = Chamfer distance between "
        "MESH and the union of hulls (20,000 samples); volume IoU; share of MESH's surface "
        "covered by the hulls.",
    )
    ev.add_argument("mesh", help="the original shape (a mesh file)")
    ev.add_argument("hulls", help="the hulls (OBJ with one 'o' per hull, or a multi-body mesh)")
    ev.add_argument("--samples", type=int, default=20000, help="samples per surface (20000)")
    ev.add_argument("--seed", type=int, default=0)
    ev.add_argument("--json", action="store_true", help="print JSON")
    ev.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    ev.set_defaults(func=cmd_evaluate)

    from .batch import add_parser as add_batch
    from .bench import add_parser as add_bench

    add_bench(sub)
    add_batch(sub)
    return parser


class _Bars:
    """Progress bars on stderr, one per pipeline stage (``progress(stage, done, total)``)."""

    def __init__(self, enabled: bool):
        self.enabled = enabled
        self.bars: dict[str, LazyBar] = {}

    def __call__(self, stage: str, done: int, total: int) -> None:
        if stage not in self.bars:
            self.bars[stage] = LazyBar(self.enabled, stage, "step" if stage == "features" else "hull")
        self.bars[stage].set(done, total)

    def close(self) -> None:
        for bar in self.bars.values():
            bar.close()


def default_output(input_path: str, format: str | None = None) -> Path:
    return Path.cwd() / f"{Path(input_path).stem}_hulls{EXPORT_EXTENSIONS[format or 'obj']}"


def _check_decompose_output(out: Path, fmt: str, per_hull: bool, args: argparse.Namespace) -> None:
    """Refuse before the (slow) decomposition what the export would refuse after it."""
    from .export import main_file, output_folder

    main = main_file(out, fmt, per_hull)
    if main is None or fmt in ("urdf", "mjcf"):  # a folder, made if missing
        folder = output_folder(out, fmt)
        if folder.exists() and not folder.is_dir():
            raise OutputError(f"{folder}: exists and is not a directory")
        first = main if main is not None else folder / f"hull_000{EXPORT_EXTENSIONS[fmt]}"
        if first.exists() and not args.overwrite:
            raise OutputError(f"{first}: exists; pass --overwrite to replace it")
        return
    check_output_path(str(main), [args.input], args.overwrite)


def cmd_decompose(args: argparse.Namespace) -> int:
    from .export import format_for, main_file
    from .pipeline import decompose
    from .simplify import hull_limits

    out = Path(args.output) if args.output else default_output(args.input, args.format)
    fmt = format_for(out, args.format)
    per_hull = args.per_hull or main_file(out, fmt) is None
    if per_hull and fmt not in ("obj", "stl"):
        raise InputError(f"--per-hull applies to obj and stl outputs, not {fmt}")
    limits = hull_limits(args.target, args.max_hull_vertices)
    _check_decompose_output(out, fmt, per_hull, args)
    opts = _load_options(args)
    load_kwargs = {k: v for k, v in vars(opts).items() if k not in ("n_points", "seed")}
    bars = _Bars(not args.quiet)
    try:
        result = decompose(
            args.input, threshold=args.threshold, max_hulls=args.max_hulls,
            features=args.features, model=args.model, views=args.views, merge=not args.no_merge,
            split=args.split, n_points=args.points, seed=args.seed, target=args.target,
            max_hull_vertices=args.max_hull_vertices, subsurface=args.subsurface, progress=bars,
            **load_kwargs,
        )
    finally:
        bars.close()
    written = result.export(out, fmt, overwrite=args.overwrite, per_hull=per_hull)
    if args.quiet:
        return 0
    summary = result.summary()
    summary["format"] = fmt
    summary["output"] = str(written[0].parent / f"hull_*{EXPORT_EXTENSIONS[fmt]}" if per_hull
                            else written[0])
    summary["files"] = len(written)
    if result.params.get("hull_limits"):
        summary["hull_limits"] = result.params["hull_limits"]
    summary["features"] = result.params.get("features")
    summary["timings"] = {k: round(v, 3) for k, v in result.timings.items()}
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        line = (f"{summary['hulls']} hulls, max concavity {summary['max_concavity']:.4f}, "
                f"{summary['seconds']:.2f} s, {summary['features']} features")
        if limits.active:
            caps = ", ".join(f"{what} <= {v}" for what, v in (("vertices", limits.max_vertices),
                                                               ("triangles", limits.max_faces))
                             if v is not None)
            line += (f"; {limits.target or 'limits'} ({caps}): at most {summary['max_hull_vertices']} "
                     f"vertices per hull, added volume {summary['added_volume']:.6g} "
                     f"(+{100 * summary['added_volume_ratio']:.3g}%)")
        elif limits.target:
            line += f"; {limits.target}: no per-hull caps"
        print(f"{line} -> {summary['output']}")
    return 0


def cmd_prepare(args: argparse.Namespace) -> int:
    from .errors import InputError
    from .training.data import prepare_dataset

    for flag, value, low in (("--points", args.points, 64), ("--anchors", args.anchors, 1),
                             ("--negatives", args.negatives, 2), ("--sdf-samples", args.sdf_samples, 0)):
        if value < low:
            raise InputError(f"{flag} must be at least {low}, got {value}")

    bars = _Bars(not args.quiet)
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


def cmd_train(args: argparse.Namespace) -> int:
    from .errors import InputError
    from .model.config import ModelConfig
    from .model.train import train
    from .training.augment import AugmentConfig
    from .training.data import TripletDataset

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
    if args.no_resume and (Path(args.out) / "last.pt").exists():
        (Path(args.out) / "last.pt").unlink()
    bar = LazyBar(not args.quiet, "train", "step", leave=True)
    try:
        train(config, dataset, args.steps, args.out, resume=not args.no_resume, device=args.device,
              init=args.init, total_steps=args.schedule_steps, workers=args.workers,
              progress=lambda step, steps, losses: bar.set(step, steps, f"loss {losses['loss']:.3f}"))
    except ValueError as exc:
        raise InputError(str(exc)) from None
    finally:
        bar.close()
    if not args.quiet:
        print(f"trained to step {args.steps}: {Path(args.out) / 'last.pt'}")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    from .metrics import evaluate_files

    report = evaluate_files(args.mesh, args.hulls, n_samples=args.samples, seed=args.seed)
    if args.json:
        print(json.dumps(report, indent=2, default=float))
    else:
        for key in ("hulls", "concavity", "reconstruction", "iou", "coverage", "seconds"):
            if key in report:
                value = report[key]
                print(f"{key:<15} {value:.5f}" if isinstance(value, float) else f"{key:<15} {value}")
    return 0


def check_output_path(output: str, inputs: list[str], overwrite: bool) -> Path:
    """Refuse to write onto an input, or onto an existing file without ``overwrite``."""
    out = Path(output)
    for src in inputs:
        if out.exists() and Path(src).exists() and os.path.samefile(out, src):
            raise OutputError(f"{out}: refusing to overwrite the input file")
    if out.exists() and not overwrite:
        raise OutputError(f"{out}: exists; pass --overwrite to replace it")
    if not out.parent.exists() and str(out.parent):
        raise OutputError(f"{out.parent}: output directory does not exist")
    return out


def _report(cloud) -> dict:
    lo, hi = cloud.in_input_units().bounds if not cloud.normalization.is_identity else cloud.bounds
    info = dict(cloud.info)
    report = {
        "source": info.pop("source", None),
        "modality": cloud.modality,
        "format": info.pop("format", None),
        "points": len(cloud),
        "bbox_min": np.round(lo, 6).tolist(),
        "bbox_max": np.round(hi, 6).tolist(),
        "normalization": {
            "center": np.round(cloud.normalization.center, 6).tolist(),
            "scale": round(float(cloud.normalization.scale), 9),
        },
        "has_colors": cloud.colors is not None,
        "has_mesh": cloud.mesh is not None,
    }
    report.update(info)
    return report


def cmd_info(args: argparse.Namespace) -> int:
    from .io import load

    opts = _load_options(args)
    out = check_output_path(args.output, [args.path], args.overwrite) if args.output else None
    cloud = load(args.path, opts)
    report = _report(cloud)
    if out is not None:
        target = cloud if args.normalized else cloud.in_input_units()
        target.save_ply(str(out))
        report["written"] = str(out)
    if args.quiet:
        return 0
    if args.json:
        print(json.dumps(report, indent=2, default=str))
    else:
        width = max(len(k) for k in report)
        for key, value in report.items():
            print(f"{key:<{width}}  {value}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help(sys.stderr)
        return EXIT_USAGE
    logging.basicConfig(
        level=logging.DEBUG if getattr(args, "verbose", False) else logging.WARNING,
        format="pointcvx: %(levelname)s: %(message)s",
    )
    try:
        return args.func(args)
    except PointcvxError as exc:
        print(f"pointcvx: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("pointcvx: interrupted", file=sys.stderr)
        return EXIT_INTERRUPT
    except MemoryError:
        print("pointcvx: error: out of memory (try a smaller --points)", file=sys.stderr)
        return EXIT_INPUT
    except (ImportError, OSError) as exc:
        library = missing_library(exc)
        if library is None:
            return _internal_error(args, exc)
        print(f"pointcvx: error: {MissingLibraryError(_missing_module(exc), library, install_hint(library))}",
              file=sys.stderr)
        return EXIT_INPUT
    except Exception as exc:  # noqa: BLE001 - the CLI promises one line, never a traceback
        return _internal_error(args, exc)


def _missing_module(exc: BaseException) -> str:
    """The package whose native module failed to load (its folder's name), or 'a dependency'."""
    path = getattr(exc, "path", None)
    return Path(path).parent.name if path else "a dependency"


def _internal_error(args: argparse.Namespace, exc: BaseException) -> int:
    if getattr(args, "verbose", False):
        log.exception("internal error")
    first = str(exc).splitlines()[0] if str(exc) else ""
    print(f"pointcvx: internal error: {type(exc).__name__}: {first} (rerun with -v for details)",
          file=sys.stderr)
    return EXIT_INTERNAL


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
