"""The feed-forward feature network (triplane transformer) and its training.

- :mod:`.config`: :class:`ModelConfig` with the ``small`` and ``paper`` presets.
- :mod:`.network`: :class:`FeatureNet` (PVCNN encoder -> triplanes -> ViT -> queried features).
- :mod:`.train`: losses, one training step, checkpoints, the (optionally distributed) loop.
- :mod:`.source`: :class:`ModelFeatureSource`, the network as a feature source; :func:`load_model`.
- :mod:`.weights`: the bundled checkpoint and the per-process cache of loaded networks.

Importing this package imports no torch; the submodules that need it import it.
"""
