"""Training the feature network: batches, one step, checkpoints and the training loop.

The dataset consumed here is any object with ``__len__`` and ``__getitem__(i) -> dict`` of numpy
arrays: ``points (n, 3)``, ``normals (n, 3)`` (the network input, augmented by the dataset),
``pool (m, 3)``, ``anchor (a,)`` (pool indices), ``positive (a, 3)``, ``negative (a, k)`` (pool
indices), and optionally ``sdf_points (s, 3)`` and ``sdf (s,)``.

:func:`train` runs single-process or, when launched by ``torchrun`` (``WORLD_SIZE`` > 1 in the
environment) or inside an initialised process group, with ``DistributedDataParallel`` (gloo on
CPU, nccl on CUDA): each rank draws its own share of every global batch, and only rank 0 writes
checkpoints and the CSV log.
"""

from __future__ import annotations

import csv
import logging
import math
import os
import random
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
import torch.nn.functional as F
from torch import nn

from ..features.loss import info_nce
from ..io.files import atomic_path
from ..training.shapes import random_rotation  # noqa: F401 - re-exported for callers
from .config import ModelConfig
from .network import FeatureNet

log = logging.getLogger(__name__)

LOG_FIELDS = ("step", "loss", "contrastive", "sdf", "lr", "seconds")


# -------------------------------------------------------------------------- batches
def collate(items: list[dict[str, np.ndarray]], device: str | torch.device = "cpu") -> dict[str, Any]:
    """Stack network inputs and keep triplets per shape.

    Parameters
    ----------
    items : list of b dataset items (see the module docstring); all with the same ``n``.

    Returns
    -------
    dict with ``points``, ``normals`` (b, n, 3) float tensors and lists of b tensors ``pool``
    (m_i, 3), ``anchor`` (a_i,), ``positive`` (a_i, 3), ``negative`` (a_i, k_i) and, when every
    item has them, ``sdf_points`` (s_i, 3) and ``sdf`` (s_i,).
    """
    def f32(x):
        return torch.as_tensor(np.asarray(x, dtype=np.float32), device=device)

    def i64(x):
        return torch.as_tensor(np.asarray(x, dtype=np.int64), device=device)

    n = {len(it["points"]) for it in items}
    if len(n) != 1:
        raise ValueError(f"all items of a batch need the same number of input points, got {sorted(n)}")
    batch: dict[str, Any] = {
        "points": torch.stack([f32(it["points"]) for it in items]),
        "normals": torch.stack([f32(it["normals"]) for it in items]),
        "pool": [f32(it["pool"]) for it in items],
        "anchor": [i64(it["anchor"]) for it in items],
        "positive": [f32(it["positive"]) for it in items],
        "negative": [i64(it["negative"]) for it in items],
    }
    if all("sdf_points" in it and "sdf" in it for it in items):
        batch["sdf_points"] = [f32(it["sdf_points"]) for it in items]
        batch["sdf"] = [f32(it["sdf"]) for it in items]
    return batch


