"""Per-shape feature fields: a small MLP on Fourier features of xyz, optimised with the
contrastive loss on the shape's own triplets (the paper's "single-shape optimisation")."""

from __future__ import annotations

import contextlib
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import nn

from .adam import Adam, cosine_lrs
from .loss import info_nce
from .pairs import Triplets

log = logging.getLogger(__name__)


class FourierMLP(nn.Module):
    """xyz (n, 3) -> unit features (n, dim) through sin/cos encodings and a ReLU MLP."""

    def __init__(self, dim: int = 32, n_freqs: int = 4, width: int = 64, depth: int = 3):
        super().__init__()
        self.register_buffer("freqs", (2.0 ** torch.arange(n_freqs)) * math.pi)
        layers: list[nn.Module] = []
        d_in = 3 + 6 * n_freqs
        for _ in range(depth):
            layers += [nn.Linear(d_in, width), nn.ReLU()]
            d_in = width
        layers.append(nn.Linear(d_in, dim))
        self.net = nn.Sequential(*layers)

    def encode(self, xyz: torch.Tensor) -> torch.Tensor:
        ang = xyz[..., None] * self.freqs  # (n, 3, f)
        return torch.cat([xyz, ang.sin().flatten(-2), ang.cos().flatten(-2)], dim=-1)

    def forward(self, xyz: torch.Tensor) -> torch.Tensor:
        return nn.functional.normalize(self.net(self.encode(xyz)), dim=-1)


@dataclass
class OptimizedField:
    """A :class:`~pointcvx.features.FeatureSource` fitted to one shape.

    Attributes
    ----------
    model : FourierMLP
    losses : list of float, the loss at each optimisation step.
    """

    model: FourierMLP
    losses: list = field(default_factory=list)
    name: str = "optimize"

    @property
    def dim(self) -> int:
        return self.model.net[-1].out_features

    @torch.no_grad()
    def features(self, points: np.ndarray, chunk: int = 65536) -> np.ndarray:
        """(n, 3) float points (normalised frame) -> (n, dim) float32 unit features."""
        self.model.eval()
        with torch_threads(1):
            out = [
                self.model(torch.as_tensor(points[s : s + chunk], dtype=torch.float32)).numpy()
                for s in range(0, len(points), chunk)
            ]
        return np.concatenate(out) if out else np.zeros((0, self.dim), np.float32)


@contextlib.contextmanager
def torch_threads(n: int):
    """Run torch ops with ``n`` intra-op threads (small MLPs are fastest, and immune to
    oversubscription on busy machines, with one)."""
    old = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def optimize_field(
    triplets: Triplets,
    *,
    dim: int = 32,
    steps: int = 300,
    batch: int = 128,
    negatives_per_step: int = 64,
    lr: float = 3e-3,
    tau: float = 0.3,
    seed: int = 0,
    progress: Callable[[int, float], None] | None = None,
) -> OptimizedField:
    """Fit a :class:`FourierMLP` to ``triplets`` with Adam and the symmetric InfoNCE loss.

    Each step draws ``batch`` anchors and, for each, ``negatives_per_step`` of its negatives (the
    hard and uniform ones in their sampled proportion); features of the pool points involved are
    computed once per step and gathered, so a step costs a few thousand MLP evaluations.
    ``progress(step, loss)`` is called after each step. Deterministic for a given seed.
    """
    with torch_threads(1):
        return _optimize(triplets, dim, steps, batch, negatives_per_step, lr, tau, seed, progress)


def _optimize(triplets, dim, steps, batch, negatives_per_step, lr, tau, seed, progress):
    torch.manual_seed(seed)
    model = FourierMLP(dim=dim)
    result = OptimizedField(model)
    if len(triplets) == 0:  # convex shape: nothing to separate
        log.debug("no triplets: the field stays at its initialisation")
        return result
    gen = torch.Generator().manual_seed(seed)
    pool = torch.as_tensor(triplets.pool, dtype=torch.float32)
    anchor = torch.as_tensor(triplets.anchor)
    positive = torch.as_tensor(triplets.positive, dtype=torch.float32)
    negative = torch.as_tensor(triplets.negative)
    opt = Adam(model.parameters())  # torch.optim.Adam's updates without its torch._dynamo import
    model.train()
    for step, step_lr in enumerate(cosine_lrs(lr, steps)):
        pick = torch.randint(len(anchor), (min(batch, len(anchor)),), generator=gen)
        cols = torch.randint(negative.shape[1], (len(pick), negatives_per_step), generator=gen)
        neg = torch.gather(negative[pick], 1, cols)
        used = torch.unique(torch.cat([anchor[pick], neg.flatten()]))
        remap = torch.full((len(pool),), -1, dtype=torch.long)
        remap[used] = torch.arange(len(used))
        f_pool = model(pool[used])
        f_pos = model(positive[pick])
        loss = info_nce(f_pool[remap[anchor[pick]]], f_pos, f_pool[remap[neg]], tau=tau)
        opt.zero_grad()
        loss.backward()
        opt.step(step_lr)
        value = float(loss.detach())
        result.losses.append(value)
        if progress is not None:
            progress(step, value)
    model.eval()
    return result
