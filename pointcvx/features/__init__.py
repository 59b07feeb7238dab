"""Convex-aware features: points -> (n, k) unit vectors, close for points that form convex pairs.

Three sources implement :class:`FeatureSource`: a field optimised per shape
(:func:`pointcvx.features.field.optimize_field`), the same field fitted fast in numpy
(:func:`pointcvx.features.fast.fit_fast_field`, opt-in) and the feed-forward model.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from .pairs import Triplets, sample_triplets


@runtime_checkable
class FeatureSource(Protocol):
    """Anything that maps (n, 3) points of the normalised frame to (n, dim) unit features."""

    name: str

    @property
    def dim(self) -> int: ...

    def features(self, points: np.ndarray) -> np.ndarray: ...


def __getattr__(name: str):
    """``info_nce`` (torch) on first use: the numpy feature source (``features="fast"``) and the
    triplet sampler do not need torch, which costs a process about 1.7 s to import."""
    if name == "info_nce":
        from .loss import info_nce

        return info_nce
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["FeatureSource", "Triplets", "info_nce", "sample_triplets"]