def shape_losses(model: FeatureNet, planes: torch.Tensor, batch: dict[str, Any], i: int, tau: float,
                 sdf_clip: float) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Contrastive and SDF losses of shape ``i`` of a batch, given its (1, 3, C, P, P) planes.

    Only the pool points that appear as anchors or negatives are queried.
    """
    pool, anchor, negative = batch["pool"][i], batch["anchor"][i], batch["negative"][i]
    used, inverse = torch.unique(torch.cat([anchor, negative.reshape(-1)]), return_inverse=True)
    a = len(anchor)
    xyz = torch.cat([pool[used], batch["positive"][i]])[None]  # (1, u + a, 3)
    raw = model.query_raw(planes, xyz)[0]
    feats = raw[:, model.sdf_channels :]
    f_pool, f_pos = feats[: len(used)], feats[len(used) :]
    f_anchor = f_pool[inverse[:a]]
    f_neg = f_pool[inverse[a:]].reshape(a, negative.shape[1], -1)
    contrastive = info_nce(f_anchor, f_pos, f_neg, tau)
    sdf = None
    if "sdf_points" in batch:
        raw_sdf = model.query_raw(planes, batch["sdf_points"][i][None])[0, :, : model.sdf_channels]
        pred = model.sdf_head(raw_sdf)[:, 0]
        target = batch["sdf"][i].clamp(-sdf_clip, sdf_clip)
        sdf = F.mse_loss(pred, target)
    return contrastive, sdf


def compute_loss(net: FeatureNet, batch: dict[str, Any], tau: float, sdf_weight: float,
                 sdf_clip: float = 0.05) -> dict[str, torch.Tensor]:
    """Mean contrastive + ``sdf_weight`` * SDF loss over the shapes of a collated batch.

    Returns a dict of () tensors ``loss``, ``contrastive``, ``sdf``. Every parameter takes part
    in the graph (the SDF head through a zero term when the batch has no SDF samples), as
    ``DistributedDataParallel`` needs.
    """
    planes = net(batch["points"], batch["normals"])
    con, sdf = [], []
    for i in range(planes.shape[0]):
        c, s = shape_losses(net, planes[i : i + 1], batch, i, tau, sdf_clip)
        con.append(c)
        if s is not None:
            sdf.append(s)
    contrastive = torch.stack(con).mean()
    if sdf:
        sdf_loss = torch.stack(sdf).mean()
    else:
        sdf_loss = 0.0 * sum(p.sum() for p in net.sdf_head.parameters())
    loss = contrastive + sdf_weight * sdf_loss
    return {"loss": loss, "contrastive": contrastive, "sdf": sdf_loss}


class Objective(nn.Module):
    """``compute_loss`` as a module, so that ``DistributedDataParallel`` can wrap the whole step."""

    def __init__(self, net: FeatureNet):
        super().__init__()
        self.net = net

    def forward(self, batch: dict[str, Any], tau: float, sdf_weight: float,
                sdf_clip: float = 0.05) -> dict[str, torch.Tensor]:
        return compute_loss(self.net, batch, tau, sdf_weight, sdf_clip)


def training_step(model: nn.Module, batch: dict[str, Any], optimizer: torch.optim.Optimizer,
                  tau: float = 1.0, sdf_weight: float = 1.0, sdf_clip: float = 0.05,
                  grad_clip: float = 0.0, amp: bool = False) -> dict[str, float]:
    """One optimiser step on a collated batch; returns ``{"loss", "contrastive", "sdf"}`` floats.

    ``model`` is a :class:`FeatureNet`, or an :class:`Objective` (possibly wrapped in
    ``DistributedDataParallel``). ``amp`` runs the forward pass under bfloat16 autocast (no loss
    scaling is needed for bfloat16).
    """
    model.train()
    optimizer.zero_grad(set_to_none=True)
    with torch.autocast(batch["points"].device.type, dtype=torch.bfloat16, enabled=amp):
        if isinstance(model, FeatureNet):
            losses = compute_loss(model, batch, tau, sdf_weight, sdf_clip)
        else:
            losses = model(batch, tau, sdf_weight, sdf_clip)
    losses = {k: v.float() for k, v in losses.items()}
    losses["loss"].backward()
    if grad_clip > 0:
        nn.utils.clip_grad_norm_(model.parameters(), grad_clip)
    optimizer.step()
    return {k: float(v.detach()) for k, v in losses.items()}


# -------------------------------------------------------------------------- augmentation
XYZ_KEYS = ("points", "pool", "positive", "sdf_points")
DIRECTION_KEYS = ("normals",)


def rotate_item(item: dict[str, np.ndarray], rotation: np.ndarray) -> dict[str, np.ndarray]:
    """A copy of a dataset item with every point and normal rotated by ``rotation`` (3, 3) about
    the origin (indices and signed distances are unchanged). Shapes normalised to 0.9 of
    [-1, 1] may leave the unit cube slightly; the network clamps them to the border cells."""
    out = dict(item)
    for k in XYZ_KEYS + DIRECTION_KEYS:
        if k in item:
            out[k] = (np.asarray(item[k]) @ rotation.T).astype(np.asarray(item[k]).dtype)
    return out


# -------------------------------------------------------------------------- reproducibility, checkpoints
def seed_everything(seed: int) -> None:
    """Seed python, numpy and torch (all devices)."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def _unwrap(model: nn.Module) -> nn.Module:
    """The :class:`FeatureNet` inside a DDP wrapper and/or an :class:`Objective`."""
    model = model.module if hasattr(model, "module") else model
    return model.net if isinstance(model, Objective) else model


