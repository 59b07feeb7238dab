"""The trained model shipped in the package: size, architecture, determinism, and that it has
learned convexity (held-out shapes' convex pairs score above their non-convex ones)."""

from __future__ import annotations

import numpy as np
import pytest
from shapes import torus, u_block

import pointcvx
from conftest import ROOT
from pointcvx.features import sample_triplets
from pointcvx.model.config import ModelConfig
from pointcvx.model.network import FeatureNet, count_parameters
from pointcvx.model.source import ModelFeatureSource, load_model
from pointcvx.model.train import load_checkpoint, seed_everything
from pointcvx.model.weights import BUNDLED_MODEL, bundled_model_path
from pointcvx.solid import Solid


def pair_accuracy(source, triplets) -> float:
    """Fraction of (anchor, negative) pairs where the anchor is more similar to its positive."""
    fa = source.features(triplets.pool[triplets.anchor])
    fp = source.features(triplets.positive)
    fn = source.features(triplets.pool)[triplets.negative]  # (a, k, d)
    pos = np.sum(fa * fp, axis=1)
    neg = np.einsum("ad,akd->ak", fa, fn)
    return float(np.mean(pos[:, None] > neg))


@pytest.fixture(scope="module")
def shapes():
    out = {}
    for name, mesh in (("u_block", u_block()), ("torus", torus())):
        cloud = pointcvx.io.from_trimesh(mesh, n_points=8000, seed=0).normalized()
        solid = Solid(np.asarray(cloud.mesh.vertices), np.asarray(cloud.mesh.faces))
        out[name] = (cloud, sample_triplets(solid, cloud.points, cloud.normals, n_anchors=512,
                                            n_candidates=256, n_hard=32, n_uniform=32, seed=0))
    return out


def test_bundled_weights_ship_and_load():
    assert bundled_model_path() == BUNDLED_MODEL and BUNDLED_MODEL.is_file()
    assert BUNDLED_MODEL.stat().st_size <= 25e6
    state = load_checkpoint(BUNDLED_MODEL)
    assert state["optimizer"] is None and state["step"] > 0
    assert state["config"].to_dict() | {"train": None, "name": None} == (
        ModelConfig.preset("small").to_dict() | {"train": None, "name": None})
    net = load_model(BUNDLED_MODEL)
    assert 1e6 <= count_parameters(net) <= 10e6 and not net.training


def test_bundled_model_has_learned_convexity(shapes):
    net = load_model(BUNDLED_MODEL)
    seed_everything(0)
    untrained = FeatureNet(ModelConfig.preset("small")).eval()
    for name, (cloud, triplets) in shapes.items():
        trained = pair_accuracy(ModelFeatureSource(net, cloud.points, cloud.normals), triplets)
        chance = pair_accuracy(ModelFeatureSource(untrained, cloud.points, cloud.normals), triplets)
        assert trained > 0.8 and trained > chance + 0.15, (name, trained, chance)


def test_bundled_model_is_deterministic(shapes):
    cloud, triplets = shapes["u_block"]
    a = ModelFeatureSource(load_model(BUNDLED_MODEL), cloud.points, cloud.normals).features(triplets.pool)
    b = ModelFeatureSource(load_model(BUNDLED_MODEL), cloud.points, cloud.normals).features(triplets.pool)
    assert np.array_equal(a, b)
    first = pointcvx.decompose(u_block(), features="model", n_points=6000, threshold=0.1, max_hulls=8)
    again = pointcvx.decompose(u_block(), features="model", n_points=6000, threshold=0.1, max_hulls=8)
    assert first.params["features"] == "model" and first.params["model"] is None
    assert [h.vertices.tolist() for h in first.hulls] == [h.vertices.tolist() for h in again.hulls]
    assert 3 <= len(first.hulls) <= 8  # a U is three boxes


# ------------------------------------------------------------------ inference in numpy
def test_the_checkpoint_reads_without_torch_as_torch_reads_it():
    from pointcvx.model.numpy_net import read_checkpoint

    ours, theirs = read_checkpoint(BUNDLED_MODEL), load_checkpoint(BUNDLED_MODEL)
    assert ours["step"] == theirs["step"] and ours["config"] == theirs["config"].to_dict()
    assert list(ours["model"]) == list(theirs["model"])
    for name, tensor in theirs["model"].items():
        assert np.array_equal(ours["model"][name], tensor.numpy()), name


