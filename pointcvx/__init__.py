"""pointcvx: approximate convex decomposition of splats, scans, meshes and CAD parts.

The pipeline, a package or module each: load (:mod:`pointcvx.io`) -> oriented cloud
(:mod:`pointcvx.cloud`) -> solid (:mod:`pointcvx.solid`) -> features (:mod:`pointcvx.features`,
:mod:`pointcvx.model`) -> decomposition (:mod:`pointcvx.decomposition`) -> hulls
(:mod:`pointcvx.result`) -> export (:mod:`pointcvx.export`); :func:`decompose`
(:mod:`pointcvx.pipeline`) runs it all, with the options of :mod:`pointcvx.options`. On top:
the evaluation protocol (:mod:`pointcvx.evaluate`), batch and bench (:mod:`pointcvx.apps`) and
the command line (:mod:`pointcvx.cli`). This module is the public face only.

The face is lazy (PEP 562): ``import pointcvx`` loads none of the pipeline; the first use of a
name (``pointcvx.decompose``, ``from pointcvx import load``) or of a sub-package
(``pointcvx.io``) imports the module that holds it. So the command line, and any program that
uses one corner of the package, pays only for what it uses.
"""

from __future__ import annotations

import importlib
import logging
from typing import TYPE_CHECKING

from .syslibs import preload_libusb
from .version import __version__

if TYPE_CHECKING:  # what the lazy names are, for type checkers and IDEs
    from .cloud import Normalization, OrientedCloud
    from .errors import (
        InputError,
        MissingExtraError,
        MissingLibraryError,
        OutputError,
        PointcvxError,
        TimeLimitError,
        UnknownFormatError,
    )
    from .io import as_cloud, detect, load
    from .options import DecomposeOptions, LoadOptions
    from .pipeline import decompose
    from .result import ConvexHull, Decomposition

logging.getLogger(__name__).addHandler(logging.NullHandler())

# open3d is imported lazily everywhere; make its libusb loadable first (see pointcvx.syslibs),
# for pointcvx's own imports and for a user's ``import open3d`` after ``import pointcvx``.
preload_libusb()

#: Public name -> the module that defines it, imported on first use.
_PUBLIC = {
    "Normalization": "cloud", "OrientedCloud": "cloud",
    "InputError": "errors", "MissingExtraError": "errors", "MissingLibraryError": "errors",
    "OutputError": "errors", "PointcvxError": "errors", "TimeLimitError": "errors",
    "UnknownFormatError": "errors",
    "as_cloud": "io", "detect": "io", "load": "io",
    "DecomposeOptions": "options", "LoadOptions": "options",
    "decompose": "pipeline",
    "ConvexHull": "result", "Decomposition": "result",
}

#: Sub-packages and modules reachable as attributes (``pointcvx.io.from_numpy``) without an
#: import of their own.
_SUBMODULES = frozenset({
    "apps", "cli", "cloud", "deadline", "decomposition", "embree", "errors", "evaluate", "export",
    "features", "flags", "io", "model", "options", "pipeline", "progress", "result", "scene",
    "solid", "syslibs", "training", "version", "view", "workers",
})


def __getattr__(name: str):
    """Import what ``name`` refers to on first use, and keep it as a module attribute."""
    if name in _PUBLIC:
        value = getattr(importlib.import_module(f".{_PUBLIC[name]}", __name__), name)
    elif name in _SUBMODULES:
        value = importlib.import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC) | _SUBMODULES)


__all__ = [
    "ConvexHull",
    "DecomposeOptions",
    "Decomposition",
    "as_cloud",
    "decompose",
    "InputError",
    "LoadOptions",
    "MissingExtraError",
    "MissingLibraryError",
    "Normalization",
    "OrientedCloud",
    "OutputError",
    "PointcvxError",
    "TimeLimitError",
    "UnknownFormatError",
    "detect",
    "load",
    "__version__",
]
