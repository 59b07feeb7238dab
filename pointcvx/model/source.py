"""The trained network as a :class:`~pointcvx.features.FeatureSource`."""

from __future__ import annotations

import os

import numpy as np
import torch

from ..errors import InputError, first_line
from .network import FeatureNet
from .train import load_checkpoint


def load_model(path: str | os.PathLike, map_location: str | torch.device = "cpu") -> FeatureNet:
    """A :class:`FeatureNet` (in eval mode) from a checkpoint written by
    :func:`~pointcvx.model.train.save_checkpoint` (config and weights are stored together).
    :class:`~pointcvx.errors.InputError` when its weights do not fit the network its config
    describes (a tensor missing, extra or of another shape) or hold NaN or infinite values."""
    state = load_checkpoint(path, map_location=map_location)
    bad = [k for k, v in state["model"].items()
           if torch.is_floating_point(v) and not torch.isfinite(v).all()]
    if bad:  # NaN features would reach the split's k-means
        raise InputError(f"{path}: not a pointcvx model checkpoint ({len(bad)} weight tensors hold "
                         f"NaN or infinite values: {bad[0]}, ...)")
    try:
        with torch.device(map_location):
            model = FeatureNet(state["config"])
        model.load_state_dict(state["model"])
    except (KeyError, RuntimeError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: not a pointcvx model checkpoint (its weights do not fit its "
                         f"config: {first_line(exc, 120)})") from None
    return model.eval()


def view_rotations(views: int, seed: int = 0) -> np.ndarray:
    """(views, 3, 3) float: the identity, then ``views - 1`` seeded uniform rotations."""
    from ..training.shapes import random_rotation

    rng = np.random.default_rng([seed, 7919])
    return np.stack([np.eye(3)] + [random_rotation(rng) for _ in range(max(0, views - 1))])


class ModelFeatureSource:
    """Features of any point from a network that has encoded one oriented cloud.

    Parameters
    ----------
    model : FeatureNet
    cloud_points, cloud_normals : (n, 3) float, the shape's oriented samples in the normalised
        frame (normals may be None: zeros are used).
    device : where the network runs (the model is moved there).
    views : int
        Encode the cloud in this many orientations (:func:`view_rotations`) and concatenate the
        unit features of each, scaled by 1/sqrt(views): the result is unit length and the cosine
        of two such features is the mean of the per-view cosines, a test-time ensemble (each view's
        embedding is only defined up to its own rotation of feature space, so averaging the
        features themselves would be meaningless). ``dim`` grows to ``views * model.dim``.

    The cloud is encoded once per view, under ``torch.no_grad()``; :meth:`features` only samples
    the planes, so it is cheap and deterministic.
    """

    name = "model"

    def __init__(self, model: FeatureNet, cloud_points: np.ndarray, cloud_normals: np.ndarray | None = None,
                 device: str | torch.device = "cpu", views: int = 1):
        if int(views) < 1:
            raise ValueError(f"views must be at least 1, got {views}")
        self.device = torch.device(device)
        self.model = model.to(self.device).eval()
        self.rotations = torch.as_tensor(view_rotations(int(views)), dtype=torch.float32, device=self.device)
        pts = torch.as_tensor(np.asarray(cloud_points, dtype=np.float32), device=self.device)[None]
        if cloud_normals is None:
            nrm = torch.zeros_like(pts)
        else:
            nrm = torch.as_tensor(np.asarray(cloud_normals, dtype=np.float32), device=self.device)[None]
        with torch.no_grad():
            # one (1, 3, C, P, P) triplane stack per view
            self.planes = [self.model(pts @ r.T, nrm @ r.T) for r in self.rotations]

    @property
    def views(self) -> int:
        return len(self.rotations)

    @property
    def dim(self) -> int:
        return self.model.dim * self.views

    def features(self, points: np.ndarray, chunk: int = 65536) -> np.ndarray:
        """(n, 3) float points -> (n, dim) float32 unit features."""
        points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
        scale = 1.0 / np.sqrt(self.views)
        out = []
        with torch.no_grad():
            for s in range(0, len(points), chunk):
                q = torch.as_tensor(points[s : s + chunk], device=self.device)[None]
                per_view = [self.model.query(planes, q @ r.T)[0]
                            for planes, r in zip(self.planes, self.rotations, strict=True)]
                out.append((torch.cat(per_view, dim=1) * scale).cpu().numpy())
        return np.concatenate(out).astype(np.float32) if out else np.zeros((0, self.dim), np.float32)

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) float points -> (n,) float32 predicted signed distance (clipped range)."""
        q = torch.as_tensor(np.asarray(points, dtype=np.float32).reshape(-1, 3), device=self.device)[None]
        with torch.no_grad():
            return self.model.query_all(self.planes[0], q)[1][0].cpu().numpy().astype(np.float32)
