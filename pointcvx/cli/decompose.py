"""``pointcvx decompose``: split a shape into convex hulls and write them."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..errors import InputError, OutputError
from ..export import EXTENSIONS, FORMATS
from ..flags import add_flags, options_from_args
from ..options import DECOMPOSE_POINTS, DecomposeOptions, LoadOptions
from ..progress import StageBars


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "decompose",
        help="split a shape into convex hulls",
        description="Decompose INPUT (any format `pointcvx info` reads) into convex hulls: "
        "convex-aware features, then recursive splitting of the most concave part until every "
        "part's concavity is under --threshold or --max-hulls hulls exist, then a merge pass. "
        "Writes the hulls in the input's units (an OBJ with one object per hull by default; STL, "
        "GLB/GLTF, URDF, MJCF, USD or a JSON report with --format or by OUT's suffix), optionally "
        "within an engine's per-hull caps (--target), and prints hulls, concavity and time.",
    )
    p.add_argument("input", help="mesh, CAD part, Gaussian splat or scan")
    p.add_argument("-o", "--output", metavar="OUT",
                   help="OUT.obj (one 'o' per hull), OUT.stl/DIR for one file per hull, OUT.glb/"
                        "OUT.gltf (a node per hull), OUT.urdf or OUT.xml/OUT.mjcf (folder OUT/ "
                        "with the robot file and an OBJ per hull), OUT.usda/OUT.usd (USD rigid "
                        "body, a collider per hull), OUT.json (report) "
                        "(default: ./INPUT_STEM_hulls.obj)")
    p.add_argument("--format", choices=list(FORMATS), default=None,
                   help="output format (default: from OUT's suffix)")
    add_flags(p, DecomposeOptions)
    p.add_argument("--per-hull", action="store_true", help="write one file per hull")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar, no summary")
    p.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    add_flags(p, LoadOptions, defaults={"n_points": DECOMPOSE_POINTS})
    p.set_defaults(func=run)
    return p


def default_output(input_path: str, format: str | None = None) -> Path:
    """``./INPUT_STEM_hulls.EXT`` in the current folder."""
    return Path.cwd() / f"{Path(input_path).stem}_hulls{EXTENSIONS[format or 'obj']}"


def check_output(out: Path, fmt: str, per_hull: bool, input_path: str, overwrite: bool) -> None:
    """Refuse before the (slow) decomposition what the export would refuse after it."""
    from ..export import main_file, output_folder
    from ..io.files import check_writable

    main = main_file(out, fmt, per_hull)
    if main is None or fmt in ("urdf", "mjcf"):  # a folder, made if missing
        folder = output_folder(out, fmt)
        if folder.exists() and not folder.is_dir():
            raise OutputError(f"{folder}: exists and is not a directory")
        first = main if main is not None else folder / f"hull_000{EXTENSIONS[fmt]}"
        if first.exists() and not overwrite:
            raise OutputError(f"{first}: exists; pass --overwrite to replace it")
        return
    check_writable(main, [input_path], overwrite)


def summary_line(summary: dict, limits) -> str:
    """The line printed at the end: hulls, concavity, time, features, caps, output."""
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
    return f"{line} -> {summary['output']}"


def run(args: argparse.Namespace) -> int:
    from ..decomposition.limits import hull_limits
    from ..export import format_for, main_file
    from ..pipeline import decompose

    dec = options_from_args(args, DecomposeOptions)
    load = options_from_args(args, LoadOptions)
    out = Path(args.output) if args.output else default_output(args.input, args.format)
    fmt = format_for(out, args.format)
    per_hull = args.per_hull or main_file(out, fmt) is None
    if per_hull and fmt not in ("obj", "stl"):
        raise InputError(f"--per-hull applies to obj and stl outputs, not {fmt}")
    limits = hull_limits(dec.target, dec.max_hull_vertices)
    check_output(out, fmt, per_hull, args.input, args.overwrite)
    bars = StageBars(not args.quiet)
    try:
        result = decompose(args.input, progress=bars, **dec.as_dict(), **load.as_dict())
    finally:
        bars.close()
    written = result.export(out, fmt, overwrite=args.overwrite, per_hull=per_hull)
    if args.quiet:
        return 0
    summary = result.summary()
    summary["format"] = fmt
    summary["output"] = str(written[0].parent / f"hull_*{EXTENSIONS[fmt]}" if per_hull else written[0])
    summary["files"] = len(written)
    if result.params.get("hull_limits"):
        summary["hull_limits"] = result.params["hull_limits"]
    summary["features"] = result.params.get("features")
    summary["timings"] = {k: round(v, 3) for k, v in result.timings.items()}
    print(json.dumps(summary, indent=2) if args.json else summary_line(summary, limits))
    return 0
