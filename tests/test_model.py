"""The feed-forward feature network: shapes, sizes, training, checkpoints, resume, DDP."""

from __future__ import annotations

import os
import socket
import time

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial import cKDTree

from pointcvx.features import FeatureSource, sample_triplets
from pointcvx.model.config import ModelConfig
from pointcvx.model.network import (
    FeatureNet,
    build_model,
    count_parameters,
    cross_plane_context,
    devoxelize,
    sample_planes,
    scatter_mean,
    scatter_planes,
    voxelize,
)
from pointcvx.model.source import ModelFeatureSource, load_model
from pointcvx.model.train import (
    batch_indices,
    batch_items,
    collate,
    export_weights,
    load_checkpoint,
    random_rotation,
    read_log,
    rotate_item,
    save_checkpoint,
    seed_everything,
    train,
    training_step,
)
from pointcvx.solid import Solid

N_POINTS = 1024


def tiny_config(**train) -> ModelConfig:
    cfg = ModelConfig.preset("tiny")
    return cfg.with_overrides({f"train.{k}": v for k, v in train.items()}) if train else cfg


def _shape_item(mesh: trimesh.Trimesh, seed: int) -> dict[str, np.ndarray]:
    """One dataset item: a randomly rotated shape normalised to 0.9 of [-1, 1], with triplets and
    approximate SDF samples."""
    rng = np.random.default_rng(seed)
    mesh = mesh.copy()
    mesh.apply_transform(trimesh.transformations.random_rotation_matrix(rng.random(3)))
    mesh.apply_translation(-mesh.bounding_box.centroid)
    mesh.apply_scale(0.9 / np.abs(mesh.vertices).max())
    pts, face = trimesh.sample.sample_surface(mesh, 4 * N_POINTS, seed=seed)
    nrm = mesh.face_normals[face]
    solid = Solid.from_trimesh(mesh)
    trip = sample_triplets(solid, pts, nrm, n_anchors=48, n_candidates=128, n_hard=8, n_uniform=8, seed=seed)
    sdf_pts = rng.uniform(-1, 1, size=(256, 3))
    dist = cKDTree(pts).query(sdf_pts)[0]
    sdf = np.where(solid.contains(sdf_pts), -dist, dist)
    return {
        "points": pts[:N_POINTS].astype(np.float32), "normals": nrm[:N_POINTS].astype(np.float32),
        "pool": trip.pool.astype(np.float32), "anchor": trip.anchor,
        "positive": trip.positive.astype(np.float32), "negative": trip.negative,
        "sdf_points": sdf_pts.astype(np.float32), "sdf": sdf.astype(np.float32),
    }


@pytest.fixture(scope="module")
def dataset() -> list[dict[str, np.ndarray]]:
    """A tiny synthetic triplet dataset (a plain list satisfies the dataset interface)."""
    from shapes import l_block, u_block

    items = [_shape_item(m, s) for s, m in enumerate([l_block(), u_block(), l_block(), u_block()])]
    assert all(len(it["anchor"]) > 8 for it in items)
    return items


# -------------------------------------------------------------------------- building blocks
def test_scatter_and_sampling_are_consistent():
    torch.manual_seed(0)
    xyz = torch.rand(2, 500, 3) * 1.8 - 0.9
    # Scatter-mean of a constant is that constant in occupied bins, 0 elsewhere.
    index = torch.randint(0, 10, (2, 50))
    out = scatter_mean(torch.ones(2, 50, 3) * 2.0, index, 10)
    occupied = torch.zeros(2, 10, dtype=torch.bool).scatter_(1, index, True)
    assert torch.allclose(out[occupied], torch.full_like(out[occupied], 2.0))
    assert torch.all(out[~occupied] == 0)
    # At cell centres, scatter + sample on the xy plane gives back (x, y) exactly: the plane's
    # columns follow x and its rows y, as grid_sample reads them.
    c = (torch.arange(8) + 0.5) / 4 - 1
    gx, gy = torch.meshgrid(c, c, indexing="xy")
    centres = torch.stack([gx.reshape(-1), gy.reshape(-1), torch.rand(64) * 2 - 1], -1)[None]
    planes = scatter_planes(centres[..., :2], centres, 8)  # (1, 3, 2, 8, 8)
    assert planes.shape == (1, 3, 2, 8, 8)
    planes[:, 1:] = 0
    assert torch.allclose(sample_planes(planes, centres), centres[..., :2], atol=1e-6)
    # Sampling constant planes gives three times the constant.
    assert torch.allclose(sample_planes(torch.ones(1, 3, 2, 8, 8), xyz[:1]), torch.full((1, 500, 2), 3.0))


