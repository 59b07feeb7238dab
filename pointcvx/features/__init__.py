"""Convex-aware features: points -> (n, k) unit vectors, close for points that form convex pairs.

Two sources implement :class:`FeatureSource`: a field optimised per shape
(:func:`pointcvx.features.field.optimize_field`) and the feed-forward model.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from .loss import info_nce
from .pairs import Triplets, sample_triplets


@runtime_checkable
class FeatureSource(Protocol):
    """Anything that maps (n, 3) points of the normalised frame to (n, dim) unit features."""

    name: str

    @property
    def dim(self) -> int: ...

    def features(self, points: np.ndarray) -> np.ndarray: ...


__all__ = ["FeatureSource", "Triplets", "info_nce", "sample_triplets"]
