"""Settings of one benchmark: which methods run, at which pointcvx thresholds, with which limits
(:class:`BenchOptions`)."""

from __future__ import annotations

import dataclasses
import importlib.util
import math
from dataclasses import dataclass, field
from typing import Any

from ...errors import InputError
from ...model.weights import check_model
from ...options import DECOMPOSE_POINTS, DecomposeOptions, LoadOptions, split_kwargs

METHODS = ("pointcvx", "coacd", "vhacd", "vhacdx")
"""Every method name ``--methods`` accepts."""
BASELINES = ("coacd", "vhacd", "vhacdx")
"""The methods pointcvx is compared with."""
PACKAGES = {"coacd": "coacd", "vhacd": "pybullet", "vhacdx": "vhacdx"}
"""The package each baseline needs (``pip install 'pointcvx[baselines]'``)."""


@dataclass(frozen=True)
class BenchOptions:
    """Settings of one benchmark.

    Attributes
    ----------
    methods : tuple of str
        Among :data:`METHODS`.
    thresholds : tuple of float
        pointcvx concavity thresholds; matched baselines follow each.
    match : bool
        Also run the baselines at matched granularity.
    timeout : float
        Wall-clock seconds allowed to each run (each search probe included).
    decompose, load : DecomposeOptions, LoadOptions
        pointcvx's settings (its threshold comes from ``thresholds``); ``load.seed`` also seeds
        CoACD and the evaluation.
    eval_samples : int
        Surface samples of :func:`pointcvx.evaluate.evaluate` (the paper's protocol); five times
        as many volume samples for the IoU.
    vhacd_resolution : int, optional
        Voxel resolution of both V-HACD flavours (default: :data:`~.methods.VHACD_RESOLUTION`
        for pybullet, :data:`~.methods.VHACDX_RESOLUTION` for vhacdx).
    search_runs : int
        Probes of a matched-granularity search.
    threads : int, optional
        Threads of pointcvx's worker (default: all; set when several shapes run at once).
    oneshot : bool
        Also time every fixed-setting run as a one-shot process, the way a user runs the method
        on one file (:mod:`.oneshot`).

    ``BenchOptions.create(methods=("pointcvx",), features="model", n_points=3000)`` takes the
    decomposition and loading options by name.
    """

    methods: tuple[str, ...] = ("pointcvx", "coacd", "vhacd")
    thresholds: tuple[float, ...] = (0.1,)
    match: bool = True
    timeout: float = 600.0
    decompose: DecomposeOptions = field(default_factory=DecomposeOptions)
    load: LoadOptions = field(default_factory=lambda: LoadOptions(n_points=DECOMPOSE_POINTS))
    eval_samples: int = 20000
    vhacd_resolution: int | None = None
    search_runs: int = 6
    threads: int | None = None
    oneshot: bool = True

    @classmethod
    def create(cls, **kwargs: Any) -> BenchOptions:
        """Build from bench settings and decomposition/loading options given by name."""
        own = {f.name for f in dataclasses.fields(cls)} - {"decompose", "load"}
        mine = {k: kwargs.pop(k) for k in list(kwargs) if k in own}
        dec, load = split_kwargs(kwargs)
        load.setdefault("n_points", DECOMPOSE_POINTS)
        return cls(decompose=DecomposeOptions(**dec), load=LoadOptions(**load), **mine)

    @property
    def seed(self) -> int:
        return self.load.seed

    def to_dict(self) -> dict:
        """Plain values (what a pool process receives); :meth:`from_dict` reads it back."""
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        d["decompose"], d["load"] = self.decompose.as_dict(), self.load.as_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> BenchOptions:
        d = dict(d)
        d["decompose"], d["load"] = DecomposeOptions(**d["decompose"]), LoadOptions(**d["load"])
        d["methods"], d["thresholds"] = tuple(d["methods"]), tuple(d["thresholds"])
        return cls(**d)

    def check(self) -> None:
        """Raise :class:`InputError` on any unusable setting (the decomposition and loading
        options were checked when they were made)."""
        if not self.methods:
            raise InputError("no method to run: pass --methods, e.g. pointcvx,coacd,vhacd")
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown:
            raise InputError(f"unknown method {unknown[0]!r}; expected some of {', '.join(METHODS)}")
        for m in self.methods:
            if m in PACKAGES and importlib.util.find_spec(PACKAGES[m]) is None:
                raise InputError(f"method {m!r} needs the package '{PACKAGES[m]}': "
                                 "pip install 'pointcvx[baselines]'")
        if not self.thresholds or not all(t > 0 and math.isfinite(t) for t in self.thresholds):
            raise InputError(f"thresholds must be positive, got {list(self.thresholds)}")
        if not self.timeout > 0:
            raise InputError(f"timeout must be positive, got {self.timeout}")
        if "pointcvx" in self.methods:
            check_model(self.decompose.features, self.decompose.model)
            if self.oneshot:  # the one-shot run is `pointcvx decompose`: can its flags say all?
                from .oneshot import decompose_flags

                decompose_flags({**self.decompose.as_dict(), **self.load.as_dict()})
        for name in ("eval_samples", "search_runs"):
            if getattr(self, name) < 1:
                raise InputError(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.vhacd_resolution is not None and self.vhacd_resolution < 1:
            raise InputError(f"vhacd resolution must be positive, got {self.vhacd_resolution}")

    @property
    def baselines(self) -> list[str]:
        return [m for m in self.methods if m in BASELINES]