def test_voxel_round_trip_of_constant():
    torch.manual_seed(0)
    xyz = torch.rand(1, 2000, 3) * 2 - 1
    grid = voxelize(torch.ones(1, 2000, 2), xyz, 4)  # every cell occupied with 2000 points
    assert torch.allclose(grid, torch.ones_like(grid))
    assert torch.allclose(devoxelize(grid, xyz), torch.ones(1, 2000, 2), atol=1e-6)


def test_cross_plane_context_follows_shared_axes():
    c = torch.arange(4.0)
    h, w = c[:, None].expand(4, 4), c[None, :].expand(4, 4)  # row (H) and column (W) coordinates
    xy = w + 10 * h  # W = x, H = y: f = x + 10 y
    xz = 100 * h  # W = x, H = z: f = 100 z
    yz = 1000 * w  # W = y, H = z: f = 1000 y
    ctx = cross_plane_context(torch.stack([xy, xz, yz])[None, :, None])  # (1, 3, 2, 4, 4)
    m = c.mean()
    # xy gets xz averaged over z (a line over x: 100 m) and yz averaged over z (over y: 1000 y).
    assert torch.allclose(ctx[0, 0, 0], torch.full((4, 4), 100 * m))
    assert torch.allclose(ctx[0, 0, 1], 1000 * h)
    # xz gets xy averaged over y (over x: x + 10 m) and yz averaged over y (over z: 1000 m).
    assert torch.allclose(ctx[0, 1, 0], w + 10 * m)
    assert torch.allclose(ctx[0, 1, 1], torch.full((4, 4), 1000 * m))
    # yz gets xy averaged over x (over y: m + 10 y) and xz averaged over x (over z: 100 z).
    assert torch.allclose(ctx[0, 2, 0], m + 10 * w)
    assert torch.allclose(ctx[0, 2, 1], 100 * h)


def test_output_shapes_and_unit_norms():
    cfg = tiny_config()
    seed_everything(0)
    model = FeatureNet(cfg).eval()
    pts = torch.rand(2, 300, 3) * 2 - 1
    nrm = torch.nn.functional.normalize(torch.randn(2, 300, 3), dim=-1)
    q = torch.rand(2, 77, 3) * 2 - 1
    with torch.no_grad():
        planes = model(pts, nrm)
        feats, sdf = model.query_all(planes, q)
        direct = model.encode_and_query(pts, nrm, q)
    p = cfg.planes.resolution
    assert planes.shape == (2, 3, cfg.head.sdf_channels + cfg.head.feature_dim, p, p)
    assert feats.shape == (2, 77, cfg.head.feature_dim) and sdf.shape == (2, 77)
    assert torch.allclose(feats.norm(dim=-1), torch.ones(2, 77), atol=1e-5)
    assert torch.allclose(direct, feats, atol=1e-6)


def test_parameter_counts():
    small = count_parameters(build_model(ModelConfig.preset("small"), "meta"))
    paper_model = build_model(ModelConfig.preset("paper"), "meta")
    paper = count_parameters(paper_model)
    assert next(paper_model.parameters()).device.type == "meta"
    assert 1e6 <= small <= 10e6, small
    assert abs(paper - 106e6) <= 0.15 * 106e6, paper


def test_config_round_trip_and_overrides():
    cfg = ModelConfig.preset("small")
    assert ModelConfig.from_json(cfg.to_json()) == cfg
    new = cfg.with_overrides(["transformer.layers=2", "lr=3e-4", "encoder.voxel_resolutions=8,4",
                              "planes.down_channels=[16, 32]"])
    assert new.transformer.layers == 2 and new.train.lr == 3e-4
    assert new.encoder.voxel_resolutions == (8, 4) and new.planes.down_channels == (16, 32)
    assert cfg.transformer.layers != 2  # the original is untouched
    with pytest.raises(KeyError):
        cfg.with_overrides(["nope=1"])


