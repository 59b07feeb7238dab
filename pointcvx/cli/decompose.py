"""``pointcvx decompose``: split a shape into convex hulls and write them."""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys
from pathlib import Path

from ..deadline import watchdog
from ..errors import EXIT_INPUT, InputError
from ..flags import add_flags, options_from_args
from ..options import DECOMPOSE_POINTS, DecomposeOptions, LoadOptions
from ..progress import StageBars
from .choices import LazyChoices


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
                   help="OUT.obj (one 'o' per hull), DIR (new or empty) or OUT.stl (folder "
                        "OUT_stl/) for one file per hull, OUT.glb/OUT.gltf (a node per hull), "
                        "OUT.urdf or OUT.xml/OUT.mjcf (folder OUT_urdf/ or OUT_mjcf/ with the robot "
                        "file and an OBJ per hull), OUT.usda/OUT.usd (USD rigid body, a collider "
                        "per hull), OUT.json (report) (default: ./INPUT_STEM_hulls.obj)")
    p.add_argument("--format", choices=LazyChoices("pointcvx.export", "FORMATS"), default=None,
                   metavar="FORMAT", help="output format: %(choices)s (default: from OUT's suffix)")
    add_flags(p, DecomposeOptions)
    p.add_argument("--per-hull", action="store_true", help="write one file per hull")
    p.add_argument("--up", default="auto", choices=("auto", "x", "y", "z", "-x", "-y", "-z"),
                   metavar="AXIS", help="the input's up axis for URDF, MJCF and USD, turned to +z there "
                   "(hull coordinates stay in the input's frame): x, y, z, -x, -y, -z, or auto (the "
                   "support plane that isolation found, else z)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing output (a folder output whole; files pointcvx did not "
                        "write are never deleted)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--preview", metavar="FILE.html",
                   help="also write a look at the result: an offline HTML page and FILE.png beside it")
    p.add_argument("-q", "--quiet", action="store_true",
                   help="no progress bar, no summary (with --json the JSON report still)")
    p.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    add_flags(p, LoadOptions, defaults={"n_points": DECOMPOSE_POINTS})
    p.set_defaults(func=run)
    return p


def default_output(input_path: str, format: str | None = None) -> Path:
    """``./INPUT_STEM_hulls.EXT`` in the current folder."""
    from ..export import EXTENSIONS

    return Path.cwd() / f"{Path(input_path).stem}_hulls{EXTENSIONS[format or 'obj']}"


def check_output(out: Path, fmt: str, per_hull: bool, input_path: str, overwrite: bool) -> None:
    """Refuse before the (slow) decomposition what the export would refuse after it."""
    from ..export import main_file, output_folder
    from ..io.files import check_writable
    from ..io.outputs import check_folder

    folder = output_folder(out, fmt, per_hull)
    if folder is not None:  # a folder of its own, replaced whole
        check_folder(folder, overwrite, protect=[input_path], flag="--overwrite")
        return
    check_writable(main_file(out, fmt, per_hull), [input_path], overwrite)


