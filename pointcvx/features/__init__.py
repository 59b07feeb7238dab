"""Convex-aware features: points -> (n, k) unit vectors, close for points that form convex pairs.

Two kinds of source implement :class:`FeatureSource`: a field fitted to the shape's own convex
pairs (:func:`pointcvx.features.field.fit_field`, numpy: ``features="optimize"`` and, in fewer
steps, ``"fast"``) and the feed-forward model (:mod:`pointcvx.model`, torch).
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
    """``info_nce`` (torch) on first use: the per-shape field (:mod:`pointcvx.features.field`) and the
    triplet sampler do not need torch, which costs a process about 1.7 s to import."""
    if name == "info_nce":
        from .loss import info_nce

        return info_nce
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["FeatureSource", "Triplets", "info_nce", "sample_triplets"]