# -------------------------------------------------------------------------- training
def test_training_steps_reduce_loss(dataset):
    cfg = tiny_config()
    seed_everything(0)
    model = FeatureNet(cfg)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    batch = collate(dataset[:2])
    losses = [training_step(model, batch, opt, tau=0.3, sdf_weight=1.0) for _ in range(12)]
    assert set(losses[0]) == {"loss", "contrastive", "sdf"}
    assert all(np.isfinite(v["loss"]) for v in losses)
    # Seeds 0-2 go from about 2.8 to 0.5-0.8 in 12 steps.
    assert losses[-1]["loss"] < losses[0]["loss"] - 0.5, [round(v["loss"], 4) for v in losses]


def test_step_without_sdf_samples(dataset):
    items = [{k: v for k, v in it.items() if not k.startswith("sdf")} for it in dataset[:2]]
    seed_everything(0)
    model = FeatureNet(tiny_config())
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    out = training_step(model, collate(items), opt, tau=0.3)
    assert out["sdf"] == 0.0 and out["loss"] == pytest.approx(out["contrastive"])
    # Every parameter took part (as DistributedDataParallel requires); the SDF head's gradient is 0.
    assert all(p.grad is not None for p in model.parameters())
    assert all(torch.all(p.grad == 0) for p in model.sdf_head.parameters())


def test_amp_step_is_finite(dataset):
    seed_everything(0)
    model = FeatureNet(tiny_config())
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    out = training_step(model, collate(dataset[:1]), opt, tau=0.3, amp=True)
    assert all(np.isfinite(v) for v in out.values())


def test_rotate_item_keeps_geometry(dataset):
    rot = random_rotation(np.random.default_rng(3))
    assert np.allclose(rot @ rot.T, np.eye(3)) and np.isclose(np.linalg.det(rot), 1.0)
    it = dataset[0]
    r = rotate_item(it, rot)
    assert r["points"].dtype == np.float32 and np.array_equal(r["anchor"], it["anchor"])
    assert np.allclose(r["normals"], it["normals"] @ rot.T, atol=1e-6)
    d0 = np.linalg.norm(it["pool"][it["anchor"]] - it["positive"], axis=1)
    d1 = np.linalg.norm(r["pool"][r["anchor"]] - r["positive"], axis=1)
    assert np.allclose(d0, d1, atol=1e-5) and np.array_equal(r["sdf"], it["sdf"])


def test_save_load_round_trip(tmp_path, dataset):
    cfg = tiny_config()
    seed_everything(1)
    model = FeatureNet(cfg)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    training_step(model, collate(dataset[:1]), opt, tau=0.3)
    path = save_checkpoint(tmp_path / "ck.pt", model, opt, 1, cfg)
    assert not [p for p in tmp_path.iterdir() if p.suffix == ".tmp"]
    state = load_checkpoint(path)
    assert state["step"] == 1 and state["config"] == cfg
    loaded = load_model(path)
    for (k1, v1), (k2, v2) in zip(model.state_dict().items(), loaded.state_dict().items(), strict=True):
        assert k1 == k2 and torch.equal(v1, v2)
    it = dataset[0]
    a = ModelFeatureSource(model, it["points"], it["normals"]).features(it["pool"])
    b = ModelFeatureSource(loaded, it["points"], it["normals"]).features(it["pool"])
    assert np.array_equal(a, b)
    # the shippable export keeps weights, config and step, drops the optimiser, and is smaller
    shipped = export_weights(path, tmp_path / "ship.pt", extra={"note": "test"})
    small = load_checkpoint(shipped)
    assert small["optimizer"] is None and small["step"] == 1 and small["extra"] == {"note": "test"}
    assert shipped.stat().st_size < path.stat().st_size
    c = ModelFeatureSource(load_model(shipped), it["points"], it["normals"]).features(it["pool"])
    assert np.array_equal(a, c)