def summary_line(summary: dict, limits) -> str:
    """The line printed at the end: hulls, concavity, time, features, caps, output."""
    line = (f"{summary['hulls']} hulls, max concavity {summary['max_concavity']:.4f}, "
            f"{summary['seconds']:.2f} s, {summary['features']} features")
    if summary.get("objects"):
        line += f", a scene of {summary['objects']} objects"
    removed = {k: v for k, v in (summary.get("removed") or {}).items() if v}
    if removed:
        line += "; removed " + ", ".join(f"{n} {why.rstrip('s')} points" for why, n in removed.items())
    if summary.get("noise_points"):
        line += f"; {summary['noise_points']} noise points in no hull"
    if summary.get("air_points"):
        line += f"; {summary['air_points']} points of hulls holding no material left out"
    if summary.get("grounded_hulls"):
        line += f"; {summary['grounded_hulls']} hulls reach down to the support plane"
    if summary.get("static_object_names"):
        held = summary["static_object_names"]
        line += (f"; {len(held)} object{'s' if len(held) > 1 else ''} held by what the capture does "
                 f"not show ({', '.join(held)}): static in MJCF and USD")
    if summary.get("resolved_threshold"):
        line += (f"; too sparse to resolve threshold {summary['threshold']:g}, so cut at "
                 + ", ".join(f"{t:.3g} ({name})" for name, t in summary["resolved_threshold"].items()))
    stopped = summary.get("budget_stopped")
    if stopped:
        which = "" if stopped == ["shape"] else f" ({', '.join(stopped)})"
        line += (f"; the {summary['max_hulls']}-hull budget stopped the split above the threshold"
                 f"{which}: raise --max-hulls for less concavity")
    if limits.active:
        caps = ", ".join(f"{what} <= {v}" for what, v in (("vertices", limits.max_vertices),
                                                           ("triangles", limits.max_faces))
                         if v is not None)
        line += (f"; {limits.target or 'limits'} ({caps}): at most {summary['max_hull_vertices']} "
                 f"vertices per hull, added volume {summary['added_volume']:.6g} "
                 f"(+{100 * summary['added_volume_ratio']:.3g}%)")
    elif limits.target:
        line += f"; {limits.target}: no per-hull caps"
    line = f"{line} -> {summary['output']}"
    if summary.get("folder"):
        line += f" ({summary['files']} files in {summary['folder']}{os.sep})"
    return line


def timeout_grace(timeout: float) -> float:
    """Seconds past ``--timeout`` before the watchdog ends the process: the API's own checks
    (after each step) get the first chance to stop cleanly."""
    return min(max(1.0, 0.1 * timeout), 10.0)


def _give_up(timeout: float, bars: bool) -> None:
    """The watchdog's end of a run past ``--timeout``: one line, exit 1; nothing was written
    (outputs are written after the decomposition)."""
    sys.stderr.write(("\n" if bars else "") + f"pointcvx: error: stopped after the time limit "
                     f"of {timeout:g} s; nothing was written\n")
    sys.stderr.flush()
    os._exit(EXIT_INPUT)


def run(args: argparse.Namespace) -> int:
    from ..decomposition.limits import hull_limits
    from ..export import EXTENSIONS, format_for, main_file, output_folder
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
        with watchdog(None if dec.timeout is None else dec.timeout + timeout_grace(dec.timeout),
                      functools.partial(_give_up, dec.timeout, not args.quiet)):
            result = decompose(args.input, progress=bars, **dec.as_dict(), **load.as_dict())
    finally:
        bars.close()
    written = result.export(out, fmt, overwrite=args.overwrite, per_hull=per_hull, up=args.up)
    if args.preview:  # the page and its PNG, after the hulls are safely written
        from ..view import write_view

        write_view(args.preview, result, overwrite=args.overwrite)
    if args.quiet and not args.json:  # --json asks for the report: it is printed even with -q
        return 0
    summary = result.summary()
    summary["format"] = fmt
    folder = output_folder(out, fmt, per_hull)
    main = main_file(out, fmt, per_hull)
    summary["output"] = str(main if main is not None else folder / f"hull_*{EXTENSIONS[fmt]}")
    summary["folder"] = str(folder) if folder is not None else None
    summary["files"] = len(written)
    if result.params.get("hull_limits"):
        summary["hull_limits"] = result.params["hull_limits"]
    summary["features"] = result.params.get("features")
    if result.objects:
        summary["objects"] = len(result.objects)
        summary["static_object_names"] = [o["name"] for o in result.objects if o.get("static")]
    if "isolation" in result.cloud.info:
        summary["removed"] = result.cloud.info["isolation"]["removed"]
    summary["noise_points"] = int(result.cloud.info.get("noise_points", 0))
    summary["air_points"] = int(result.cloud.info.get("air_points", 0))
    summary["grounded_hulls"] = int(result.cloud.info.get("grounded_hulls", 0))
    summary["threshold"] = result.params["threshold"]
    summary["resolved_threshold"] = result.resolved_thresholds
    summary["max_hulls"] = result.params["max_hulls"]
    summary["budget_stopped"] = result.budget_stopped
    summary["timings"] = {k: round(v, 3) for k, v in result.timings.items()}
    print(json.dumps(summary, indent=2) if args.json else summary_line(summary, limits))
    return 0
