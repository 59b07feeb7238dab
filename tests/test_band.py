"""Splat points moved to the middle of their surface band (pointcvx.scene.band): the band gets
thin, the surface stays where it was, and the hulls of a splat sit on its true surface."""

from __future__ import annotations

import numpy as np
import pytest

import pointcvx
from conftest import load_tool
from pointcvx.scene.band import flatten_band


def sphere(n: int, noise: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n, 3) noisy points of the unit sphere, their (n, 3) true normals and (n,) noise."""
    rng = np.random.default_rng(seed)
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    e = rng.normal(0.0, noise, n)
    return nrm * (1.0 + e)[:, None], nrm, e


def test_a_noisy_sphere_gets_a_thin_band_at_the_same_radius():
    pts, nrm, e = sphere(20000, 0.01)
    flat = flatten_band(pts, nrm)
    r = np.linalg.norm(flat, axis=1)
    assert np.std(r - 1.0) < 0.35 * np.std(e)  # 16 neighbours: about 1/4 of the noise is left
    assert abs(np.mean(r) - 1.0) < 1e-3  # the middle of the band, not its edge
    # Only the normal offset moves: each point stays on its own ray from the centre.
    cos = np.einsum("ij,ij->i", flat / r[:, None], nrm)
    assert cos.min() > 1 - 1e-12
    # Hulls of the band sat on its outer edge; flattened, at the surface.
    assert np.percentile(np.linalg.norm(pts, axis=1), 99) > 1.02
    assert np.percentile(r, 99) < 1.01


def test_moves_are_capped_and_degenerate_input_is_returned_whole():
    pts, nrm, _ = sphere(2000, 0.0)
    cloud = np.vstack([pts, [[0.0, 0.0, 3.0]]])  # a far outlier keeps its place within the cap
    normals = np.vstack([nrm, [[0.0, 0.0, 1.0]]])
    flat = flatten_band(cloud, normals, limit=0.05)
    assert np.abs(flat - cloud).max() <= 0.05 + 1e-12
    assert np.allclose(flatten_band(pts[:2], nrm[:2]), pts[:2])
    np.testing.assert_allclose(flatten_band(pts, nrm), flatten_band(pts, nrm))  # deterministic


@pytest.fixture(scope="module")
def synthetic_splat(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth")
    assert load_tool("synthetic_splats").main([str(out), "--shapes", "1", "--seed", "5"]) == 0
    return out / "splats" / "solid_00.ply", out / "truth" / "solid_00.obj"


def test_a_splats_hulls_sit_on_its_true_surface_by_default(synthetic_splat):
    """Default (band "auto" on a splat) against ``band="off"``: the hull vertices outside the
    true solid are closer to it (0.57x), with no more hulls and the reconstruction against the
    true mesh within 5 %, in the mean of two seeds. One seed's split path is noise: over seeds
    0-5 the band's 3-5 hulls reconstruct 0.98x the 4-5 without it, per seed 0.91x-1.05x."""
    import trimesh
    from scipy.spatial import cKDTree

    from pointcvx.evaluate import evaluate
    from pointcvx.solid import Solid

    splat, truth = synthetic_splat
    mesh = trimesh.load(truth, force="mesh")
    solid = Solid.from_trimesh(mesh)
    surface = cKDTree(trimesh.sample.sample_surface(mesh, 100000, seed=0)[0])
    rows = {}
    for band in ("auto", "off"):
        runs = []
        for seed in (0, 1):
            result = pointcvx.decompose(splat, band=band, seed=seed, n_points=8000, features="fast")
            assert result.params["band"] == band
            verts = np.vstack([h.vertices for h in result.hulls])
            out = verts[~solid.contains(verts)]
            runs.append((surface.query(out)[0].mean(), evaluate(mesh, [h.vertices for h in result.hulls],
                                                                n_samples=5000)["reconstruction"],
                         len(result.hulls)))
        rows[band] = np.mean(runs, axis=0)
    assert rows["auto"][0] < 0.7 * rows["off"][0], rows
    assert rows["auto"][1] < 1.05 * rows["off"][1] and rows["auto"][2] <= rows["off"][2], rows