def test_numpy_inference_matches_the_torch_network(shapes):
    """The numpy forward pass and plane queries give torch's planes and features to float32
    round-off, on the shapes and on a real splat (measured: planes within 5e-6 of values up to
    3, feature cosines at least 0.9999996)."""
    from pointcvx.model.numpy_net import NumpyFeatureNet, NumpyModelSource

    net, ref = NumpyFeatureNet.load(BUNDLED_MODEL), load_model(BUNDLED_MODEL)
    splat = pointcvx.pipeline.as_cloud(ROOT / "io" / "mug_splat.ply", n_points=8000, seed=0)
    clouds = [cloud for cloud, _ in shapes.values()] + [splat]
    for cloud in clouds:
        ours = NumpyModelSource(net, cloud.points, cloud.normals)
        theirs = ModelFeatureSource(ref, cloud.points, cloud.normals)
        planes = theirs.planes[0][0].numpy()
        assert np.abs(ours.planes - planes).max() <= 1e-5 * max(1.0, np.abs(planes).max())
        a, b = ours.features(cloud.points), theirs.features(cloud.points)
        assert a.dtype == np.float32 and a.shape == b.shape == (len(cloud), net.dim)
        assert (a * b).sum(axis=1).min() > 0.99999


def test_a_checkpoint_with_anything_but_tensors_is_refused(tmp_path):
    """The numpy reader resolves only what a state dict holds: a pickle that names any other
    callable (os.system here) is refused before it runs, as torch's weights_only load does."""
    import zipfile

    from pointcvx import InputError
    from pointcvx.model.weights import load_cached_model

    path = tmp_path / "evil.pt"
    payload = b"cos\nsystem\n(S'echo pwned > " + str(tmp_path / "ran").encode() + b"'\ntR."
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("archive/data.pkl", payload)
    with pytest.raises(InputError, match="not a pointcvx model checkpoint"):
        load_cached_model(path)
    assert not (tmp_path / "ran").exists()


@pytest.mark.parametrize("views", [1, 2])
def test_a_checkpoint_whose_weights_do_not_fit_its_config_is_an_input_error(tmp_path, views):
    """A checkpoint that reads but whose tensors do not fit the network its config describes
    (one missing, one cut short), or that holds NaN weights (whose features reached the split's
    k-means and failed there), is the user's bad input: a one-line InputError naming the file
    from the numpy inference (one view) and from the torch network (the views' ensemble), and
    exit 1 from the command; it was an internal error."""
    import torch

    from pointcvx import InputError
    from pointcvx.cli import EXIT_INPUT, main

    state = torch.load(BUNDLED_MODEL, weights_only=True)
    name = "encoder.mlp.2.weight"
    cut = {**state, "model": {**state["model"], name: state["model"][name][:, :-3]}}
    gone = {**state, "model": {k: v for k, v in state["model"].items() if k != name}}
    nan = {**state, "model": {**state["model"], name: state["model"][name] * float("nan")}}
    cloud = pointcvx.io.from_trimesh(u_block(), n_points=3000, seed=0)  # concave: features needed
    unfit = r"its weights do not fit its config"
    for tag, bad, why in (("cut", cut, unfit), ("gone", gone, unfit),
                          ("nan", nan, rf"1 weight tensors hold NaN or infinite values: {name}")):
        path = tmp_path / f"{tag}.pt"
        torch.save(bad, path)
        with pytest.raises(InputError, match=rf"{tag}\.pt: not a pointcvx model checkpoint \({why}"):
            pointcvx.decompose(cloud, features="model", model=path, views=views)
    splat = ROOT / "io" / "mug_splat.ply"
    out = tmp_path / "x.obj"
    args = ["decompose", str(splat), "--model", str(path), "--views", str(views), "-o", str(out), "-q"]
    assert main(args) == EXIT_INPUT and not out.exists()
