"""Convex pairs, triplet sampling, the InfoNCE loss and per-shape feature fields."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from shapes import l_block

from pointcvx.features import info_nce, sample_triplets
from pointcvx.features.field import fit_field
from pointcvx.features.pairs import inward_directions, nonconvex_mask, positives
from pointcvx.io.mesh import cloud_from_mesh
from pointcvx.solid import Solid


@pytest.fixture(scope="module")
def lshape():
    cloud = cloud_from_mesh(l_block(), n_points=6000, seed=0).normalized()
    return cloud, Solid.from_trimesh(cloud.mesh)


def test_inward_directions_stay_in_the_hemisphere():
    rng = np.random.default_rng(0)
    n = rng.normal(size=(5000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d = inward_directions(n, rng)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    assert (np.einsum("ij,ij->i", d, n) <= -0.05 + 1e-9).all()


def test_positives_are_convex_partners_on_the_far_surface(lshape):
    cloud, solid = lshape
    rng = np.random.default_rng(1)
    pos, ok = positives(solid, cloud.points[:500], cloud.normals[:500], rng)
    assert ok.mean() > 0.99  # a closed solid: every inward ray leaves it somewhere
    assert np.abs(solid.distance(pos)).max() < 1e-4  # exit points lie on the surface
    mid = (cloud.points[:500][ok] + pos) / 2
    assert solid.contains(mid).mean() > 0.99  # and the segment stays inside


def test_nonconvex_mask_on_the_l(lshape):
    """Across the L's inner corner, segments leave the solid; within one box they don't."""
    cloud, solid = lshape
    scale = cloud.normalization
    # Points on the two faces meeting at the inner (concave) corner of the L, in input units:
    top_of_bar = scale.forward(np.array([[1.5, 0.5, 1.0]]))
    side_of_cube = scale.forward(np.array([[1.0, 0.5, 1.5]]))
    far_bottom = scale.forward(np.array([[1.5, 0.5, 0.0]]))
    up, left = np.array([[0, 0, 1.0]]), np.array([[1.0, 0, 0]])
    assert nonconvex_mask(solid, top_of_bar, up, side_of_cube[None])[0, 0]
    assert nonconvex_mask(solid, side_of_cube, left, top_of_bar[None])[0, 0]
    assert not nonconvex_mask(solid, top_of_bar, up, far_bottom[None])[0, 0]


def test_triplets_counts_seed_and_hardness(lshape):
    cloud, solid = lshape
    kw = dict(n_anchors=256, n_candidates=256, n_hard=32, n_uniform=32, seed=3)
    a = sample_triplets(solid, cloud.points, cloud.normals, **kw)
    b = sample_triplets(solid, cloud.points, cloud.normals, **kw)
    np.testing.assert_array_equal(a.negative, b.negative)
    np.testing.assert_array_equal(a.positive, b.positive)
    assert a.negative.shape == (len(a), 64) and 0 < len(a) <= 256
    # Every negative is a real non-convex pair.
    rows = np.repeat(np.arange(len(a)), 4)
    cols = a.negative[:, ::16].ravel()
    mask = nonconvex_mask(solid, a.pool[a.anchor[rows]], cloud.normals[a.anchor[rows]],
                          a.pool[cols][:, None])
    assert mask.all()
    # Hard negatives (1/d^2 weights) lie nearer the positive than uniform ones on average.
    hard = sample_triplets(solid, cloud.points, cloud.normals, power=2.0, **kw)
    d = np.linalg.norm(hard.pool[hard.negative] - hard.positive[:, None], axis=2)
    assert d[:, 32:].mean() < 0.95 * d[:, :32].mean()


def test_convex_shape_has_no_triplets():
    import trimesh

    cloud = cloud_from_mesh(trimesh.creation.icosphere(3), n_points=3000).normalized()
    t = sample_triplets(Solid.from_trimesh(cloud.mesh), cloud.points, cloud.normals,
                        n_anchors=128, n_candidates=128, n_hard=8, n_uniform=8)
    assert len(t) == 0


def test_info_nce_prefers_the_positive():
    torch.manual_seed(0)
    a = torch.randn(64, 16)
    negs = torch.randn(64, 32, 16)
    good = info_nce(a, a + 0.01 * torch.randn(64, 16), negs, tau=0.1)
    bad = info_nce(a, torch.randn(64, 16), negs, tau=0.1)
    assert good < 0.1 < bad
    # symmetric in anchor and positive
    p = torch.randn(64, 16)
    torch.testing.assert_close(info_nce(a, p, negs), info_nce(p, a, negs))


def test_field_optimisation_lowers_the_loss_and_is_deterministic(lshape):
    """The per-shape field at the settings of ``features="optimize"`` (learning rate 3e-3,
    cosine decay), here in 120 steps on triplets of the reference sampler."""
    from pointcvx.pipeline import OPTIMIZE_LR

    cloud, solid = lshape
    t = sample_triplets(solid, cloud.points, cloud.normals, n_anchors=512, n_candidates=256,
                        n_hard=32, n_uniform=32, seed=0)
    f1 = fit_field(t, steps=120, lr=OPTIMIZE_LR, seed=5)
    f2 = fit_field(t, steps=120, lr=OPTIMIZE_LR, seed=5)
    assert np.mean(f1.losses[-10:]) < 0.7 * np.mean(f1.losses[:10])
    x = cloud.points[:1000]
    np.testing.assert_array_equal(f1.features(x), f2.features(x))
    feats = f1.features(x)
    assert feats.shape == (1000, f1.dim) and feats.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(feats, axis=1), 1.0, atol=1e-5)
    # The features separate the L's two convex pieces better than chance: points deep in the bar
    # and points deep in the cube are less similar than points within each.
    back = cloud.normalization.inverse(cloud.points)
    bar = np.flatnonzero((back[:, 0] > 1.6) & (back[:, 2] < 1.0))[:200]
    cube = np.flatnonzero(back[:, 2] > 1.4)[:200]
    f = f1.features(cloud.points)
    within = (f[bar] @ f[bar].T).mean() + (f[cube] @ f[cube].T).mean()
    across = 2 * (f[bar] @ f[cube].T).mean()
    assert across < within - 0.1
