"""The settings of one batch: every asset's decomposition and loading options, its output format
and its limits, as one frozen value that travels to the workers."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ...errors import InputError
from ...io.files import file_digest
from ...model.weights import bundled_model_path, check_model
from ...options import DECOMPOSE_POINTS, DecomposeOptions, LoadOptions, split_kwargs


@dataclass(frozen=True)
class BatchOptions:
    """Settings of one batch.

    Attributes
    ----------
    decompose : DecomposeOptions
        :func:`pointcvx.decompose`'s settings for every asset.
    load : LoadOptions
        Loader settings; ``load.seed`` is the batch seed: each asset runs with
        :func:`~pointcvx.apps.batch.assets.asset_seed` of it. ``n_points`` defaults to
        :data:`pointcvx.options.DECOMPOSE_POINTS`, as ``pointcvx decompose``.
    format : str
        Output format per asset, one of :data:`pointcvx.export.FORMATS` (default ``obj``).
    timeout : float
        Wall-clock seconds allowed to one asset.
    max_memory_mb : float, optional
        Resident memory (MB) a worker may reach while running an asset (it includes the worker's
        own libraries and model); default: :data:`~pointcvx.apps.batch.guard.MEMORY_SHARE` of the machine's
        memory divided by its workers. 0 turns the guard off.
    threads : int
        Threads of each worker (BLAS, torch). Fixed, not derived from the worker count, so that
        results do not depend on it.

    ``BatchOptions.create(features="model", n_points=3000, timeout=60)`` takes every option by
    name.
    """

    decompose: DecomposeOptions = field(default_factory=DecomposeOptions)
    load: LoadOptions = field(default_factory=lambda: LoadOptions(n_points=DECOMPOSE_POINTS))
    format: str = "obj"
    timeout: float = 600.0
    max_memory_mb: float | None = None
    threads: int = 1

    @classmethod
    def create(cls, *, format: str = "obj", timeout: float = 600.0, max_memory_mb: float | None = None,
               threads: int = 1, **options: Any) -> BatchOptions:
        """Build from decomposition and loading options given by name (see :mod:`pointcvx.options`)."""
        dec, load = split_kwargs(options)
        load.setdefault("n_points", DECOMPOSE_POINTS)
        return cls(DecomposeOptions(**dec), LoadOptions(**load), format, timeout, max_memory_mb, threads)

    def replace(self, **changes: Any) -> BatchOptions:
        """A copy with batch settings or options (by name) changed."""
        own = {k: changes.pop(k) for k in ("format", "timeout", "max_memory_mb", "threads") if k in changes}
        dec, load = split_kwargs(changes)
        return dataclasses.replace(self, decompose=dataclasses.replace(self.decompose, **dec),
                                   load=dataclasses.replace(self.load, **load), **own)

    @property
    def seed(self) -> int:
        return self.load.seed

    def to_dict(self) -> dict:
        """Plain values (what is sent to a worker process); :meth:`from_dict` reads it back."""
        return {"decompose": self.decompose.as_dict(), "load": self.load.as_dict(), "format": self.format,
                "timeout": self.timeout, "max_memory_mb": self.max_memory_mb, "threads": self.threads}

    @classmethod
    def from_dict(cls, d: dict) -> BatchOptions:
        return cls(DecomposeOptions(**d["decompose"]), LoadOptions(**d["load"]), d["format"],
                   d["timeout"], d["max_memory_mb"], d["threads"])

    def check(self) -> None:
        """Raise :class:`InputError` on any unusable setting (before any worker starts); the
        decomposition and loading options were checked when they were made."""
        from ...decomposition.limits import hull_limits
        from ...export import FORMATS

        if self.format not in FORMATS:
            raise InputError(f"unknown output format {self.format!r}; expected one of {', '.join(FORMATS)}")
        if int(self.threads) < 1:
            raise InputError(f"threads must be at least 1, got {self.threads}")
        if not (self.timeout > 0 and math.isfinite(self.timeout)):
            raise InputError(f"timeout must be positive, got {self.timeout}")
        if self.max_memory_mb is not None and not (self.max_memory_mb >= 0):
            raise InputError(f"max memory must be positive (0: no limit), got {self.max_memory_mb}")
        hull_limits(self.decompose.target, self.decompose.max_hull_vertices)
        check_model(self.decompose.features, self.decompose.model)

    def decompose_kwargs(self, seed: int) -> dict:
        """Keyword arguments of :func:`pointcvx.decompose` for an asset with ``seed``."""
        return {**self.decompose.as_dict(), **self.load.as_dict(), "seed": int(seed)}

    def fingerprint(self) -> str:
        """16 hex digits naming the settings that change an asset's output (not the engine,
        workers, limits): a ``done`` asset with another fingerprint is done again. The model's
        content is part of it."""
        keys = {"format": self.format, "decompose": self.decompose.changed(), "load": self.load.changed()}
        keys["decompose"].pop("model", None)
        if self.decompose.features in ("model", "auto"):  # "auto" uses the model on splats
            path = Path(self.decompose.model) if self.decompose.model is not None else bundled_model_path()
            keys["model"] = file_digest(path) if path is not None and path.is_file() else str(path)
        text = json.dumps(keys, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]
