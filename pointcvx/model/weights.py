"""Model checkpoints as the pipeline uses them: the bundled weights, the checks of a checkpoint
path, and the per-process cache of loaded networks (torch is imported only to load one)."""

from __future__ import annotations

import functools
import os
import pickle
import zipfile
from pathlib import Path

from ..errors import InputError, PointcvxError, first_line

BUNDLED_MODEL = Path(__file__).resolve().parents[1] / "data" / "model_small.pt"


def bundled_model_path() -> Path | None:
    """The model shipped inside the package, if this build has one."""
    return BUNDLED_MODEL if BUNDLED_MODEL.is_file() else None


def model_path(model: str | os.PathLike | None = None) -> Path:
    """The checkpoint ``model`` names (default: the bundled one), checked to exist.

    Raises
    ------
    PointcvxError
        No ``model`` given and this build ships none.
    InputError
        ``model`` is missing.
    """
    path = Path(model) if model is not None else bundled_model_path()
    if path is None:
        raise PointcvxError("this build ships no feed-forward model yet: train one with "
                            "`pointcvx train` and pass --model PATH, or use --features optimize")
    if not path.is_file():
        raise InputError(f"{path}: no such model checkpoint")
    return path


def needs_model(features: str, model: str | os.PathLike | None) -> bool:
    """Whether these settings must have a usable checkpoint: the model features, or "auto" with
    a checkpoint named (which must then be valid even where auto would not use it)."""
    return features == "model" or (features == "auto" and model is not None)


def check_model(features: str, model: str | os.PathLike | None) -> None:
    """Fail now (without loading weights) where :func:`load_cached_model` would fail later."""
    if needs_model(features, model):
        model_path(model)


@functools.lru_cache(maxsize=4)
def _cached(path: str, mtime_ns: int, size: int):
    """The network of checkpoint ``path`` for inference (numpy, no torch:
    :class:`~pointcvx.model.numpy_net.NumpyFeatureNet`), loaded once per process (keyed by the
    file's mtime and size too, so a rewritten checkpoint is read again)."""
    from .numpy_net import NumpyFeatureNet

    bundled = bundled_model_path()
    return NumpyFeatureNet.load(path, shipped=bundled is not None and path == str(bundled.resolve()))


def load_cached_model(model: str | os.PathLike | None = None):
    """The feed-forward network of checkpoint ``model`` (default: the bundled one) for inference
    (:class:`~pointcvx.model.numpy_net.NumpyFeatureNet`), loaded once per process and reused by
    every later call (long-lived batch workers load it when they start).

    Raises
    ------
    PointcvxError
        No ``model`` given and this build ships none.
    InputError
        ``model`` is missing or not a pointcvx checkpoint.
    """
    path = model_path(model)
    try:
        stat = path.stat()
        return _cached(str(path.resolve()), stat.st_mtime_ns, stat.st_size)
    except (KeyError, RuntimeError, ValueError, TypeError, EOFError, StopIteration, OSError,
            pickle.UnpicklingError, zipfile.BadZipFile) as exc:
        raise InputError(f"{path}: not a pointcvx model checkpoint ({first_line(exc, 120)})") from None


def cache_info():
    """Hits and misses of the per-process network cache (``functools.lru_cache`` statistics)."""
    return _cached.cache_info()
