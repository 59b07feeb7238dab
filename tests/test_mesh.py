"""Mesh loading: formats, cleaning, outward orientation on real meshes, sampling."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import pointcvx
from conftest import DATA
from pointcvx.io.mesh import clean_mesh, cloud_from_mesh, read_mesh, winding_signs
from pointcvx.io.sniff import detect

# Watertight, consistently wound dev meshes of every category: their true outward normals are
# known (the winding that gives a positive volume).
WATERTIGHT = [
    "cad/fandisk.obj", "cad/abc5.stl", "characters/dog.stl", "characters/knight.off",
    "objects/ant.ply", "objects/concave_box.obj", "objects/nut.ply", "scans/dragon_50k.ply",
    "scans/armadillo.obj", "scans/horse.ply",
]


def _true_mesh(rel: str) -> trimesh.Trimesh:
    path = DATA / "dev" / rel
    mesh = clean_mesh(read_mesh(path, detect(path).format))
    assert mesh.is_watertight and mesh.is_winding_consistent
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def _agreement(cloud, truth: trimesh.Trimesh) -> float:
    ref = truth.face_normals[cloud.face_index]
    return float((np.einsum("ij,ij->i", ref, cloud.normals) > 0).mean())


@pytest.mark.parametrize("rel", WATERTIGHT)
def test_watertight_file_normals_point_outward(rel):
    cloud = pointcvx.load(DATA / "dev" / rel, n_points=5000, normalize=False)
    assert _agreement(cloud, _true_mesh(rel)) >= 0.99


@pytest.mark.parametrize("rel", WATERTIGHT)
def test_badly_wound_mesh_is_repaired_by_ray_parity(rel):
    """Reverse 30% of faces at random and the whole mesh: the loader must recover the outside."""
    truth = _true_mesh(rel)
    rng = np.random.default_rng(1)
    faces = truth.faces[:, ::-1].copy()
    flip = rng.random(len(faces)) < 0.3
    faces[flip] = faces[flip][:, ::-1]
    bad = trimesh.Trimesh(truth.vertices, faces, process=False)
    cloud = cloud_from_mesh(bad, n_points=5000, seed=3)
    assert cloud.info["normals"].startswith("face normals, outward by ray parity")
    assert _agreement(cloud, truth) >= 0.99
    # Reported flips: every face that was wound inward, and no other.
    assert cloud.info["faces_flipped"] == int((~flip).sum())


def test_open_mug_normals_face_away_from_the_axis():
    """mug.obj is open (no lid) and not watertight: the wall's outer side faces away from the
    axis, its inner side toward it; ray parity must get both right."""
    cloud = pointcvx.load(DATA / "dev/objects/mug.obj", n_points=6000, normalize=False)
    assert not cloud.info["watertight"]
    p, n = cloud.points, cloud.normals
    r = np.linalg.norm(p[:, :2], axis=1)  # the body's axis is the z axis, radius 0.041
    wall = (np.abs(n[:, 2]) < 0.3) & (p[:, 1] < 0.04)  # the handle sits at y > 0.04
    outer = wall & (r > 0.039)
    inner = wall & (r < 0.036)
    radial = np.einsum("ij,ij->i", n[:, :2], p[:, :2] / r[:, None])
    assert outer.sum() > 500 and inner.sum() > 500
    assert (radial[outer] > 0).mean() > 0.99
    assert (radial[inner] < 0).mean() > 0.99


def test_winding_signs_make_neighbours_consistent():
    box = trimesh.creation.box()
    faces = box.faces.copy()
    faces[[0, 3, 5]] = faces[[0, 3, 5]][:, ::-1]
    bad = trimesh.Trimesh(box.vertices, faces, process=False)
    assert not bad.is_winding_consistent
    sign, labels, conflicted = winding_signs(bad)
    fixed = faces.copy()
    fixed[sign < 0] = fixed[sign < 0][:, ::-1]
    assert trimesh.Trimesh(box.vertices, fixed, process=False).is_winding_consistent
    assert len(np.unique(labels)) == 1 and not conflicted.any()


def test_sampling_is_seeded_and_area_weighted():
    mesh = trimesh.creation.box(extents=[4.0, 1.0, 1.0])
    a = cloud_from_mesh(mesh, n_points=20000, seed=7)
    b = cloud_from_mesh(mesh, n_points=20000, seed=7)
    c = cloud_from_mesh(mesh, n_points=20000, seed=8)
    np.testing.assert_array_equal(a.points, b.points)
    assert not np.array_equal(a.points, c.points)
    # The two 1x1 ends hold 2/18 of the area.
    ends = np.abs(np.abs(a.points[:, 0]) - 2.0) < 1e-9
    assert abs(ends.mean() - 2 / 18) < 0.01
    # Points lie on the box's faces: one coordinate at its half extent, the others within.
    half = np.array([2.0, 0.5, 0.5])
    on_face = np.isclose(np.abs(a.points), half, atol=1e-12).any(axis=1)
    assert on_face.all() and (np.abs(a.points) <= half + 1e-12).all()


@pytest.mark.parametrize("ext", ["obj", "ply", "stl", "off", "glb"])
def test_every_mesh_format_round_trips(tmp_path, ext):
    mesh = trimesh.creation.annulus(r_min=0.5, r_max=1.0, height=0.5)
    path = tmp_path / f"ring.{ext}"
    mesh.export(path)
    found = detect(path)
    assert found.modality == "mesh"
    cloud = pointcvx.load(path, n_points=3000)
    assert cloud.modality == "mesh" and len(cloud) == 3000
    v = np.asarray(cloud.mesh.vertices)  # the mesh's box is normalised to [-1, 1]^3
    lo, hi = v.min(axis=0), v.max(axis=0)
    assert np.isclose(max(hi - lo), 2.0) and np.allclose((lo + hi) / 2, 0, atol=1e-9)
    assert np.all(np.abs(cloud.points) <= 1 + 1e-9)
    # Outward: on the outer wall normals point away from the axis; inner wall toward it.
    back = cloud.in_input_units()
    r = np.linalg.norm(back.points[:, :2], axis=1)
    radial = np.einsum("ij,ij->i", back.normals[:, :2], back.points[:, :2] / r[:, None])
    wall = np.abs(back.normals[:, 2]) < 0.5
    assert (radial[wall & (r > 0.97)] > 0.9).all() and (radial[wall & (r < 0.53)] < -0.9).all()
    caps = ~wall
    assert (np.sign(back.normals[caps, 2]) == np.sign(back.points[caps, 2])).all()


def test_gltf_scene_is_flattened_with_transforms(tmp_path):
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box(), node_name="a")
    scene.add_geometry(trimesh.creation.box(), node_name="b",
                       transform=trimesh.transformations.translation_matrix([5.0, 0, 0]))
    path = tmp_path / "two.glb"
    scene.export(path)
    cloud = pointcvx.load(path, n_points=4000, normalize=False)
    lo, hi = cloud.bounds
    np.testing.assert_allclose(lo, [-0.5, -0.5, -0.5], atol=1e-6)
    np.testing.assert_allclose(hi, [5.5, 0.5, 0.5], atol=1e-6)
    assert cloud.info["components"] == 2
