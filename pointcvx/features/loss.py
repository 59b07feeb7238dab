"""The contrastive objective on unit features."""

from __future__ import annotations

import torch
import torch.nn.functional as F


def info_nce(anchor: torch.Tensor, positive: torch.Tensor, negatives: torch.Tensor,
             tau: float = 0.1) -> torch.Tensor:
    """Symmetric InfoNCE with similarity ``exp(cos / tau)``.

    Parameters
    ----------
    anchor, positive : (a, k) float
        Features of anchors and their positives (normalised inside).
    negatives : (a, m, k) float
        Features of each anchor's negatives.
    tau : float
        Temperature.

    Returns
    -------
    () float
        Mean over anchors of the two cross-entropies, one with the anchor as query and one with
        the positive as query, each picking its partner out of {partner} + negatives.
    """
    a = F.normalize(anchor, dim=-1)
    p = F.normalize(positive, dim=-1)
    n = F.normalize(negatives, dim=-1)
    ap = (a * p).sum(-1, keepdim=True)  # (a, 1)
    an = torch.einsum("ak,amk->am", a, n)
    pn = torch.einsum("ak,amk->am", p, n)
    target = torch.zeros(len(a), dtype=torch.long, device=a.device)
    loss_a = F.cross_entropy(torch.cat([ap, an], dim=1) / tau, target)
    loss_p = F.cross_entropy(torch.cat([ap, pn], dim=1) / tau, target)
    return 0.5 * (loss_a + loss_p)