def save_checkpoint(path: str | os.PathLike, model: nn.Module, optimizer: torch.optim.Optimizer | None,
                    step: int, config: ModelConfig, scheduler: Any = None,
                    extra: dict[str, Any] | None = None) -> Path:
    """Write weights, optimiser/scheduler state, step and config atomically (temp file + replace)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {
        "model": _unwrap(model).state_dict(),
        "optimizer": optimizer.state_dict() if optimizer is not None else None,
        "scheduler": scheduler.state_dict() if scheduler is not None else None,
        "step": int(step),
        "config": config.to_dict(),
        "extra": extra or {},
    }
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        torch.save(state, fh)
    return path


def load_checkpoint(path: str | os.PathLike, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """The dict written by :func:`save_checkpoint` (``config`` as a :class:`ModelConfig`)."""
    state = torch.load(path, map_location=map_location, weights_only=True)
    state["config"] = ModelConfig.from_dict(state["config"])
    return state


def export_weights(checkpoint: str | os.PathLike, out: str | os.PathLike,
                   extra: dict[str, Any] | None = None) -> Path:
    """Write the inference part of a training checkpoint (weights, config, step; no optimiser or
    scheduler state, about a third of the size) to ``out``, atomically; ``extra`` (e.g. how it
    was trained) is stored alongside and merged over the checkpoint's own."""
    state = load_checkpoint(checkpoint)
    model = FeatureNet(state["config"])
    model.load_state_dict(state["model"])
    return save_checkpoint(out, model, None, state["step"], state["config"],
                           extra={**state.get("extra", {}), **(extra or {})})


# -------------------------------------------------------------------------- schedule, sharding
def cosine_lambda(total_steps: int, warmup_steps: int = 0, min_ratio: float = 0.0):
    """LR multiplier: linear warm-up, then cosine decay from 1 to ``min_ratio`` at ``total_steps``."""
    def f(step: int) -> float:
        if warmup_steps and step < warmup_steps:
            return (step + 1) / warmup_steps
        t = min(1.0, (step - warmup_steps) / max(1, total_steps - warmup_steps))
        return min_ratio + (1.0 - min_ratio) * 0.5 * (1.0 + math.cos(math.pi * t))
    return f


def batch_items(step: int, n_items: int, batch_size: int, rank: int = 0, world_size: int = 1,
                seed: int = 0) -> list[tuple[int, int]]:
    """``(index, epoch)`` of each item of ``rank``'s share of global batch ``step`` (0-based).

    Items are drawn epoch by epoch from a seeded permutation, the global batch of
    ``batch_size * world_size`` items split by rank (``DistributedSampler``-style), so a resumed
    run sees exactly the items an uninterrupted one would. ``epoch`` is the pass over the data
    the item belongs to; datasets augment each pass differently.
    """
    out = []
    for j in range(batch_size):
        pos = (step * world_size + rank) * batch_size + j
        epoch, k = divmod(pos, n_items)
        perm = np.random.default_rng([seed, epoch]).permutation(n_items)
        out.append((int(perm[k]), int(epoch)))
    return out


def batch_indices(step: int, n_items: int, batch_size: int, rank: int = 0, world_size: int = 1,
                  seed: int = 0) -> list[int]:
    """Dataset indices of :func:`batch_items`."""
    return [i for i, _ in batch_items(step, n_items, batch_size, rank, world_size, seed)]


def fetch_item(dataset, index: int, epoch: int) -> dict[str, np.ndarray]:
    """``dataset.item(index, epoch)`` where the dataset augments per pass, else ``dataset[index]``."""
    item = getattr(dataset, "item", None)
    return item(index, epoch) if callable(item) else dataset[index]


_WORKER_DATASET = None


def _init_worker(dataset) -> None:
    global _WORKER_DATASET
    _WORKER_DATASET = dataset
    torch.set_num_threads(1)


def _worker_fetch(index: int, epoch: int) -> dict[str, np.ndarray]:
    return fetch_item(_WORKER_DATASET, index, epoch)


