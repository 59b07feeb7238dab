"""The per-shape feature field in numpy (pointcvx.features.field, ``features="optimize"`` and
``"fast"``): its hand-written backward pass, its triplets, its fit, decompositions with the fast
settings, and that it never imports torch."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from shapes import l_block, u_block

import pointcvx
from conftest import DATA, ROOT
from pointcvx import workers
from pointcvx.evaluate import evaluate
from pointcvx.features.field import (
    FAST_STEPS,
    FourierField,
    _draw_columns,
    fit_field,
    info_nce_grad,
    pool_info_nce_grad,
    sample_field_triplets,
)
from pointcvx.features.pairs import nonconvex_mask
from pointcvx.io.mesh import cloud_from_mesh
from pointcvx.solid import Solid

CHAIR = DATA / "vhacd61" / "chair.off"
TABLE = DATA / "vhacd61" / "table.off"


@pytest.fixture(scope="module")
def lshape():
    cloud = cloud_from_mesh(l_block(), n_points=6000, seed=0).normalized()
    return cloud, Solid.from_trimesh(cloud.mesh)


def _small_problem(dtype=np.float32):
    """A field, 60 points and index triplets into them (8 anchors, 8 positives, 5 negatives each)."""
    rng = np.random.default_rng(0)
    field = FourierField.initial(rng)
    field.params = [tuple(p.astype(dtype) for p in layer) for layer in field.params]
    x = rng.uniform(-1, 1, (60, 3)).astype(np.float32)
    anchor, positive, negative = rng.integers(0, 40, 8), np.arange(40, 48), rng.integers(0, 40, (8, 5))
    return field, x, anchor, positive, negative


def _loss_and_grads(field, x, anchor, positive, negative):
    feats, acts, norm = field._forward(x)
    loss, g_a, g_p, g_n = info_nce_grad(feats[anchor], feats[positive], feats[negative], 0.3)
    grad = np.zeros_like(feats)
    np.add.at(grad, anchor, g_a)
    np.add.at(grad, positive, g_p)
    np.add.at(grad, negative.ravel(), g_n.reshape(-1, field.dim))
    return loss, field._backward(grad, feats, acts, norm)


def test_backward_pass_matches_finite_differences():
    """Central differences (float64) of the loss w.r.t. sampled weights and biases of every layer
    equal the hand-written gradients."""
    field, x, anchor, positive, negative = _small_problem(np.float64)
    _, grads = _loss_and_grads(field, x, anchor, positive, negative)
    rng, eps = np.random.default_rng(1), 1e-6
    for i, layer in enumerate(field.params):
        for j, p in enumerate(layer):
            for flat in rng.choice(p.size, 6, replace=False):
                idx = np.unravel_index(flat, p.shape)
                old = p[idx]
                p[idx] = old + eps
                up = _loss_and_grads(field, x, anchor, positive, negative)[0]
                p[idx] = old - eps
                down = _loss_and_grads(field, x, anchor, positive, negative)[0]
                p[idx] = old
                numeric = (up - down) / (2 * eps)
                assert grads[i][j][idx] == pytest.approx(numeric, rel=1e-4, abs=1e-8), (i, j, idx)


def test_loss_and_gradients_match_torch():
    """The loss is pointcvx.features.loss.info_nce, and the backward pass equals torch's autograd
    on the same weights."""
    torch = pytest.importorskip("torch")
    from pointcvx.features.loss import info_nce

    field, x, anchor, positive, negative = _small_problem()
    loss, grads = _loss_and_grads(field, x, anchor, positive, negative)
    params = [[torch.tensor(p, requires_grad=True) for p in layer] for layer in field.params]
    h = torch.tensor(field._encode(x))
    for i, (w, b) in enumerate(params):
        h = h @ w + b
        h = torch.relu(h) if i < len(params) - 1 else h
    f = torch.nn.functional.normalize(h, dim=-1)
    expected = info_nce(f[anchor], f[positive], f[negative], tau=0.3)
    expected.backward()
    assert loss == pytest.approx(float(expected.detach()), rel=1e-5)
    for (gw, gb), (w, b) in zip(grads, params, strict=True):
        np.testing.assert_allclose(gw, w.grad.numpy(), rtol=1e-4, atol=1e-6)
        np.testing.assert_allclose(gb, b.grad.numpy(), rtol=1e-4, atol=1e-6)


def test_pool_loss_and_gradients_equal_the_per_triplet_ones():
    """The fit's step (pool_info_nce_grad: negatives as pool rows, their gradients gathered by
    one sparse product) equals info_nce_grad on the gathered features with every row's gradient
    scattered back onto the pool, duplicates and anchors among the negatives included."""
    rng = np.random.default_rng(2)
    pool = rng.normal(size=(50, 32))
    pool /= np.linalg.norm(pool, axis=1, keepdims=True)
    positive = rng.normal(size=(12, 32))
    positive /= np.linalg.norm(positive, axis=1, keepdims=True)
    anchor = rng.integers(0, 50, 12)
    negative = rng.integers(0, 50, (12, 9))
    negative[0, :3] = negative[0, 3]  # a negative drawn several times
    negative[1, 0] = anchor[2]  # an anchor that is another anchor's negative
    ref, g_a, g_p, g_n = info_nce_grad(pool[anchor], positive, pool[negative], 0.3)
    expected = np.zeros_like(pool)
    np.add.at(expected, anchor, g_a)
    np.add.at(expected, negative.ravel(), g_n.reshape(-1, 32))
    workers.set_threads(2)
    try:
        for chunks in (1, 2, 5):  # the anchors in runs on two threads, their sums joined
            loss, g_pool, g_pos = pool_info_nce_grad(pool, anchor, positive, negative, 0.3, chunks)
            assert loss == pytest.approx(ref, rel=1e-12)
            np.testing.assert_allclose(g_pool, expected, rtol=1e-10, atol=1e-14)
            np.testing.assert_allclose(g_pos, g_p, rtol=1e-10, atol=1e-14)
    finally:
        workers.set_threads(None)


def test_weighted_draws_follow_the_weights():
    rng = np.random.default_rng(0)
    w = np.array([[0.0, 1.0, 0.0, 3.0], [2.0, 0.0, 0.0, 0.0]])
    cols = _draw_columns(rng, w, 20000)
    assert set(np.unique(cols[0])) == {1, 3} and (cols[1] == 0).all()
    assert (cols[0] == 3).mean() == pytest.approx(0.75, abs=0.02)


def test_triplets_are_real_and_seeded(lshape):
    cloud, solid = lshape
    kw = dict(pool_size=4000, n_anchors=256, n_candidates=128, n_hard=32, n_uniform=32, seed=3)
    a = sample_field_triplets(solid, cloud.points, cloud.normals, **kw)
    b = sample_field_triplets(solid, cloud.points, cloud.normals, **kw)
    np.testing.assert_array_equal(a.negative, b.negative)
    np.testing.assert_array_equal(a.positive, b.positive)
    assert a.negative.shape == (len(a), 64) and 0 < len(a) <= 256 and len(a.pool) == 4000
    normals = cloud.normals[np.sort(np.random.default_rng(3).choice(len(cloud.points), 4000, replace=False))]
    rows = np.repeat(np.arange(len(a)), 8)
    cols = a.negative[:, ::8].ravel()
    mask = nonconvex_mask(solid, a.pool[a.anchor[rows]], normals[a.anchor[rows]], a.pool[cols][:, None])
    assert mask.all()  # every negative is a non-convex pair
    # Hard negatives (1/d^2 weights) lie nearer the positive than uniform ones, as with
    # sample_triplets (whose draws these vectorise).
    hard = sample_field_triplets(solid, cloud.points, cloud.normals, power=2.0, **kw)
    d = np.linalg.norm(hard.pool[hard.negative] - hard.positive[:, None], axis=2)
    assert d[:, 32:].mean() < 0.95 * d[:, :32].mean()


def test_fit_lowers_the_loss_separates_the_l_and_is_deterministic(lshape):
    cloud, solid = lshape
    t = sample_field_triplets(solid, cloud.points, cloud.normals, n_anchors=1024, seed=0)
    fits = []
    for threads in (1, 2):  # the step's chunks are fixed: any number of threads, one field
        workers.set_threads(threads)
        try:
            fits.append(fit_field(t, seed=5))
        finally:
            workers.set_threads(None)
    f1, f2 = fits
    assert len(f1.losses) == FAST_STEPS and np.mean(f1.losses[-10:]) < 0.7 * np.mean(f1.losses[:10])
    assert f1.losses == f2.losses
    feats = f1.features(cloud.points)
    np.testing.assert_array_equal(feats, f2.features(cloud.points))
    assert feats.shape == (len(cloud.points), 32) and feats.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(feats, axis=1), 1.0, atol=1e-5)
    back = cloud.normalization.inverse(cloud.points)
    bar = np.flatnonzero((back[:, 0] > 1.6) & (back[:, 2] < 1.0))[:200]
    cube = np.flatnonzero(back[:, 2] > 1.4)[:200]
    within = (feats[bar] @ feats[bar].T).mean() + (feats[cube] @ feats[cube].T).mean()
    assert 2 * (feats[bar] @ feats[cube].T).mean() < within - 0.1


def test_decompose_fast_known_answer_and_same_seed_same_hulls():
    a = pointcvx.decompose(u_block(), features="fast", threshold=0.1, n_points=6000, seed=0)
    b = pointcvx.decompose(u_block(), features="fast", threshold=0.1, n_points=6000, seed=0)
    assert len(a) == 3 and a.params["features"] == "fast"
    np.testing.assert_array_equal(a.labels, b.labels)
    for ha, hb in zip(a.hulls, b.hulls, strict=True):
        np.testing.assert_array_equal(ha.vertices, hb.vertices)


def test_fast_decomposes_a_real_chair_into_sensible_hulls():
    """vhacd61's chair: a handful of hulls under the threshold that cover the chair, with the
    feature progress reported from step 0 (before the convex pairs) to the last step."""
    import trimesh

    calls = []
    r = pointcvx.decompose(CHAIR, features="fast", n_points=6000, seed=0,
                           progress=lambda stage, done, total: calls.append((stage, done, total)))
    assert r.params["features"] == "fast"
    assert 3 <= len(r) <= 24 and r.max_concavity <= 0.1, r.summary()
    steps = [(done, total) for stage, done, total in calls if stage == "features"]
    assert steps[0] == (0, FAST_STEPS) and steps[-1] == (FAST_STEPS, FAST_STEPS)
    assert [d for d, _ in steps] == list(range(FAST_STEPS + 1))
    ev = evaluate(trimesh.load(CHAIR, force="mesh"), [h.vertices for h in r.hulls], n_samples=4000)
    assert ev["coverage"] > 0.97 and ev["concavity"] <= 0.12, ev


def test_cli_fast_never_imports_torch(tmp_path):
    """``python -m pointcvx decompose SHAPE --features fast`` writes its hulls without importing
    torch (``-X importtime`` lists every module the process imports)."""
    out = tmp_path / "table.obj"
    cmd = [sys.executable, "-X", "importtime", "-m", "pointcvx", "decompose", str(TABLE),
           "--features", "fast", "-o", str(out), "-q", "-n", "3000"]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    imported = {line.rsplit("|", 1)[-1].strip() for line in proc.stderr.splitlines()
                if line.startswith("import time:")}
    assert "pointcvx.features.field" in imported and "numpy" in imported
    torch = sorted(m for m in imported if m == "torch" or m.startswith("torch."))
    assert not torch, torch
    assert out.stat().st_size > 0 and out.read_text().count("\no ") >= 1


def test_unique_rows_equal_numpy_unique():
    from pointcvx.features.field import _unique_rows

    idx = np.random.default_rng(3).integers(0, 300, 1000)
    idx[:5] = 299  # the last row, several times
    used, inv = _unique_rows(idx, 300)
    ref_used, ref_inv = np.unique(idx, return_inverse=True)
    np.testing.assert_array_equal(used, ref_used)
    np.testing.assert_array_equal(inv, ref_inv)
    assert _unique_rows(np.zeros(0, np.int64), 4)[0].size == 0


def test_the_negatives_gradient_spread_equals_scipys_sparse_product_bit_for_bit(monkeypatch):
    """_spread builds the fit's sparse (pool x queries) product with scipy's compiled routines
    directly: the same float32 sums in the same order as csr_matrix((data, (rows, cols))) @ q,
    negatives drawn twice for one query included; so does its fallback, scipy's public path."""
    from scipy import sparse

    from pointcvx.features import field

    rng = np.random.default_rng(4)
    a, m, n, k = 40, 16, 90, 32
    negative = rng.integers(0, n, (a, m))
    negative[0, :4] = negative[0, 5]  # one negative four times over for one query
    weights = rng.normal(size=(2 * a, m + 1)).astype(np.float32)[:, 1:]  # a strided view, as in the fit
    queries = rng.normal(size=(2 * a, k)).astype(np.float32)
    rows = np.concatenate([negative, negative]).ravel()
    cols = np.repeat(np.arange(2 * a), m)
    ref = np.asarray(sparse.csr_matrix((weights.ravel(), (rows, cols)), shape=(n, 2 * a)) @ queries)
    got = field._spread(negative, weights, queries, n)
    assert got.dtype == np.float32 and got.shape == (n, k)
    np.testing.assert_array_equal(got, ref)
    loose = np.zeros((n, k))
    np.add.at(loose, rows, weights.ravel()[:, None].astype(np.float64) * queries[cols])
    np.testing.assert_allclose(got, loose, rtol=1e-4, atol=1e-4)  # and it is that sum
    monkeypatch.setattr(field, "_sparsetools", None)
    np.testing.assert_array_equal(field._spread(negative, weights, queries, n), ref)


