"""The feed-forward feature network (triplane transformer) and its training.

- :mod:`.config`: :class:`ModelConfig` with the ``small`` and ``paper`` presets.
- :mod:`.network`: :class:`FeatureNet` (PVCNN encoder -> triplanes -> ViT -> queried features).
- :mod:`.train`: losses, one training step, checkpoints, the (optionally distributed) loop.
- :mod:`.source`: :class:`ModelFeatureSource`, the network as a feature source; :func:`load_model`.
"""

from .config import ModelConfig
from .network import FeatureNet, build_model, count_parameters
from .source import ModelFeatureSource, load_model
from .train import load_checkpoint, save_checkpoint, seed_everything, train, training_step

__all__ = [
    "FeatureNet",
    "ModelConfig",
    "ModelFeatureSource",
    "build_model",
    "count_parameters",
    "load_checkpoint",
    "load_model",
    "save_checkpoint",
    "seed_everything",
    "train",
    "training_step",
]