def test_feature_source_deterministic(dataset):
    seed_everything(2)
    model = FeatureNet(tiny_config())
    it = dataset[1]
    src = ModelFeatureSource(model, it["points"], it["normals"], device="cpu")
    assert isinstance(src, FeatureSource) and src.name == "model" and src.dim == 16
    f1 = src.features(it["pool"])
    f2 = ModelFeatureSource(model, it["points"], it["normals"], device="cpu").features(it["pool"])
    assert f1.dtype == np.float32 and f1.shape == (len(it["pool"]), 16)
    assert np.array_equal(f1, f2)
    assert np.allclose(np.linalg.norm(f1, axis=1), 1.0, atol=1e-5)
    assert np.array_equal(src.features(it["pool"][:5]), f1[:5])  # chunking does not matter
    assert src.features(np.zeros((0, 3))).shape == (0, 16)
    assert src.sdf(it["pool"][:7]).shape == (7,)


def test_rotation_views_ensemble(dataset):
    from pointcvx.model.source import view_rotations

    rots = view_rotations(4)
    assert np.array_equal(rots[0], np.eye(3))
    assert np.allclose(rots @ rots.transpose(0, 2, 1), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(rots), 1.0) and np.array_equal(rots, view_rotations(4))
    seed_everything(2)
    model = FeatureNet(tiny_config())
    it = dataset[1]
    one = ModelFeatureSource(model, it["points"], it["normals"]).features(it["pool"])
    ens = ModelFeatureSource(model, it["points"], it["normals"], views=3)
    f = ens.features(it["pool"])
    assert ens.dim == 48 and f.shape == (len(it["pool"]), 48)
    assert np.allclose(np.linalg.norm(f, axis=1), 1.0, atol=1e-5)
    assert np.allclose(f[:, :16] * np.sqrt(3), one, atol=1e-6)  # view 0 is the plain pass
    # view 2 is the network run on the rotated cloud, queried at the rotated points
    r = rots[2].astype(np.float32)
    rotated = ModelFeatureSource(model, it["points"] @ r.T, it["normals"] @ r.T).features(it["pool"] @ r.T)
    assert np.allclose(f[:, 32:] * np.sqrt(3), rotated, atol=1e-5)
    # cosine of the ensemble = mean of the per-view cosines
    views = [f[:, 16 * k : 16 * (k + 1)] * np.sqrt(3) for k in range(3)]
    mean_cos = np.mean([v[:50] @ v[50:100].T for v in views], axis=0)
    assert np.allclose(f[:50] @ f[50:100].T, mean_cos, atol=1e-5)
    with pytest.raises(ValueError):
        ModelFeatureSource(model, it["points"], it["normals"], views=0)


# Measured on the shared 2-core CPU of the development machine while other jobs ran: about 0.1 s
# (best of three), single runs up to about 1 s under heavy load.
SMALL_INFERENCE_BOUND_S = 1.0


def test_small_inference_time():
    seed_everything(0)
    model = build_model(ModelConfig.preset("small")).eval()
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, size=(20000, 3)).astype(np.float32)
    nrm = rng.normal(size=(20000, 3)).astype(np.float32)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    best = np.inf
    for _ in range(3):
        t = time.perf_counter()
        ModelFeatureSource(model, pts, nrm).features(pts)
        best = min(best, time.perf_counter() - t)
    print(f"small preset, 20k points encode + query: {best:.3f} s")
    assert best < SMALL_INFERENCE_BOUND_S