def _reference_fit(triplets, steps, lr, seed, batch=128, negatives_per_step=64, tau=0.3,
                   betas=(0.9, 0.999), eps=1e-8):
    """fit_field with Adam written per weight and bias array, as it was before the parameters
    became views of one vector (the same step's gradients)."""
    from pointcvx.features.field import step_gradients

    rng = np.random.default_rng(seed)
    field = FourierField.initial(rng)
    enc_pool = field._encode(np.asarray(triplets.pool, np.float32))
    enc_pos = field._encode(np.asarray(triplets.positive, np.float32))
    moments = [[(np.zeros_like(p), np.zeros_like(p)) for p in layer] for layer in field.params]
    b1, b2 = betas
    for step in range(steps):
        rate = lr * 0.5 * (1.0 + math.cos(math.pi * step / steps))
        _, back = step_gradients(field, rng, enc_pool, enc_pos, triplets.anchor, triplets.negative,
                                 batch, negatives_per_step, tau)
        grads = [tuple(sum(g[i][j] for g in back) for j in range(2)) for i in range(len(back[0]))]
        t = step + 1
        for layer, layer_grads, layer_moments in zip(field.params, grads, moments, strict=True):
            for p, g, (mo, v) in zip(layer, layer_grads, layer_moments, strict=True):
                mo *= b1
                mo += (1 - b1) * g
                v *= b2
                v += (1 - b2) * g * g
                p -= (rate / (1 - b1**t)) * mo / (np.sqrt(v / (1 - b2**t)) + eps)
    return field


def test_the_fits_one_vector_adam_equals_adam_per_array_bit_for_bit(lshape):
    from threadpoolctl import threadpool_limits

    cloud, solid = lshape
    t = sample_field_triplets(solid, cloud.points, cloud.normals, n_anchors=512, seed=1)
    got = fit_field(t, steps=12, lr=3e-3, seed=2)
    with threadpool_limits(1):  # as the fit's products run: one BLAS thread
        ref = _reference_fit(t, steps=12, lr=3e-3, seed=2)
    for (w, b), (rw, rb) in zip(got.params, ref.params, strict=True):
        np.testing.assert_array_equal(w, rw)
        np.testing.assert_array_equal(b, rb)
    assert not np.array_equal(got.params[0][0], FourierField.initial(np.random.default_rng(2)).params[0][0])
