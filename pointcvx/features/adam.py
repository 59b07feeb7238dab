"""Adam with a cosine learning-rate schedule for per-shape optimisation, written out.

``torch.optim.Adam(...)`` imports ``torch._dynamo`` (with sympy) when it is constructed: 1.3-3 s
of every process that optimises one shape's field, more than the fit of a small shape. These
are the same updates as ``torch.optim.Adam`` (its single-tensor CPU path: no weight decay, no
amsgrad) under ``torch.optim.lr_scheduler.CosineAnnealingLR`` (``eta_min=0``), operation for
operation, so the result is bit-identical (``tests/test_features.py`` compares the two).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator

import torch


def cosine_lrs(lr: float, steps: int) -> Iterator[float]:
    """The learning rate of each of ``steps`` steps under ``CosineAnnealingLR(T_max=steps)``:
    ``lr`` first, then torch's recursive form (not the closed form: the floats differ)."""
    t_max = max(steps, 1)
    for epoch in range(steps):
        if epoch > 0:
            lr = ((1 + math.cos(math.pi * epoch / t_max)) / (1 + math.cos(math.pi * (epoch - 1) / t_max))
                  * (lr - 0.0) + 0.0)
        yield lr


class Adam:
    """Adam over ``params`` (tensors with ``.grad``); :meth:`step` applies one update at ``lr``.

    Parameters
    ----------
    params : iterable of torch.Tensor
    betas : (float, float)
    eps : float
    """

    def __init__(self, params: Iterable[torch.Tensor], betas: tuple[float, float] = (0.9, 0.999),
                 eps: float = 1e-8):
        self.params = [p for p in params if p.requires_grad]
        self.beta1, self.beta2 = float(betas[0]), float(betas[1])
        self.eps = float(eps)
        self.steps = 0
        self.exp_avg = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        self.exp_avg_sq = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]

    def zero_grad(self) -> None:
        for p in self.params:
            p.grad = None

    @torch.no_grad()
    def step(self, lr: float) -> None:
        self.steps += 1
        step = float(self.steps)
        bias_correction1 = 1 - self.beta1 ** step
        bias_correction2 = 1 - self.beta2 ** step
        step_size = lr / bias_correction1
        bias_correction2_sqrt = bias_correction2 ** 0.5
        for p, exp_avg, exp_avg_sq in zip(self.params, self.exp_avg, self.exp_avg_sq, strict=True):
            if p.grad is None:
                continue
            grad = p.grad
            exp_avg.lerp_(grad, 1 - self.beta1)
            exp_avg_sq.mul_(self.beta2).addcmul_(grad, grad, value=1 - self.beta2)
            denom = (exp_avg_sq.sqrt() / bias_correction2_sqrt).add_(self.eps)
            p.addcdiv_(exp_avg, denom, value=-step_size)
