"""Configuration of the feed-forward feature network and its training, as plain data.

A :class:`ModelConfig` is a tree of small dataclasses (``encoder``, ``planes``, ``transformer``,
``head``, ``train``) that round-trips through JSON (:meth:`ModelConfig.to_dict` /
:meth:`ModelConfig.from_dict`) and takes command-line style overrides
(:meth:`ModelConfig.with_overrides`). Two presets: ``small`` (a few million parameters, CPU
friendly) and ``paper`` (the release architecture, about 106 M parameters).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from typing import Any

#: Axes of the three planes, as (width axis, height axis) of the (P, P) images: xy, xz, yz.
PLANE_AXES = ((0, 1), (0, 2), (1, 2))


def _context_lines() -> tuple[tuple[tuple[int, int, bool], ...], ...]:
    """For each plane k, the lines the other two planes give it (the network's
    ``cross_plane_context``): (j, the axis of plane j's (c, H, W) image it is averaged over,
    -2 or -1; whether the line runs along plane k's W axis, i.e. is the same for every row).
    Each plane shares one axis with each other plane; axes[0] runs along W, axes[1] along H."""
    out = []
    for k, axes_k in enumerate(PLANE_AXES):
        lines = []
        for j, axes_j in enumerate(PLANE_AXES):
            if j != k:
                (shared,) = set(axes_k) & set(axes_j)
                lines.append((j, -2 if axes_j[0] == shared else -1, axes_k[0] == shared))
        out.append(tuple(lines))
    return tuple(out)


#: :func:`_context_lines`, shared by the torch network and its numpy inference.
CONTEXT_LINES = _context_lines()


@dataclass
class EncoderConfig:
    """PVCNN-style point encoder: a shared MLP on (xyz, normal), then voxel blocks.

    Attributes
    ----------
    point_channels : width of the per-point MLP.
    voxel_resolutions : grid resolution of each point-voxel block.
    voxel_channels : output channels of each point-voxel block.
    """

    point_channels: int = 64
    voxel_resolutions: tuple[int, ...] = (16, 8)
    voxel_channels: tuple[int, ...] = (64, 64)


@dataclass
class PlaneConfig:
    """Triplane scatter and the 2D CNN that shrinks it to transformer tokens.

    Attributes
    ----------
    resolution : side P of the three P x P planes.
    channels : channels of the scattered planes.
    down_channels : output channels of each conv + max-pool (factor 2) stage.
    aware_layers : 3D-aware residual conv blocks at full resolution before the down stages.
    """

    resolution: int = 64
    channels: int = 64
    down_channels: tuple[int, ...] = (128, 192)
    aware_layers: int = 1


@dataclass
class TransformerConfig:
    """ViT over the 3 (P / 2**stages)^2 plane tokens."""

    layers: int = 3
    width: int = 192
    heads: int = 6
    mlp_ratio: float = 4.0
    dropout: float = 0.0


@dataclass
class HeadConfig:
    """Output planes (sdf_channels + feature_dim channels) and the SDF MLP.

    Attributes
    ----------
    feature_dim : channels that form the (unit-normalised) convexity feature.
    sdf_channels : channels read by the SDF head.
    sdf_hidden : hidden width of the SDF MLP.
    residual_hidden : hidden width of the per-pixel MLP residual on the scattered planes.
    """

    feature_dim: int = 48
    sdf_channels: int = 16
    sdf_hidden: int = 32
    residual_hidden: int = 64


@dataclass
class TrainConfig:
    """Optimisation settings (release: Adam, lr 1e-5, cosine, batch 2 per GPU)."""

    lr: float = 1e-4
    weight_decay: float = 0.0
    warmup_steps: int = 0
    min_lr_ratio: float = 0.0
    batch_size: int = 2
    tau: float = 1.0
    sdf_weight: float = 1.0
    sdf_clip: float = 0.05
    grad_clip: float = 0.0
    amp: bool = False
    checkpoint_every: int = 1000
    log_every: int = 1
    seed: int = 0


_SECTIONS = {
    "encoder": EncoderConfig,
    "planes": PlaneConfig,
    "transformer": TransformerConfig,
    "head": HeadConfig,
    "train": TrainConfig,
}


@dataclass
class ModelConfig:
    """The whole network + training configuration (see the module docstring)."""

    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    planes: PlaneConfig = field(default_factory=PlaneConfig)
    transformer: TransformerConfig = field(default_factory=TransformerConfig)
    head: HeadConfig = field(default_factory=HeadConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    name: str = "custom"

    # ---------------------------------------------------------------- serialisation
    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible dict (tuples become lists)."""
        return json.loads(json.dumps(dataclasses.asdict(self)))

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ModelConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise ``KeyError``."""
        kwargs: dict[str, Any] = {}
        for key, value in d.items():
            if key == "name":
                kwargs[key] = str(value)
            elif key in _SECTIONS:
                kwargs[key] = _section_from_dict(_SECTIONS[key], value)
            else:
                raise KeyError(f"unknown config section {key!r}")
        return cls(**kwargs)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> ModelConfig:
        return cls.from_dict(json.loads(text))

    # ---------------------------------------------------------------- overrides
    def with_overrides(self, overrides: list[str] | dict[str, Any]) -> ModelConfig:
        """A copy with ``["transformer.layers=2", "lr=3e-4", ...]`` (or a dict) applied.

        Keys are ``section.field`` or a bare ``field`` that is unique across sections; values
        are parsed as JSON when possible (``2``, ``3e-4``, ``[32,16]``, ``true``), otherwise
        kept as strings. Sequence fields also accept ``32,16``.
        """
        items = overrides.items() if isinstance(overrides, dict) else (_split(o) for o in overrides)
        d = self.to_dict()
        for key, value in items:
            section, name = self._resolve(key)
            current = d[section][name] if section else d[name]
            value = _parse(value, current)
            if section:
                d[section][name] = value
            else:
                d[name] = value
        return ModelConfig.from_dict(d)

    def _resolve(self, key: str) -> tuple[str | None, str]:
        if key == "name":
            return None, key
        if "." in key:
            section, name = key.split(".", 1)
            if section not in _SECTIONS or name not in _field_names(_SECTIONS[section]):
                raise KeyError(f"unknown config key {key!r}")
            return section, name
        hits = [s for s, c in _SECTIONS.items() if key in _field_names(c)]
        if len(hits) != 1:
            raise KeyError(f"config key {key!r} is {'ambiguous' if hits else 'unknown'}: "
                           f"use section.{key}")
        return hits[0], key

    # ---------------------------------------------------------------- presets
    @classmethod
    def preset(cls, name: str) -> ModelConfig:
        """``"small"``, ``"paper"`` or ``"tiny"`` (tests only)."""
        try:
            return PRESETS[name]()
        except KeyError:
            raise KeyError(f"unknown preset {name!r}; choose from {sorted(PRESETS)}") from None


def _field_names(cls) -> set[str]:
    return {f.name for f in dataclasses.fields(cls)}


def _section_from_dict(cls, d: dict[str, Any]):
    names = _field_names(cls)
    unknown = set(d) - names
    if unknown:
        raise KeyError(f"unknown {cls.__name__} keys {sorted(unknown)}")
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name in d:
            v = d[f.name]
            kwargs[f.name] = tuple(v) if isinstance(v, (list, tuple)) else v
    return cls(**kwargs)


def _split(item: str) -> tuple[str, str]:
    if "=" not in item:
        raise ValueError(f"override {item!r} is not key=value")
    key, value = item.split("=", 1)
    return key.strip(), value.strip()


def _parse(value: Any, current: Any) -> Any:
    if isinstance(value, str):
        try:
            value = json.loads(value)
        except json.JSONDecodeError:
            if isinstance(current, list):
                value = [json.loads(v) for v in value.split(",") if v.strip()]
    if isinstance(current, list) and not isinstance(value, (list, tuple)):
        value = [value]
    if isinstance(current, float) and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    return list(value) if isinstance(value, tuple) else value


def small() -> ModelConfig:
    """About 4 M parameters; encodes 20 k points in well under a second on a CPU."""
    return ModelConfig(
        encoder=EncoderConfig(point_channels=48, voxel_resolutions=(16, 8), voxel_channels=(32, 64)),
        planes=PlaneConfig(resolution=64, channels=48, down_channels=(96, 192, 256), aware_layers=1),
        transformer=TransformerConfig(layers=4, width=256, heads=8, mlp_ratio=4.0),
        head=HeadConfig(feature_dim=48, sdf_channels=16, sdf_hidden=32, residual_hidden=64),
        name="small",
    )


def paper() -> ModelConfig:
    """The release architecture (PartField-style), about 106 M parameters."""
    return ModelConfig(
        encoder=EncoderConfig(point_channels=128, voxel_resolutions=(32, 16, 8),
                              voxel_channels=(256, 128, 256)),
        planes=PlaneConfig(resolution=128, channels=256, down_channels=(512, 1024), aware_layers=4),
        transformer=TransformerConfig(layers=6, width=1024, heads=8, mlp_ratio=4.0),
        head=HeadConfig(feature_dim=448, sdf_channels=64, sdf_hidden=64, residual_hidden=512),
        train=TrainConfig(lr=1e-5, batch_size=2),
        name="paper",
    )


def tiny() -> ModelConfig:
    """A toy network for unit tests (a few tens of thousands of parameters)."""
    return ModelConfig(
        encoder=EncoderConfig(point_channels=16, voxel_resolutions=(8,), voxel_channels=(16,)),
        planes=PlaneConfig(resolution=16, channels=16, down_channels=(32,), aware_layers=1),
        transformer=TransformerConfig(layers=1, width=32, heads=2, mlp_ratio=2.0),
        head=HeadConfig(feature_dim=16, sdf_channels=4, sdf_hidden=16, residual_hidden=16),
        train=TrainConfig(lr=3e-3, batch_size=2, tau=0.3),
        name="tiny",
    )


PRESETS = {"small": small, "paper": paper, "tiny": tiny}
