"""Mean contrastive loss of trained weights on prepared shapes none of them was trained on.

    pointcvx prepare /tmp/heldout --procedural 40 --no-urdfs --seed 7 --jobs 2
    python tools/heldout_loss.py /tmp/heldout pointcvx/data/model_small.pt OTHER.pt ... [--tau 0.3]

Each shape's input is a fixed random subset of its points (``--points``, the training input size),
without augmentation; its triplets are the prepared ones. Prints one line per checkpoint: the
mean symmetric InfoNCE over the shapes (lower is better; comparable across checkpoints only
at the same ``--tau`` on the same folder).
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from pointcvx.model.source import load_model
from pointcvx.model.train import collate, compute_loss
from pointcvx.training.data import TripletDataset


def held_out_items(folder: str, n_points: int, limit: int | None = None) -> list[dict]:
    """The prepared shapes of ``folder``, each with a seeded (n_points,) subset as input."""
    ds = TripletDataset(folder, augment=False)
    items = []
    for i in range(len(ds) if limit is None else min(limit, len(ds))):
        item = ds.item(i, 0)
        n = len(item["points"])
        if n > n_points:
            keep = np.random.default_rng(i).choice(n, n_points, replace=False)
            item["points"], item["normals"] = item["points"][keep], item["normals"][keep]
        items.append(item)
    return items


def mean_loss(checkpoint: str, items: list[dict], tau: float) -> float:
    net = load_model(checkpoint).eval()
    with torch.no_grad():
        return float(np.mean([float(compute_loss(net, collate([it]), tau, 1.0)["contrastive"])
                              for it in items]))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", help="folder written by `pointcvx prepare`")
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--tau", type=float, default=0.3)
    parser.add_argument("--points", type=int, default=4096)
    parser.add_argument("--limit", type=int, default=None, help="use at most N shapes")
    args = parser.parse_args(argv)
    torch.manual_seed(0)
    items = held_out_items(args.data, args.points, args.limit)
    for ckpt in args.checkpoints:
        print(f"{ckpt}\t{mean_loss(ckpt, items, args.tau):.4f}\t({len(items)} shapes, tau {args.tau})")


if __name__ == "__main__":
    main()
