"""Training data: procedural solids, prepared samples, the resumable dataset writer, augmentation."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from pointcvx.features.pairs import nonconvex_mask
from pointcvx.solid import Solid
from pointcvx.training import augment as aug
from pointcvx.training.data import (
    KEYS,
    TripletDataset,
    closed_surface,
    load_sample,
    load_training_mesh,
    prepare_dataset,
    prepare_shape,
    save_sample,
    training_meshes,
)
from pointcvx.training.shapes import random_solid

# Small settings so the whole file runs in well under a minute on 2 cores.
SMALL = dict(n_points=3000, resolution=64, n_anchors=48, n_candidates=256, n_hard=16, n_uniform=16,
             n_sdf_near=800, n_sdf_uniform=400)


@pytest.fixture(scope="module")
def urdf_path():
    paths = training_meshes()
    assert len(paths) == 500
    return paths[7]


@pytest.fixture(scope="module")
def proc_sample():
    mesh = random_solid(np.random.default_rng(1))
    return mesh, prepare_shape(mesh, seed=3, watertight=False, **SMALL)


@pytest.fixture(scope="module")
def urdf_sample(urdf_path):
    mesh = load_training_mesh(urdf_path)
    return mesh, prepare_shape(mesh, seed=4, **SMALL)


# ---------------------------------------------------------------------------------- shapes
def test_random_solid_valid_and_nonconvex():
    nonconvex = 0
    for seed in range(20):
        mesh = random_solid(np.random.default_rng(seed))
        assert mesh.is_watertight
        assert mesh.volume > 0
        lo, hi = mesh.bounds
        assert np.all(lo >= -0.9 - 1e-9) and np.all(hi <= 0.9 + 1e-9)
        assert np.isclose((hi - lo).max(), 1.8)
        nonconvex += mesh.volume < 0.95 * mesh.convex_hull.volume
    assert nonconvex >= 14


def test_random_solid_deterministic():
    a = random_solid(np.random.default_rng(11))
    b = random_solid(np.random.default_rng(11))
    c = random_solid(np.random.default_rng(12))
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    assert a.vertices.shape != c.vertices.shape or not np.allclose(a.vertices, c.vertices)


# ---------------------------------------------------------------------------------- samples
def _check_sample(sample, solid):
    assert set(KEYS) <= set(sample)
    n, m, a = len(sample["points"]), len(sample["pool"]), len(sample["anchor"])
    assert n == SMALL["n_points"] and m == n
    assert sample["points"].shape == sample["normals"].shape == (n, 3)
    assert sample["pool_normals"].shape == (m, 3)
    assert a > 0
    assert sample["positive"].shape == (a, 3)
    assert sample["negative"].shape == (a, SMALL["n_hard"] + SMALL["n_uniform"])
    s = SMALL["n_sdf_near"] + SMALL["n_sdf_uniform"]
    assert sample["sdf_points"].shape == (s, 3) and sample["sdf"].shape == (s,)
    for key in ("points", "normals", "pool", "positive", "sdf_points", "sdf"):
        assert sample[key].dtype == np.float32, key
    for key in ("anchor", "negative"):
        assert sample[key].dtype == np.int64, key
        assert sample[key].min() >= 0 and sample[key].max() < m
    assert np.allclose(np.linalg.norm(sample["normals"], axis=1), 1.0, atol=1e-4)
    assert np.abs(sample["points"]).max() <= 0.9 + 1e-4
    # Positives lie on the surface.
    assert np.all(solid.distance(sample["positive"]) < 2e-3)
    # Negatives are not convex partners of their anchors (checked on a subset).
    pool, normals = sample["pool"].astype(np.float64), sample["pool_normals"].astype(np.float64)
    sub = np.arange(min(a, 16))
    anchors = sample["anchor"][sub]
    mask = nonconvex_mask(solid, pool[anchors], normals[anchors], pool[sample["negative"][sub]])
    assert mask.mean() > 0.98
    # SDF: sign matches the solid, magnitude clipped.
    inside = solid.contains(sample["sdf_points"].astype(np.float64))
    sdf = sample["sdf"]
    assert np.all(np.abs(sdf) <= 0.05 + 1e-6)
    assert np.all((sdf < 0) == inside)
    assert inside.any() and (~inside).any()


def test_prepare_procedural(proc_sample):
    mesh, sample = proc_sample
    _check_sample(sample, Solid.from_trimesh(closed_surface(mesh, watertight=False)))


def test_prepare_urdf(urdf_sample):
    mesh, sample = urdf_sample
    _check_sample(sample, Solid.from_trimesh(closed_surface(mesh, SMALL["resolution"])))


def test_prepare_deterministic(proc_sample):
    mesh, sample = proc_sample
    again = prepare_shape(mesh, seed=3, watertight=False, **SMALL)
    for key in KEYS:
        assert np.array_equal(sample[key], again[key]), key


# ---------------------------------------------------------------------------------- dataset
def test_prepare_dataset_resumable_and_failures(tmp_path, urdf_path):
    src = tmp_path / "src"
    src.mkdir()
    shutil.copy(urdf_path, src / urdf_path.name)
    (src / "zz_corrupt.obj").write_text("v 0 0 0\nv nan 1 0\nf 1 2 9\nthis is not an obj\n")
    out = tmp_path / "out"
    seen = []
    manifest = prepare_dataset(out, 3, urdf_root=src, seed=5, progress=lambda i, n, e: seen.append(e["name"]),
                               **SMALL)
    names = {"proc_00000", "proc_00001", "proc_00002", f"urdf_{urdf_path.stem}", "urdf_zz_corrupt"}
    assert set(manifest) == names and set(seen) == names
    on_disk = json.loads((out / "manifest.json").read_text())
    assert on_disk == manifest
    assert not manifest["urdf_zz_corrupt"]["ok"] and manifest["urdf_zz_corrupt"]["error"]
    for name in names - {"urdf_zz_corrupt"}:
        assert manifest[name]["ok"], manifest[name]
        assert manifest[name]["source"] in ("procedural", str(src / urdf_path.name))
        assert (out / f"{name}.npz").is_file()
    assert not list(out.glob("*.tmp")) and not list(out.glob(".*"))
    mtimes = {p.name: p.stat().st_mtime_ns for p in out.glob("*.npz")}

    seen.clear()
    again = prepare_dataset(out, 3, urdf_root=src, seed=5, progress=lambda i, n, e: seen.append(e["name"]),
                            **SMALL)
    assert seen == ["urdf_zz_corrupt"]  # only the failure is retried
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("*.npz")} == mtimes
    assert set(again) == names

    ds = TripletDataset(out, augment=True, seed=0)
    assert len(ds) == 4
    item = ds[0]
    assert set(KEYS) <= set(item)
    plain = TripletDataset(out, augment=False)[0]
    assert np.array_equal(plain["anchor"], item["anchor"])
    assert np.array_equal(TripletDataset(out, seed=0)[0]["points"], item["points"])


# ---------------------------------------------------------------------------------- augmentation
def test_rotation_keeps_pairs_consistent(proc_sample):
    _, sample = proc_sample
    rng = np.random.default_rng(0)
    for mode in ("so3", "up"):
        rot = aug.random_rotate(sample, rng, mode)
        for key in ("points", "pool", "positive", "sdf_points"):
            r0, r1 = np.linalg.norm(sample[key], axis=1), np.linalg.norm(rot[key], axis=1)
            assert np.allclose(r0, r1, atol=1e-5)
        d0 = np.linalg.norm(sample["pool"][sample["anchor"]] - sample["positive"], axis=1)
        d1 = np.linalg.norm(rot["pool"][rot["anchor"]] - rot["positive"], axis=1)
        assert np.allclose(d0, d1, atol=1e-5)
        n0 = np.einsum("ij,ij->i", sample["pool_normals"][sample["anchor"]],
                       sample["positive"] - sample["pool"][sample["anchor"]])
        n1 = np.einsum("ij,ij->i", rot["pool_normals"][rot["anchor"]],
                       rot["positive"] - rot["pool"][rot["anchor"]])
        assert np.allclose(n0, n1, atol=1e-5)
        assert np.array_equal(rot["sdf"], sample["sdf"])
    up = aug.random_rotate(sample, rng, "up")
    assert np.allclose(up["points"][:, 2], sample["points"][:, 2], atol=1e-6)


def test_partial_view_keeps_facing_subset(proc_sample):
    _, sample = proc_sample
    p, n = sample["points"], sample["normals"]
    view = np.array([0.0, 0.0, 1.0])
    keep = aug.visible_mask(p, n, view, threshold=0.1)
    assert 0 < keep.sum() < len(p)
    assert np.all(n[keep] @ view > 0.1)
    zkeep = aug.visible_mask(p, n, view, zbuffer=32)
    assert zkeep.sum() <= (n @ view > 0).sum() and np.all(n[zkeep] @ view > 0)
    q, m = aug.partial_view(p, n, np.random.default_rng(2), zbuffer=32)
    assert 0 < len(q) < len(p) and len(q) == len(m)
    # every kept point is one of the inputs
    assert np.isin(q.view([("", q.dtype)] * 3), p.view([("", p.dtype)] * 3)).all()


def test_input_corruptions(proc_sample):
    _, sample = proc_sample
    p, n = sample["points"], sample["normals"]
    rng = np.random.default_rng(0)
    q, m = aug.resample(p, n, rng, 5000)
    assert q.shape == m.shape == (5000, 3)
    q, m = aug.gaussian_noise(p, n, rng, 0.01)
    assert 0.005 < np.abs(q - p).std() < 0.02 and m is n
    q, m = aug.flip_normals(p, n, rng, 0.25)
    flipped = np.einsum("ij,ij->i", m, n) < 0
    assert 0.15 < flipped.mean() < 0.35 and np.array_equal(q, p)
    q, m = aug.splat_jitter(p, n, rng, tangent_scale=0.02, normal_scale=0.0)
    off = q.astype(np.float64) - p
    assert np.abs(np.einsum("ij,ij->i", off, n)).max() < 1e-4  # stays in the tangent plane
    assert np.linalg.norm(off, axis=1).mean() > 1e-3


def test_augment_sample_deterministic_and_clean(proc_sample):
    _, sample = proc_sample
    cfg = aug.AugmentConfig(p_count=1, p_noise=1, p_partial=1, p_flip=1, p_splat=1, count_low=500)
    a = aug.augment_sample(sample, np.random.default_rng(9), cfg)
    b = aug.augment_sample(sample, np.random.default_rng(9), cfg)
    c = aug.augment_sample(sample, np.random.default_rng(10), cfg)
    for key in KEYS:
        assert np.array_equal(a[key], b[key]), key
    assert not np.array_equal(a["pool"], c["pool"])
    assert np.allclose(np.linalg.norm(a["normals"], axis=1), 1.0, atol=1e-5)
    assert a["points"].dtype == np.float32 and len(a["points"]) == len(a["normals"])
    # supervision is only rotated, never corrupted: pairwise distances are preserved
    assert np.allclose(np.linalg.norm(a["pool"] - a["pool"][0], axis=1),
                       np.linalg.norm(sample["pool"] - sample["pool"][0], axis=1), atol=1e-5)
    assert np.array_equal(a["negative"], sample["negative"])
    fixed = aug.augment_sample(sample, np.random.default_rng(1), aug.AugmentConfig(n_points=1234))
    assert fixed["points"].shape == (1234, 3)


# ---------------------------------------------------------------------------------- compact files
def test_compact_sample_round_trip(tmp_path, proc_sample):
    _, sample = proc_sample
    save_sample(tmp_path / "full.npz", sample)
    save_sample(tmp_path / "compact.npz", sample, compact=True)
    full, compact = load_sample(tmp_path / "full.npz"), load_sample(tmp_path / "compact.npz")
    assert set(compact) == set(full) == set(KEYS)
    with np.load(tmp_path / "compact.npz") as raw:
        assert "pool" not in raw.files and raw["points"].dtype == np.float16
    for key in KEYS:
        assert compact[key].dtype == full[key].dtype, key
        assert compact[key].shape == full[key].shape, key
        if np.issubdtype(full[key].dtype, np.integer):
            assert np.array_equal(compact[key], full[key]), key
        else:  # float16: 11 significant bits; coordinates and distances are within [-1, 1]
            assert np.allclose(compact[key], full[key], rtol=1e-3, atol=1e-3), key
    assert np.array_equal(compact["pool"], compact["points"])
    assert compact["pool"] is not compact["points"]  # augmenting the input must not move the pool
    assert (tmp_path / "compact.npz").stat().st_size < 0.5 * (tmp_path / "full.npz").stat().st_size


def test_dataset_augments_each_pass_differently(tmp_path, proc_sample):
    _, sample = proc_sample
    save_sample(tmp_path / "a.npz", sample)
    ds = TripletDataset(tmp_path, augment=True, seed=3)
    first, again, second = ds.item(0, 0), ds.item(0, 0), ds.item(0, 1)
    assert all(np.array_equal(first[k], again[k]) for k in first)
    assert np.array_equal(ds[0]["points"], first["points"])  # __getitem__ is the current pass
    assert not np.allclose(first["points"][:50], second["points"][:50])
    assert not np.allclose(first["pool"], second["pool"])  # a new rotation moves the supervision too
    assert np.array_equal(first["anchor"], second["anchor"])
