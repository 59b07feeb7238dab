"""The trained network as a :class:`~pointcvx.features.FeatureSource`."""

from __future__ import annotations

import os

import numpy as np
import torch

from .network import FeatureNet
from .train import load_checkpoint


def load_model(path: str | os.PathLike, map_location: str | torch.device = "cpu") -> FeatureNet:
    """A :class:`FeatureNet` (in eval mode) from a checkpoint written by
    :func:`~pointcvx.model.train.save_checkpoint` (config and weights are stored together)."""
    state = load_checkpoint(path, map_location=map_location)
    with torch.device(map_location):
        model = FeatureNet(state["config"])
    model.load_state_dict(state["model"])
    return model.eval()


class ModelFeatureSource:
    """Features of any point from a network that has encoded one oriented cloud.

    Parameters
    ----------
    model : FeatureNet
    cloud_points, cloud_normals : (n, 3) float, the shape's oriented samples in the normalised
        frame (normals may be None: zeros are used).
    device : where the network runs (the model is moved there).

    The cloud is encoded once, under ``torch.no_grad()``; :meth:`features` only samples the
    planes, so it is cheap and deterministic.
    """

    name = "model"

    def __init__(self, model: FeatureNet, cloud_points: np.ndarray, cloud_normals: np.ndarray | None = None,
                 device: str | torch.device = "cpu"):
        self.device = torch.device(device)
        self.model = model.to(self.device).eval()
        pts = torch.as_tensor(np.asarray(cloud_points, dtype=np.float32), device=self.device)[None]
        if cloud_normals is None:
            nrm = torch.zeros_like(pts)
        else:
            nrm = torch.as_tensor(np.asarray(cloud_normals, dtype=np.float32), device=self.device)[None]
        with torch.no_grad():
            self.planes = self.model(pts, nrm)  # (1, 3, C, P, P)

    @property
    def dim(self) -> int:
        return self.model.dim

    def features(self, points: np.ndarray, chunk: int = 65536) -> np.ndarray:
        """(n, 3) float points -> (n, dim) float32 unit features."""
        points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
        out = []
        with torch.no_grad():
            for s in range(0, len(points), chunk):
                q = torch.as_tensor(points[s : s + chunk], device=self.device)[None]
                out.append(self.model.query(self.planes, q)[0].cpu().numpy())
        return np.concatenate(out).astype(np.float32) if out else np.zeros((0, self.dim), np.float32)

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) float points -> (n,) float32 predicted signed distance (clipped range)."""
        q = torch.as_tensor(np.asarray(points, dtype=np.float32).reshape(-1, 3), device=self.device)[None]
        with torch.no_grad():
            return self.model.query_all(self.planes, q)[1][0].cpu().numpy().astype(np.float32)
