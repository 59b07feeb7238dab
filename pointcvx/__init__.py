"""pointcvx: approximate convex decomposition of splats, scans, meshes and CAD parts.

The pipeline, one module each: load (:mod:`pointcvx.io`) -> oriented cloud
(:mod:`pointcvx.cloud`) -> solid (:mod:`pointcvx.solid`, :mod:`pointcvx.watertight`) -> features
(:mod:`pointcvx.features`) -> recursive decomposition (:mod:`pointcvx.recursive`) -> hulls and
export (:mod:`pointcvx.result`); :func:`decompose` (:mod:`pointcvx.pipeline`) runs it all.
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
from .io import LoadOptions, detect, load
from .pipeline import decompose
from .result import ConvexHull, Decomposition
from .syslibs import preload_libusb

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())

# open3d is imported lazily everywhere; make its libusb loadable first (see pointcvx.syslibs),
# for pointcvx's own imports and for a user's ``import open3d`` after ``import pointcvx``.
preload_libusb()

__all__ = [
    "ConvexHull",
    "Decomposition",
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
