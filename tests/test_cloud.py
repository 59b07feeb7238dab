"""The oriented point cloud type: validation, normalisation, conversions."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest
import trimesh

from pointcvx import InputError, Normalization, OrientedCloud
from pointcvx.io import from_numpy, from_open3d, from_trimesh, save_cloud


def _sphere(n=2000, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    return p * 3.0 + [10.0, -2.0, 5.0], p


def test_normalization_round_trip_and_unit_cube():
    pts, nrm = _sphere()
    cloud = OrientedCloud(pts, nrm * 2.0)
    np.testing.assert_allclose(np.linalg.norm(cloud.normals, axis=1), 1.0)
    unit = cloud.normalized()
    lo, hi = unit.bounds
    assert np.isclose((hi - lo).max(), 2.0) and np.allclose((hi + lo) / 2, 0.0)
    np.testing.assert_allclose(unit.normalization.inverse(unit.points), pts, atol=1e-12)
    np.testing.assert_allclose(unit.in_input_units().points, pts, atol=1e-12)
    twice = unit.normalized()  # already unit: composition keeps the way back
    np.testing.assert_allclose(twice.normalization.inverse(twice.points), pts, atol=1e-12)


def test_normalization_matrix_matches_forward():
    t = Normalization(np.array([1.0, 2.0, 3.0]), 4.0)
    x = np.random.default_rng(0).normal(size=(10, 3))
    h = np.c_[x, np.ones(10)] @ t.as_matrix().T
    np.testing.assert_allclose(h[:, :3], t.forward(x))


def test_resample_is_deterministic_and_caps():
    pts, nrm = _sphere(5000)
    cloud = OrientedCloud(pts, nrm)
    a, b = cloud.resample(1000, seed=3), cloud.resample(1000, seed=3)
    np.testing.assert_array_equal(a.points, b.points)
    assert len(a) == 1000 and cloud.resample(10**6) is cloud
    assert not np.array_equal(a.points, cloud.resample(1000, seed=4).points)


@pytest.mark.parametrize(
    "points, message",
    [
        (np.zeros((0, 3)), "empty"),
        (np.ones((5, 2)), "shape"),
        (np.array([[0, 0, 0], [1, np.nan, 0], [0, 1, 0], [0, 0, 1]]), "NaN"),
        (np.array([[0, 0, 0], [1, np.inf, 0], [0, 1, 0], [0, 0, 1]]), "NaN or infinite"),
    ],
)
def test_bad_arrays_raise_input_error(points, message):
    with pytest.raises(InputError, match=message):
        OrientedCloud(points, np.ones_like(points))


def test_degenerate_arrays_raise_input_error():
    with pytest.raises(InputError, match="identical"):
        from_numpy(np.ones((10, 3)), np.ones((10, 3)))
    line = np.linspace(0, 1, 50)[:, None] * [1.0, 2.0, 3.0]
    with pytest.raises(InputError, match="collinear"):
        from_numpy(line, np.ones((50, 3)))


def test_zero_normals_rejected():
    pts, nrm = _sphere(10)
    nrm[3] = 0
    with pytest.raises(InputError, match="zero length"):
        OrientedCloud(pts, nrm)


def test_open3d_and_trimesh_conversions():
    pts, nrm = _sphere(500)
    colors = np.random.default_rng(0).random((500, 3))
    cloud = OrientedCloud(pts, nrm, colors=colors)
    pc = cloud.to_open3d()
    np.testing.assert_allclose(np.asarray(pc.points), pts)
    np.testing.assert_allclose(np.asarray(pc.normals), nrm)
    back = from_open3d(pc)
    np.testing.assert_allclose(back.points, pts)
    assert (np.einsum("ij,ij->i", back.normals, nrm) > 0.99).mean() > 0.99
    tpc = cloud.to_trimesh()
    assert isinstance(tpc, trimesh.PointCloud)
    np.testing.assert_allclose(tpc.vertices, pts)
    np.testing.assert_allclose(tpc.metadata["normals"], nrm)


def test_from_open3d_mesh_and_trimesh_keep_mesh_and_faces():
    box = o3d.geometry.TriangleMesh.create_box(2.0, 1.0, 1.0)
    cloud = from_open3d(box, n_points=3000, seed=1)
    assert cloud.mesh is not None and cloud.face_index.shape == (3000,)
    # outward: normals point away from the box centre
    c = np.array([1.0, 0.5, 0.5])
    assert (np.einsum("ij,ij->i", cloud.normals, cloud.points - c) > 0).all()
    m = cloud.to_open3d_mesh()
    assert len(m.triangles) == 12
    cloud2 = from_trimesh(trimesh.creation.icosphere(), n_points=1000)
    np.testing.assert_allclose(np.linalg.norm(cloud2.points, axis=1), 1.0, atol=0.05)


def test_save_ply_round_trip(tmp_path):
    from plyfile import PlyData

    pts, nrm = _sphere(300)
    save_cloud(OrientedCloud(pts, nrm), tmp_path / "c.ply")
    v = PlyData.read(str(tmp_path / "c.ply"))["vertex"]
    np.testing.assert_allclose(np.c_[v["x"], v["y"], v["z"]], pts, atol=1e-5)
    np.testing.assert_allclose(np.c_[v["nx"], v["ny"], v["nz"]], nrm, atol=1e-6)
    assert not list(tmp_path.glob(".c.ply*"))  # no temporary left behind