def test_resume_continues_step_and_log(tmp_path, dataset):
    cfg = tiny_config(checkpoint_every=2, batch_size=2, lr=3e-3)
    a = tmp_path / "a"
    train(cfg, dataset, 3, a, total_steps=6)
    assert load_checkpoint(a / "last.pt")["step"] == 3
    assert [r["step"] for r in read_log(a / "log.csv")] == [1, 2, 3]
    resumed = train(cfg, dataset, 6, a, total_steps=6)
    assert load_checkpoint(a / "last.pt")["step"] == 6
    assert (a / "step_0000002.pt").exists() and (a / "step_0000006.pt").exists()
    rows = read_log(a / "log.csv")
    assert [r["step"] for r in rows] == [1, 2, 3, 4, 5, 6]
    # Resuming gives the same model as one uninterrupted run (same data order, optimiser state).
    b = tmp_path / "b"
    straight = train(cfg, dataset, 6, b)
    assert [r["loss"] for r in read_log(b / "log.csv")] == pytest.approx([r["loss"] for r in rows], rel=1e-4)
    for p, q in zip(resumed.parameters(), straight.parameters(), strict=True):
        assert torch.allclose(p, q, atol=1e-5)


def test_batch_indices_shard_by_rank():
    a = [batch_indices(s, 10, 2, rank=0, world_size=2) for s in range(5)]
    b = [batch_indices(s, 10, 2, rank=1, world_size=2) for s in range(5)]
    flat = sorted(i for x in a + b for i in x)
    assert flat == sorted(list(range(10)) * 2)  # 20 draws = two epochs, each item once per epoch


def test_batch_items_count_passes_over_the_data():
    items = [batch_items(s, 4, 2) for s in range(4)]
    assert [[e for _, e in it] for it in items] == [[0, 0], [0, 0], [1, 1], [1, 1]]
    assert sorted(i for it in items[:2] for i, _ in it) == [0, 1, 2, 3]


class _PassAwareData:
    """Items that depend on the pass, like TripletDataset's augmentation (picklable for workers)."""

    def __init__(self, items):
        self.items = items

    def __len__(self):
        return len(self.items)

    def item(self, i, epoch):
        out = dict(self.items[i])
        out["points"] = out["points"] * np.float32(1.0 + 0.05 * epoch)
        return out


def test_workers_give_the_same_training_as_none(tmp_path, dataset):
    cfg = tiny_config(batch_size=2, lr=3e-3, checkpoint_every=100)
    data = _PassAwareData(dataset)  # 4 items: steps 2 and 3 are the second pass
    a = train(cfg, data, 4, tmp_path / "a")
    b = train(cfg, data, 4, tmp_path / "b", workers=2)
    la, lb = read_log(tmp_path / "a" / "log.csv"), read_log(tmp_path / "b" / "log.csv")
    assert [r["loss"] for r in la] == pytest.approx([r["loss"] for r in lb], rel=1e-6)
    for p, q in zip(a.parameters(), b.parameters(), strict=True):
        assert torch.equal(p, q)


# -------------------------------------------------------------------------- distributed (2 CPU processes)
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _ddp_worker(rank: int, world: int, port: int, dataset, out_dir: str) -> None:
    import torch.distributed as dist

    torch.set_num_threads(1)
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    dist.init_process_group("gloo", rank=rank, world_size=world)
    try:
        model = train(tiny_config(batch_size=1, checkpoint_every=100), dataset, 2, out_dir, device="cpu")
        flat = torch.cat([p.detach().reshape(-1) for p in model.parameters()])
        torch.save(flat, os.path.join(out_dir, f"params_rank{rank}.pt"))
    finally:
        dist.destroy_process_group()


def test_ddp_two_cpu_processes_stay_in_sync(tmp_path, dataset):
    """DDP on 2 CPU processes (gloo, 127.0.0.1): after 2 steps on different shards, the parameters
    are identical on both ranks, and rank 0 alone wrote the checkpoint and log."""
    import torch.multiprocessing as mp

    mp.spawn(_ddp_worker, args=(2, _free_port(), dataset, str(tmp_path)), nprocs=2, join=True)
    p0 = torch.load(tmp_path / "params_rank0.pt")
    p1 = torch.load(tmp_path / "params_rank1.pt")
    assert torch.equal(p0, p1)
    assert load_checkpoint(tmp_path / "last.pt")["step"] == 2
    assert [r["step"] for r in read_log(tmp_path / "log.csv")] == [1, 2]
    # The run moved the weights away from the initialisation.
    seed_everything(0)
    init = torch.cat([p.detach().reshape(-1) for p in FeatureNet(tiny_config()).parameters()])
    assert not torch.equal(init, p0)
