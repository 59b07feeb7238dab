"""pointcvx: approximate convex decomposition of splats, scans, meshes and CAD parts.

The pipeline, one module each: load (:mod:`pointcvx.io`) -> oriented cloud
(:mod:`pointcvx.cloud`) -> features -> decompose -> hulls -> export.
"""

from __future__ import annotations

import logging

from .cloud import Normalization, OrientedCloud
from .errors import InputError, MissingExtraError, OutputError, PointcvxError, UnknownFormatError
from .io import LoadOptions, detect, load

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())

__all__ = [
    "InputError",
    "LoadOptions",
    "MissingExtraError",
    "Normalization",
    "OrientedCloud",
    "OutputError",
    "PointcvxError",
    "UnknownFormatError",
    "detect",
    "load",
    "__version__",
]
