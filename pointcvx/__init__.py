"""pointcvx: approximate convex decomposition of splats, scans, meshes and CAD parts.

The pipeline, a package or module each: load (:mod:`pointcvx.io`) -> oriented cloud
(:mod:`pointcvx.cloud`) -> solid (:mod:`pointcvx.solid`) -> features (:mod:`pointcvx.features`,
:mod:`pointcvx.model`) -> decomposition (:mod:`pointcvx.decomposition`) -> hulls
(:mod:`pointcvx.result`) -> export (:mod:`pointcvx.export`); :func:`decompose`
(:mod:`pointcvx.pipeline`) runs it all, with the options of :mod:`pointcvx.options`. On top:
the evaluation protocol (:mod:`pointcvx.evaluate`), batch and bench (:mod:`pointcvx.apps`) and
the command line (:mod:`pointcvx.cli`). This module is the public face only.
"""

from __future__ import annotations

import logging

from .cloud import Normalization, OrientedCloud
from .errors import (
    InputError,
    MissingExtraError,
    MissingLibraryError,
    OutputError,
    PointcvxError,
    UnknownFormatError,
)
from .io import as_cloud, detect, load
from .options import DecomposeOptions, LoadOptions
from .pipeline import decompose
from .result import ConvexHull, Decomposition
from .syslibs import preload_libusb
from .version import __version__

logging.getLogger(__name__).addHandler(logging.NullHandler())

# open3d is imported lazily everywhere; make its libusb loadable first (see pointcvx.syslibs),
# for pointcvx's own imports and for a user's ``import open3d`` after ``import pointcvx``.
preload_libusb()

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
    "UnknownFormatError",
    "detect",
    "load",
    "__version__",
]
