"""Every real shape in shared/data/dev loads, through the API and through the CLI, into an
oriented cloud with unit normals in [-1, 1]^3."""

from __future__ import annotations

import json

import numpy as np
import pytest

import pointcvx
from conftest import dev_files
from pointcvx.cli import main

FILES = dev_files()
MODALITY = {"objects": {"mesh"}, "characters": {"mesh"}, "scans": {"mesh"},
            "cad": {"mesh", "cad"}, "splats": {"splat"}}


def test_dev_data_is_all_there():
    assert len(FILES) >= 80
    assert {f.parent.name for f in FILES} == set(MODALITY)


@pytest.mark.parametrize("path", FILES, ids=[f"{f.parent.name}/{f.name}" for f in FILES])
def test_dev_file_loads_through_api_and_cli(path, tmp_path, capsys):
    cloud = pointcvx.load(path, n_points=2000, seed=1)
    assert cloud.modality in MODALITY[path.parent.name]
    assert 100 <= len(cloud) <= 2000
    np.testing.assert_allclose(np.linalg.norm(cloud.normals, axis=1), 1.0, atol=1e-6)
    ref = cloud.points if cloud.mesh is None else np.asarray(cloud.mesh.vertices)
    lo, hi = ref.min(axis=0), ref.max(axis=0)
    assert np.isclose((hi - lo).max(), 2.0, atol=1e-6) and np.allclose(hi + lo, 0.0, atol=1e-6)
    assert np.all(np.abs(cloud.points) <= 1 + 1e-6)
    back = cloud.normalization.inverse(cloud.points)
    assert np.isfinite(back).all()

    out = tmp_path / "cloud.ply"
    assert main(["info", str(path), "-n", "2000", "--seed", "1", "-o", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["modality"] == cloud.modality and report["points"] == len(cloud)
    from plyfile import PlyData

    v = PlyData.read(str(out))["vertex"]
    normals = np.c_[v["nx"], v["ny"], v["nz"]]
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    # The CLI writes input units: same points as the API's cloud mapped back (same seed).
    np.testing.assert_allclose(np.c_[v["x"], v["y"], v["z"]], back, rtol=1e-5,
                               atol=1e-5 * float(np.abs(back).max()))
