"""``pointcvx view``: a look at an input and its hulls, as an offline HTML page and a PNG."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..flags import add_flags, options_from_args
from ..options import LoadOptions
from .choices import LazyChoices

#: Points loaded (meshes: sampled) for a view unless -n says otherwise: what the page draws.
VIEW_POINTS = 50_000


def _size(text: str) -> tuple[int, int]:
    """``WIDTHxHEIGHT`` -> (width, height)."""
    try:
        w, h = (int(s) for s in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, e.g. 960x720, got {text!r}") from None
    if not (16 <= w <= 8000 and 16 <= h <= 8000):
        raise argparse.ArgumentTypeError(f"width and height must be 16 to 8000 pixels, got {text!r}")
    return w, h


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "view",
        help="look at an input and its hulls (offline HTML page and PNG)",
        description="Write a self-contained HTML page (no network: the viewer is inside it) "
        "showing INPUT's points (at most 50,000, their own colours where the input has them) "
        "and, with HULLS (an OBJ with one 'o' per hull, as `pointcvx decompose` writes, or any "
        "mesh file whose connected components are the hulls), the hulls translucent, one colour "
        "each; drag to orbit, wheel to zoom. A PNG of the same scene from a fixed 3/4 view is "
        "written beside the page.",
    )
    p.add_argument("input", help="any file `pointcvx info` reads (mesh, CAD part, splat, scan)")
    p.add_argument("hulls", nargs="?", help="the hulls, in INPUT's units (default: none)")
    p.add_argument("-o", "--output", metavar="OUT.html",
                   help="the page (default: ./INPUT_STEM_view.html); OUT.png writes only the picture")
    png = p.add_mutually_exclusive_group()
    png.add_argument("--png", metavar="FILE", help="write the picture here (default: OUT with .png)")
    png.add_argument("--no-png", action="store_true", help="write the page only")
    p.add_argument("--size", type=_size, default=(960, 720), metavar="WxH",
                   help="picture size in pixels (default 960x720)")
    p.add_argument("--up", choices=LazyChoices("pointcvx.view.drawing", "UP_AXES"), default=None,
                   metavar="AXIS", help="the axis that points up: %(choices)s (default: as detected, "
                   "else z; a negative one as --up=-y)")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    p.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    add_flags(p, LoadOptions, defaults={"n_points": VIEW_POINTS})
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from ..evaluate import load_hulls
    from ..io import load
    from ..io.files import check_writable
    from ..view import view_outputs, write_view

    out = Path(args.output) if args.output else Path.cwd() / f"{Path(args.input).stem}_view.html"
    png = False if args.no_png else (args.png or True)
    inputs = [args.input] + ([args.hulls] if args.hulls else [])
    for target in view_outputs(out, png):
        if target is not None:
            check_writable(target, inputs, args.overwrite)
    hulls = load_hulls(args.hulls) if args.hulls else None
    cloud = load(args.input, options_from_args(args, LoadOptions))
    legend = {"hulls_file": Path(args.hulls).name} if args.hulls else {}
    written = write_view(out, cloud, hulls, png=png, size=args.size, overwrite=args.overwrite,
                         up=args.up, legend=legend, seed=args.seed)
    if not args.quiet:
        what = f"{len(cloud):,} points" + (f", {len(hulls)} hulls" if hulls is not None else "")
        print(f"{what} -> {', '.join(str(w) for w in written)}")
    return 0
