"""The ``pointcvx`` command: one module per sub-command; :func:`main` parses and turns every
failure into one line on stderr and an exit status (:mod:`pointcvx.errors`): 1 bad input or
output, 2 bad usage, 3 internal error, 130 interrupted."""

from __future__ import annotations

import argparse
import logging
import os
import sys
import warnings
from pathlib import Path

from ..errors import (
    EXIT_INPUT,
    EXIT_INTERNAL,
    EXIT_INTERRUPT,
    EXIT_USAGE,
    MissingLibraryError,
    PointcvxError,
    first_line,
)
from ..flags import UsageParser
from ..syslibs import install_hint, missing_library
from ..version import __version__

log = logging.getLogger("pointcvx")


def build_parser() -> argparse.ArgumentParser:
    from . import batch, bench, decompose, evaluate, info, train, view

    parser = UsageParser(
        prog="pointcvx",
        description="Approximate convex decomposition of Gaussian splats, scans, meshes and CAD parts.",
        epilog="Exit status: 0 ok, 1 bad input or output, 2 bad usage, 3 internal error.",
    )
    parser.add_argument("--version", action="version", version=f"pointcvx {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=UsageParser)
    info.add_parser(sub)
    decompose.add_parser(sub)
    train.add_parsers(sub)
    evaluate.add_parser(sub)
    bench.add_parser(sub)
    batch.add_parser(sub)
    view.add_parser(sub)
    return parser


#: Sub-commands whose process ends as soon as they return (:func:`console`): they leave no
#: child process or pending file behind, and a one-shot ``pointcvx decompose`` would otherwise
#: spend about 0.1 s in the interpreter's teardown (module finalisers of numpy, scipy, open3d).
FAST_EXIT_COMMANDS = ("decompose", "info")


def console() -> None:
    """The ``pointcvx`` script and ``python -m pointcvx``: :func:`main` on ``sys.argv``, its
    status as the exit status. After a command of :data:`FAST_EXIT_COMMANDS` the output
    streams are flushed and the process exits at once (``os._exit``); every file such a command
    writes is complete and closed before it returns (:mod:`pointcvx.io.outputs`). Not under a
    profiler, tracer or coverage tool (:func:`_observed`): they write their results at exit."""
    code = main()
    command = sys.argv[1] if len(sys.argv) > 1 else None
    if command in FAST_EXIT_COMMANDS and not _observed():
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        except (OSError, ValueError):  # a closed or broken pipe: let the interpreter report it
            sys.exit(code)
        logging.shutdown()
        os._exit(code)
    sys.exit(code)


def _observed() -> bool:
    """Whether a profiler, tracer or monitoring tool (``python -m cProfile``, ``trace``,
    coverage) watches this process: they write their results at the interpreter's exit."""
    if sys.getprofile() is not None or sys.gettrace() is not None:
        return True
    monitoring = getattr(sys, "monitoring", None)  # Python 3.12+: coverage's sys.monitoring core
    return monitoring is not None and any(monitoring.get_tool(i) is not None for i in range(6))


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
    # Libraries' warnings (numpy on overflowing values, torch on its own settings) come with a
    # source line and say nothing a user can act on; pointcvx's own go through logging.
    # With -v they are logged like everything else.
    if getattr(args, "verbose", False):
        logging.captureWarnings(True)
    else:
        warnings.simplefilter("ignore")
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
    print(f"pointcvx: internal error: {type(exc).__name__}: {first_line(exc)} (rerun with -v for details)",
          file=sys.stderr)
    return EXIT_INTERNAL
