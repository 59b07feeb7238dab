"""The model's commands end to end: prepare a (tiny) training set, train a (tiny) model, resume,
and decompose with it as the feature source."""

from __future__ import annotations

import json

import pytest

from conftest import ROOT
from pointcvx.cli import main
from pointcvx.errors import EXIT_INPUT, EXIT_USAGE
from pointcvx.model.train import read_log


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    out = tmp_path_factory.mktemp("prepared")
    assert main(["prepare", str(out), "--procedural", "2", "--max-urdfs", "1", "-q"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert len(manifest) == 3 and all(e["ok"] for e in manifest.values())
    assert sum(1 for e in manifest.values() if e["source"].endswith(".obj")) == 1
    return out


def test_prepare_train_resume_and_decompose_with_the_model(tiny_data, tmp_path, capsys):
    run = tmp_path / "run"
    base = ["train", str(tiny_data), "-o", str(run), "--config", "tiny", "--points", "1024",
            "--device", "cpu"]
    assert main([*base, "--steps", "3"]) == 0
    assert "train: 100%" in capsys.readouterr().err  # the progress bar (quiet with -q)
    assert main([*base, "--steps", "5"]) == 0  # resumes from step 3
    log = read_log(run / "log.csv")
    assert [int(r["step"]) for r in log] == [1, 2, 3, 4, 5]
    # the same curves in TensorBoard (the dev extra installs it)
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    board = EventAccumulator(str(run / "tensorboard"))
    board.Reload()
    scalars = board.Scalars("train/contrastive")
    assert [e.step for e in scalars] == [1, 2, 3, 4, 5]
    assert [e.value for e in scalars] == pytest.approx([r["contrastive"] for r in log], rel=1e-5)
    capsys.readouterr()
    out = tmp_path / "hulls.obj"
    args = ["decompose", str(ROOT / "io" / "mug.obj"), "--features", "model", "--model",
            str(run / "last.pt"), "-n", "4000", "-o", str(out), "--json", "-t", "0.2", "-k", "12"]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert 1 <= summary["hulls"] <= 12 and out.exists()
    # in a loop over shapes the network is loaded once, and the results are the same
    import pointcvx
    from pointcvx.model.weights import cache_info

    opts = {"features": "model", "model": str(run / "last.pt"), "n_points": 4000, "threshold": 0.2,
            "max_hulls": 12}
    first = pointcvx.decompose(ROOT / "io" / "mug.obj", **opts)
    before = cache_info()
    again = pointcvx.decompose(ROOT / "io" / "mug.obj", **opts)
    after = cache_info()
    assert after.misses == before.misses and after.hits > before.hits  # not read again
    assert [h.vertices.tolist() for h in first.hulls] == [h.vertices.tolist() for h in again.hulls]
    two = pointcvx.decompose(ROOT / "io" / "mug.obj", views=2, **opts)
    assert two.params["views"] == 2 and 1 <= len(two.hulls) <= 12
    with pytest.raises(SystemExit) as bad:  # a bad value is bad usage
        main([*args, "--overwrite", "--views", "0"])
    assert bad.value.code == EXIT_USAGE
    assert "views must be at least 1, got 0" in capsys.readouterr().err

    # a new run warm-started from those weights: fresh step count, the same weights at step 0
    import torch

    from pointcvx.model.train import load_checkpoint

    tuned = tmp_path / "tuned"
    assert main(["train", str(tiny_data), "-o", str(tuned), "--config", "tiny", "--points", "1024",
                 "--device", "cpu", "--steps", "2", "--init", str(run / "last.pt"), "-q",
                 "--set", "train.lr=0"]) == 0
    assert [int(r["step"]) for r in read_log(tuned / "log.csv")] == [1, 2]
    a, b = load_checkpoint(run / "last.pt")["model"], load_checkpoint(tuned / "last.pt")["model"]
    assert b.keys() == a.keys() and all(torch.equal(a[k], b[k]) for k in a)  # lr 0: unchanged
    # weights of another architecture are refused with one line
    capsys.readouterr()
    assert main(["train", str(tiny_data), "-o", str(tmp_path / "other"), "--config", "tiny",
                 "--set", "head.feature_dim=8", "--steps", "1", "--init", str(run / "last.pt"),
                 "--points", "1024", "--device", "cpu", "-q"]) == EXIT_INPUT
    assert "do not fit" in capsys.readouterr().err


def test_train_and_model_errors(tmp_path, capsys):
    assert main(["train", str(tmp_path / "none"), "-o", str(tmp_path / "r"), "--steps", "1"]) == EXIT_INPUT
    assert "no such folder" in capsys.readouterr().err
    assert main(["train", str(tmp_path), "-o", str(tmp_path / "r"), "--steps", "1",
                 "--config", "huge"]) == EXIT_INPUT
    assert "unknown config" in capsys.readouterr().err
    assert main(["train", str(tmp_path), "-o", str(tmp_path / "r"), "--steps", "1",
                 "--init", str(tmp_path / "missing.pt")]) == EXIT_INPUT
    assert "no such checkpoint" in capsys.readouterr().err
    bogus = tmp_path / "bogus.pt"
    bogus.write_bytes(b"not a checkpoint")
    args = ["decompose", str(ROOT / "io" / "mug.obj"), "--features", "model", "--model", str(bogus),
            "-o", str(tmp_path / "h.obj")]
    assert main(args) == EXIT_INPUT
    assert "not a pointcvx model checkpoint" in capsys.readouterr().err


def test_prepare_compact_with_sizes_then_train_with_workers(tmp_path, capsys):
    import numpy as np

    out = tmp_path / "compact"
    args = ["prepare", str(out), "--procedural", "1", "--no-urdfs", "--points", "2000", "--anchors", "32",
            "--negatives", "16", "--sdf-samples", "300", "--compact", "-q"]
    assert main(args) == 0
    with np.load(out / "proc_00000.npz") as raw:
        assert raw["points"].shape == (2000, 3) and raw["points"].dtype == np.float16
        assert "pool" not in raw.files  # the pool is the input points: not stored twice
        assert 0 < len(raw["anchor"]) <= 32 and raw["negative"].shape == (len(raw["anchor"]), 16)
        assert raw["sdf"].shape == (300,)
    run = tmp_path / "run"
    assert main(["train", str(out), "-o", str(run), "--config", "tiny", "--points", "1024", "--device", "cpu",
                 "--steps", "2", "--workers", "1", "-q"]) == 0
    assert [int(r["step"]) for r in read_log(run / "log.csv")] == [1, 2]
    capsys.readouterr()
    assert main(["prepare", str(tmp_path / "bad"), "--negatives", "1", "-q"]) == EXIT_INPUT
    assert "--negatives must be at least 2" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