class BatchLoader:
    """The items of successive training steps, read in ``workers`` processes ahead of use
    (``prefetch`` steps ahead), or in this process with ``workers=0``. Deterministic: item
    ``(index, epoch)`` is the same array whichever process reads it.

    Use as a context manager; :meth:`get` returns the list of items of one step.
    """

    def __init__(self, dataset, batch_size: int, rank: int, world_size: int, seed: int,
                 workers: int = 0, prefetch: int = 4):
        self.dataset, self.batch_size, self.rank, self.world, self.seed = (
            dataset, batch_size, rank, world_size, seed)
        self.workers, self.prefetch = int(workers), max(1, int(prefetch))
        self._pool = None
        self._pending: dict[int, list] = {}

    def __enter__(self) -> BatchLoader:
        if self.workers > 0:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            self._pool = ProcessPoolExecutor(self.workers, mp_context=mp.get_context("spawn"),
                                             initializer=_init_worker, initargs=(self.dataset,))
        return self

    def __exit__(self, *exc) -> None:
        if self._pool is not None:
            for futures in self._pending.values():
                for f in futures:
                    f.cancel()
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def _items(self, step: int) -> list[tuple[int, int]]:
        return batch_items(step, len(self.dataset), self.batch_size, self.rank, self.world, self.seed)

    def get(self, step: int) -> list[dict[str, np.ndarray]]:
        if self._pool is None:
            return [fetch_item(self.dataset, i, e) for i, e in self._items(step)]
        for s in range(step, step + self.prefetch):
            if s not in self._pending:
                self._pending[s] = [self._pool.submit(_worker_fetch, i, e) for i, e in self._items(s)]
        for s in [s for s in self._pending if s < step]:
            for f in self._pending.pop(s):
                f.cancel()
        return [f.result() for f in self._pending.pop(step)]


