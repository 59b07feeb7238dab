"""Watertight conversion of triangle soups and proxy solids of oriented point clouds."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import pointcvx
from conftest import DATA, SAMPLES
from pointcvx.errors import InputError
from pointcvx.solid import (
    Solid,
    closed_mesh_solid,
    solid_for,
    solid_from_cloud,
    surface_from_cloud,
    watertight_mesh,
)


def box_with_hole() -> trimesh.Trimesh:
    box = trimesh.creation.box((1.6, 1.6, 0.8))
    return box.difference(trimesh.creation.cylinder(0.4, 2.0, sections=64))


# name -> (mesh, points inside, points outside)
SHAPES = {
    "sphere": (
        lambda: trimesh.creation.icosphere(4),
        [[0, 0, 0], [0, 0, 0.9], [0.6, -0.6, 0.3]],
        [[0, 0, 1.1], [0.8, 0.8, 0], [-1.2, 0, 0]],
    ),
    "torus": (
        lambda: trimesh.creation.torus(0.65, 0.3),
        [[0.65, 0, 0], [0, -0.65, 0.2], [-0.5, 0.4, 0]],
        [[0, 0, 0], [1.0, 0, 0], [0.65, 0, 0.35]],
    ),
    "box_with_hole": (
        box_with_hole,
        [[0.6, 0.6, 0], [-0.7, 0.0, 0.3], [0.0, 0.5, -0.3]],
        [[0, 0, 0], [0.2, -0.2, 0.1], [0.6, 0.6, 0.5]],
    ),
}


def volume_iou(a: Solid, b: Solid, n: int = 100_000, seed: int = 0) -> float:
    """Monte Carlo volume IoU of two solids in [-1.05, 1.05]^3."""
    p = np.random.default_rng(seed).uniform(-1.05, 1.05, size=(n, 3))
    ia, ib = a.contains(p), b.contains(p)
    return float((ia & ib).sum() / max((ia | ib).sum(), 1))


def sphere_with_holes(fraction: float = 0.1, seed: int = 0) -> tuple[trimesh.Trimesh, float]:
    sphere = trimesh.creation.icosphere(4)
    keep = np.random.default_rng(seed).random(len(sphere.faces)) >= fraction
    return trimesh.Trimesh(sphere.vertices, sphere.faces[keep], process=False), sphere.volume


# ------------------------------------------------------------------------- watertight_mesh
@pytest.mark.parametrize("name", sorted(SHAPES))
def test_watertight_mesh_analytic(name):
    make, inside, outside = SHAPES[name]
    mesh = make()
    out = watertight_mesh(mesh, resolution=128)
    assert out.is_watertight and out.is_winding_consistent
    assert out.volume > 0
    # Measured: within 0.1 % for all three at 128^3.
    assert out.volume == pytest.approx(mesh.volume, rel=0.02)
    solid = Solid.from_trimesh(out)
    assert solid.contains(np.array(inside, dtype=float)).all()
    assert not solid.contains(np.array(outside, dtype=float)).any()


def test_watertight_mesh_keeps_input_coordinates():
    mesh = trimesh.creation.box((30.0, 10.0, 20.0))
    mesh.apply_translation([100.0, -50.0, 7.0])
    out = watertight_mesh(mesh, resolution=64)
    assert np.allclose(out.bounds, mesh.bounds, atol=30.0 / 50)
    assert out.volume == pytest.approx(mesh.volume, rel=0.03)


def test_watertight_mesh_inverted_and_shuffled_winding():
    mesh = trimesh.creation.icosphere(3)
    faces = mesh.faces.copy()
    faces[::3] = faces[::3, ::-1]  # inconsistent winding: sign must not come from the faces
    out = watertight_mesh((mesh.vertices, faces), resolution=96)
    assert out.is_watertight and out.volume == pytest.approx(mesh.volume, rel=0.02)


def test_watertight_mesh_seals_holes():
    mesh, true_volume = sphere_with_holes(0.1)
    assert not mesh.is_watertight
    out = watertight_mesh(mesh, resolution=128)
    assert out.is_watertight
    # Measured -0.4 %: the plugged holes leave small dents.
    assert out.volume == pytest.approx(true_volume, rel=0.03)


def test_watertight_mesh_triangle_soup():
    """A soup: every triangle with its own vertices (all edges open until merged)."""
    sphere = trimesh.creation.icosphere(3)
    tri = sphere.triangles.reshape(-1, 3)
    soup = trimesh.Trimesh(tri, np.arange(len(tri)).reshape(-1, 3), process=False)
    out = watertight_mesh(soup, resolution=96)
    assert out.is_watertight and out.volume == pytest.approx(sphere.volume, rel=0.02)


def test_watertight_mesh_open_sheet_becomes_slab():
    square = trimesh.Trimesh(
        [[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]], process=False
    )
    resolution = 64
    out = watertight_mesh(square, resolution=resolution)
    assert out.is_watertight and out.volume > 0
    # A slab of half-thickness `level` (0.75 voxel by default) around the square.
    h = 2.0 / (resolution - 1 - 2 * 5)
    assert out.volume == pytest.approx(4.0 * 2 * 0.75 * h, rel=0.3)
    assert Solid.from_trimesh(out).contains(np.array([[0.0, 0.0, 0.0]])).all()


@pytest.mark.parametrize("name", ["KitchenPot.obj", "Kettle.obj"])
def test_watertight_mesh_real_soups(name):
    path = DATA / "dev" / "objects" / name
    if not path.is_file():
        pytest.fail(f"{path} not available: the shared data must sit beside the checkout")
    cloud = pointcvx.load(path, normalize=True, n_points=2000)
    out = watertight_mesh(cloud.mesh, resolution=128)
    assert out.is_watertight and out.is_winding_consistent
    assert out.volume > 0
    lo, hi = cloud.mesh.bounds
    assert np.allclose(out.bounds, [lo, hi], atol=0.05)
    # The input surface lies inside the result or on it, within a fraction of a voxel (thin
    # walls become slabs around it). Measured: all within 0.45 voxel.
    solid = Solid.from_trimesh(out)
    h = 2.0 / (128 - 1 - 2 * 5)
    ok = solid.contains(cloud.points) | (solid.distance(cloud.points) < 0.6 * h)
    assert ok.mean() >= 0.999


def test_watertight_mesh_errors():
    with pytest.raises(InputError):
        watertight_mesh((np.zeros((3, 3)), np.array([[0, 1, 2]])))
    with pytest.raises(InputError):
        watertight_mesh((np.full((3, 3), np.nan), np.array([[0, 1, 2]])))
    with pytest.raises(InputError):
        watertight_mesh((np.eye(3), np.array([[0, 1, 5]])))
    with pytest.raises(InputError):
        watertight_mesh(trimesh.creation.icosphere(1), resolution=12)


def test_watertight_mesh_deterministic():
    mesh, _ = sphere_with_holes(0.1, seed=3)
    a = watertight_mesh(mesh, resolution=64)
    b = watertight_mesh(mesh, resolution=64)
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)


# ------------------------------------------------------------------------- point clouds
def surface_samples(mesh, n=8000):
    points, face = trimesh.sample.sample_surface_even(mesh, n, seed=0)
    return points, mesh.face_normals[face]


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_solid_from_cloud_analytic(name):
    make, inside, outside = SHAPES[name]
    mesh = make()
    points, normals = surface_samples(mesh)
    solid = solid_from_cloud(points, normals, resolution=64)
    # Measured within 0.6 % at 64^3 with 8000 points.
    assert solid.volume == pytest.approx(mesh.volume, rel=0.03)
    assert solid.contains(np.array(inside, dtype=float)).all()
    assert not solid.contains(np.array(outside, dtype=float)).any()
    assert solid.to_trimesh().is_watertight


def test_solid_from_cloud_noisy():
    mesh = trimesh.creation.torus(0.65, 0.3)
    points, normals = surface_samples(mesh)
    rng = np.random.default_rng(1)
    points = points + 0.005 * rng.normal(size=points.shape)
    normals = normals + 0.1 * rng.normal(size=normals.shape)
    solid = solid_from_cloud(points, normals, resolution=64)
    assert solid.volume == pytest.approx(mesh.volume, rel=0.04)


# Measured volume IoU and volume ratio at resolution 96 with 20000 points, without closing:
# dog 0.987 / 0.997, dragon 0.953 / 1.008; with the default closing (2 voxels), which fills the
# dragon's narrowest folds: dog 0.972 / 1.013, dragon 0.930 / 1.053.
@pytest.mark.parametrize(
    "rel, closing, threshold, volume_rel",
    [("characters/dog.stl", 0, 0.975, 0.02), ("scans/dragon_50k.ply", 0, 0.94, 0.02),
     ("characters/dog.stl", 2, 0.96, 0.03), ("scans/dragon_50k.ply", 2, 0.92, 0.07)],
)
def test_solid_from_cloud_real_mesh_samples(rel, closing, threshold, volume_rel):
    path = DATA / "dev" / rel
    if not path.is_file():
        pytest.fail(f"{path} not available: the shared data must sit beside the checkout")
    cloud = pointcvx.load(path, normalize=True, n_points=20000)
    truth = closed_mesh_solid(cloud.mesh)
    assert truth is not None  # both are closed meshes: the exact solid
    solid = solid_from_cloud(cloud.points, cloud.normals, closing=closing)
    assert volume_iou(solid, truth) >= threshold
    assert solid.volume == pytest.approx(truth.volume, rel=volume_rel)


@pytest.mark.parametrize("name", ["mug_splat.ply", "mug_scan.ply"])
def test_solid_from_cloud_bundled_samples(name):
    path = SAMPLES / name
    if not path.is_file():
        pytest.fail(f"{path} missing: run tools/make_samples.py")
    cloud = pointcvx.load(path, normalize=True)
    solid = solid_for(cloud, cache=False)
    assert solid.volume > 0.01
    assert solid.to_trimesh().is_watertight


def test_bundled_mug_splat_solid_matches_the_true_mug():
    """The splat and the mesh samples are the same mug, in the same frame. Measured volume IoU
    0.960 (0.918 without the closing, 0.685 while the loader got the cup's inner wall wrong),
    and the splat counts as closed (share of flooded voxels behind the points 0.09, LEAK_SHARE
    0.2). The closing also removes the pinholes and tunnels of the noisy sign: the surface has
    the Euler characteristic of a solid (measured 2; -470 without the closing)."""
    cloud = pointcvx.load(SAMPLES / "mug_splat.ply", normalize=False)
    truth = closed_mesh_solid(trimesh.load(SAMPLES / "mug.obj", force="mesh"))
    assert truth is not None
    solid = solid_from_cloud(cloud.points, cloud.normals)
    assert volume_iou(solid, truth) >= 0.94
    assert abs(solid.to_trimesh().euler_number) <= 20
    # The cup's cavity is air, its wall solid (measured 2.0 % and 99.8 % inside; the wall was
    # 77 % with the wrong inner normals and no closing).
    p = np.random.default_rng(0).uniform(-0.8, 0.8, (200_000, 3))
    r = np.hypot(p[:, 0], p[:, 1])
    cavity = p[(r < 0.28) & (p[:, 2] > -0.36) & (p[:, 2] < 0.5)]
    wall = p[(r > 0.33) & (r < 0.39) & (np.abs(p[:, 2]) < 0.45)]
    assert solid.contains(cavity).mean() <= 0.05
    assert solid.contains(wall).mean() >= 0.95


def test_open_capture_of_a_real_splat_is_filled_behind_its_points():
    """The dev donut splat was never filmed from below: the flood fill runs into its tube
    through the missing underside, so the cloud must count as open and the tube be filled
    from the tangent planes and the winding number. Probes: circles around the donut's axis at
    the tube's mid-height (the middle of the ring's height range, whichever way the axis
    points). Measured: all of them inside (60 % from the tangent planes alone, which left
    hollows under a sub-surface layer; 2 % as a closed cloud); the hole stays empty."""
    path = DATA / "dev" / "splats" / "donut.ply"
    if not path.is_file():
        pytest.fail(f"{path} not available: the shared data must sit beside the checkout")
    cloud = pointcvx.load(path, n_points=20000)
    centre = cloud.points.mean(axis=0)
    _, _, vt = np.linalg.svd(cloud.points - centre, full_matrices=False)
    q = (cloud.points - centre) @ vt.T
    r = np.hypot(q[:, 0], q[:, 1])
    ring = (r > 0.5) & (r < 0.75)
    mid = 0.5 * (np.percentile(q[ring, 2], 5) + np.percentile(q[ring, 2], 95))
    t = np.linspace(0.0, 2.0 * np.pi, 200, endpoint=False)
    core = np.concatenate([
        np.stack([rr * np.cos(t), rr * np.sin(t), np.full_like(t, mid + dz)], axis=1) @ vt + centre
        for rr in (0.55, 0.62, 0.7) for dz in (-0.1, 0.0, 0.1)
    ])
    solid = solid_from_cloud(cloud.points, cloud.normals)
    assert solid.contains(core).mean() >= 0.95
    hole = np.stack([0.1 * np.cos(t), 0.1 * np.sin(t), np.full_like(t, mid)], axis=1) @ vt + centre
    assert not solid.contains(centre[None])[0] and not solid.contains(hole).any()


def test_winding_number_of_a_cloud_is_one_inside_and_zero_outside():
    """Lumped per cell, the generalized winding number of a sphere's oriented samples is 1
    inside (measured 1.045: the neighbour-distance areas run a little high) and 0 outside a
    few cells from the surface; with the lower half missing, the centre reads 0.5 and the
    upper inside more than 0.75; flipped normals negate it."""
    from pointcvx.solid import dipole_cells, winding_number

    sphere = trimesh.creation.icosphere(4)
    points, normals = surface_samples(sphere, 20000)
    centres, moments = dipole_cells(points, normals, 0.1)
    assert len(centres) < len(points) / 5
    inside = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, -0.3, 0.5]])
    outside = np.array([[1.5, 0.0, 0.0], [0.0, 2.0, 1.0], [-1.3, 0.0, 0.0]])
    np.testing.assert_allclose(winding_number(centres, moments, inside), 1.0, atol=0.07)
    np.testing.assert_allclose(winding_number(centres, moments, outside), 0.0, atol=0.03)
    np.testing.assert_allclose(winding_number(centres, -moments, inside), -1.0, atol=0.07)
    upper = points[:, 2] > 0
    half = dipole_cells(points[upper], normals[upper], 0.1)
    assert winding_number(*half, np.zeros((1, 3)))[0] == pytest.approx(0.5, abs=0.05)
    assert winding_number(*half, np.array([[0.0, 0.0, 0.7]]))[0] > 0.75


def test_solid_from_cloud_partial_scan():
    """An open hemisphere (x > 0): the flood fill leaks, the far sign follows the tangent
    planes, and the result is about the filled hemisphere, bounded by the padded bounds."""
    sphere = trimesh.creation.icosphere(4)
    points, normals = surface_samples(sphere, 5000)
    keep = points[:, 0] > 0
    solid = solid_from_cloud(points[keep], normals[keep], resolution=64)
    assert solid.volume > 0
    assert solid.to_trimesh().is_watertight
    assert solid.contains(np.array([[0.5, 0.0, 0.0], [0.2, 0.3, -0.3]])).all()
    assert not solid.contains(np.array([[0.5, 0.0, 1.1], [-0.5, 0.0, 0.0]])).any()
    assert solid.volume == pytest.approx(sphere.volume / 2, rel=0.1)  # measured +6 %


def test_solid_from_cloud_flat_patch():
    """An open flat patch gives a slab behind it, never nothing."""
    rng = np.random.default_rng(0)
    points = np.c_[rng.uniform(-1, 1, (3000, 2)), 0.005 * rng.normal(size=3000)]
    normals = np.tile([0.0, 0.0, 1.0], (3000, 1))
    solid = solid_from_cloud(points, normals, resolution=48)
    assert solid.volume > 0 and solid.to_trimesh().is_watertight
    assert solid.contains(np.array([[0.0, 0.0, -0.05]])).all()
    assert not solid.contains(np.array([[0.0, 0.0, 0.05]])).any()


def test_solid_from_cloud_deterministic():
    points, normals = surface_samples(trimesh.creation.torus(0.65, 0.3), 3000)
    a = surface_from_cloud(points, normals, resolution=48)
    b = surface_from_cloud(points, normals, resolution=48)
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)


def test_solid_from_cloud_errors():
    with pytest.raises(InputError):
        solid_from_cloud(np.zeros((0, 3)), np.zeros((0, 3)))
    with pytest.raises(InputError):
        solid_from_cloud(np.random.rand(10, 3), np.zeros((10, 3)))
    with pytest.raises(InputError):
        solid_from_cloud(np.random.rand(10, 3), np.ones((9, 3)))


# ------------------------------------------------------------------------- solid_for
def test_closed_mesh_solid_nested_and_intersecting():
    outer = trimesh.creation.box((2.0, 2.0, 2.0))
    inner = trimesh.creation.box((1.0, 1.0, 1.0))  # wound outward too: must become a void
    nested = trimesh.util.concatenate([outer, inner])
    solid = closed_mesh_solid(nested)
    assert solid is not None
    assert solid.volume == pytest.approx(8.0 - 1.0)
    assert not solid.contains(np.array([[0.0, 0.0, 0.0]])).any()
    assert solid.contains(np.array([[0.8, 0.8, 0.8]])).all()

    crossing = trimesh.util.concatenate([outer, inner.copy().apply_translation([1.0, 0, 0])])
    assert closed_mesh_solid(crossing) is None
    open_mesh, _ = sphere_with_holes(0.1)
    assert closed_mesh_solid(open_mesh) is None


def test_solid_for_routes():
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    closed = pointcvx.io.from_trimesh(box, n_points=2000)
    solid = solid_for(closed, cache=False)
    assert np.array_equal(solid.vertices, closed.mesh.vertices)  # the mesh itself
    assert solid.volume == pytest.approx(1.0)

    holes, true_volume = sphere_with_holes(0.1)
    cloud = pointcvx.io.from_trimesh(holes, n_points=2000)
    solid = solid_for(cloud, resolution=64, cache=False)
    assert solid.volume == pytest.approx(true_volume, rel=0.05)

    points, normals = surface_samples(trimesh.creation.icosphere(3), 4000)
    splat = pointcvx.OrientedCloud(points, normals, modality="splat")
    solid = solid_for(splat, resolution=64)
    assert solid.volume == pytest.approx(4 / 3 * np.pi, rel=0.05)
    assert solid_for(splat, resolution=64) is solid  # cached by content
    again = solid_for(pointcvx.OrientedCloud(points.copy(), normals.copy()), resolution=64)
    assert again is solid  # keyed by content, not by object
    fresh = solid_for(splat, resolution=64, cache=False)
    assert fresh is not solid and np.array_equal(fresh.vertices, solid.vertices)