def distributed_context(device: str | torch.device | None) -> tuple[int, int, torch.device]:
    """``(rank, world_size, device)``; initialises the process group under ``torchrun``."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if not dist.is_initialized() and world > 1:
        cuda = torch.cuda.is_available() and (device is None or torch.device(device).type == "cuda")
        dist.init_process_group("nccl" if cuda else "gloo")
    if dist.is_initialized():
        rank, world = dist.get_rank(), dist.get_world_size()
    else:
        rank, world = 0, 1
    if device is None:
        if torch.cuda.is_available():
            device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", rank)) % torch.cuda.device_count())
        else:
            device = torch.device("cpu")
    device = torch.device(device)
    if device.type == "cuda" and device.index is not None:
        torch.cuda.set_device(device)
    return rank, world, device


# -------------------------------------------------------------------------- the loop
def train(config: ModelConfig, dataset, steps: int, out_dir: str | os.PathLike, *, resume: bool = True,
          log_csv: bool = True, device: str | torch.device | None = None,
          total_steps: int | None = None, init: str | os.PathLike | None = None,
          progress=None, workers: int = 0) -> FeatureNet:
    """Train (or continue training) a :class:`FeatureNet` up to global step ``steps``.

    Parameters
    ----------
    config : ModelConfig, network and ``config.train`` settings.
    dataset : see the module docstring.
    steps : int, the step count to reach (a resumed run continues from its checkpoint's step).
    out_dir : checkpoints (``last.pt``, every ``checkpoint_every`` steps also ``step_XXXXXXX.pt``)
        and ``log.csv`` go here.
    resume : continue from ``out_dir/last.pt`` if it exists.
    total_steps : length of the cosine schedule (default ``steps``).
    init : checkpoint whose weights start a new run (fine-tuning); the optimiser, schedule and
        step start fresh. Ignored when the run resumes from its own ``last.pt``.
    progress : optional ``callable(step, steps, losses)`` called on rank 0 after every step.
    workers : processes that read and augment the items of the next steps ahead of use (0: read
        them in this process). The batches are the same for any count.

    Returns
    -------
    FeatureNet, the trained network (unwrapped), on ``device``.
    """
    tc = config.train
    rank, world, device = distributed_context(device)
    out = Path(out_dir)
    last = out / "last.pt"
    seed_everything(tc.seed)
    model = FeatureNet(config).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=tc.lr, weight_decay=tc.weight_decay)
    schedule = cosine_lambda(total_steps or steps, tc.warmup_steps, tc.min_lr_ratio)
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, schedule)
    step = 0
    if resume and last.exists():
        state = load_checkpoint(last, map_location=device)
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        if state.get("scheduler") is not None:
            scheduler.load_state_dict(state["scheduler"])
        step = state["step"]
        log.info("resumed from %s at step %d", last, step)
    elif init is not None:
        state = load_checkpoint(init, map_location=device)
        try:
            model.load_state_dict(state["model"])
        except RuntimeError:
            raise ValueError(f"{init}: its weights do not fit this network configuration "
                             f"(it was trained as {state['config'].name!r})") from None
        log.info("initialised the weights from %s (step %d there)", init, state["step"])
    ddp = world > 1
    if ddp:
        from torch.nn.parallel import DistributedDataParallel

        net = DistributedDataParallel(Objective(model),
                                      device_ids=[device.index] if device.type == "cuda" else None)
    else:
        net = model
    if rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    writer, fh, board = None, None, None
    if rank == 0 and log_csv:
        board = _tensorboard(out / "tensorboard", step)
        path = out / "log.csv"
        new = not path.exists() or step == 0
        if not new:
            _truncate_log(path, step)
        fh = open(path, "w" if new else "a", newline="")  # closed in the finally below
        writer = csv.writer(fh)
        if new:
            writer.writerow(LOG_FIELDS)
    loader = BatchLoader(dataset, tc.batch_size, rank, world, tc.seed, workers, prefetch=2 * workers)
    try:
        loader.__enter__()
        while step < steps:
            t0 = time.perf_counter()
            batch = collate(loader.get(step), device)
            lr = optimizer.param_groups[0]["lr"]
            losses = training_step(net, batch, optimizer, tc.tau, tc.sdf_weight, tc.sdf_clip, tc.grad_clip,
                                   tc.amp)
            scheduler.step()
            step += 1
            if ddp:
                losses = _mean_across_ranks(losses, device)
            if rank == 0:
                if writer is not None and (step % tc.log_every == 0 or step == steps):
                    writer.writerow([step, losses["loss"], losses["contrastive"], losses["sdf"], lr,
                                     round(time.perf_counter() - t0, 4)])
                    fh.flush()
                if board is not None and (step % tc.log_every == 0 or step == steps):
                    for key in ("loss", "contrastive", "sdf"):
                        board.add_scalar(f"train/{key}", losses[key], step)
                    board.add_scalar("train/lr", lr, step)
                log.info("step %d loss %.4f (contrastive %.4f, sdf %.5f) lr %.3g", step, losses["loss"],
                         losses["contrastive"], losses["sdf"], lr)
                if progress is not None:
                    progress(step, steps, losses)
                if step % tc.checkpoint_every == 0 or step == steps:
                    save_checkpoint(last, model, optimizer, step, config, scheduler)
                    if step % tc.checkpoint_every == 0:
                        save_checkpoint(out / f"step_{step:07d}.pt", model, optimizer, step, config,
                                        scheduler)
    finally:
        loader.__exit__(None, None, None)
        if fh is not None:
            fh.close()
        if board is not None:
            board.close()
    if ddp:
        dist.barrier()
    return model


def _tensorboard(folder: Path, step: int):
    """A TensorBoard ``SummaryWriter`` on ``folder`` when the ``tensorboard`` package is installed
    (a resumed run purges events past ``step``), else None: the CSV log is always written."""
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:
        log.debug("tensorboard is not installed: CSV log only")
        return None
    return SummaryWriter(str(folder), purge_step=step + 1 if step else None)


def _mean_across_ranks(losses: dict[str, float], device: torch.device) -> dict[str, float]:
    t = torch.tensor([losses[k] for k in ("loss", "contrastive", "sdf")], device=device, dtype=torch.float64)
    dist.all_reduce(t)
    t /= dist.get_world_size()
    return dict(zip(("loss", "contrastive", "sdf"), t.tolist(), strict=True))


def _truncate_log(path: Path, step: int) -> None:
    """Drop log rows past ``step`` (written after the checkpoint a run resumes from)."""
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    keep = [rows[0]] + [r for r in rows[1:] if r and int(r[0]) <= step]
    if len(keep) != len(rows):
        with open(path, "w", newline="") as fh:
            csv.writer(fh).writerows(keep)


def read_log(path: str | os.PathLike) -> list[dict[str, float]]:
    """Rows of a ``log.csv`` as dicts of floats (``step`` as int)."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return [{k: (int(v) if k == "step" else float(v)) for k, v in row.items()} for row in rows]
