"""Scan loading: point clouds without (trustworthy) normals, built from real shapes.

The dragon of ``shared/data/dev/scans`` (a watertight mesh, read in place) is turned into scan-like
inputs in ``tmp_path``: its vertices without faces, with noise and far outliers, in every point
format, and single views of it (only the points visible from one camera). The mesh's own outward
normals are the ground truth. The agreement floors sit a little under what was measured (noted
beside each).
"""

from __future__ import annotations

import struct
import sys

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

import pointcvx
from conftest import DATA, load_tool
from pointcvx import InputError, MissingExtraError, OrientedCloud
from pointcvx.io import LoadOptions, finalize
from pointcvx.io.ply import write_cloud_ply
from pointcvx.io.pointfiles import read_xyz
from pointcvx.io.scan import cloud_from_points, face_one_viewer, load_scan_file

DRAGON = DATA / "dev" / "scans" / "dragon_50k.ply"


@pytest.fixture(scope="module")
def dragon():
    """The watertight dragon mesh (25k vertices) with its outward vertex normals."""
    if not DRAGON.is_file():
        pytest.fail(f"{DRAGON} not found: the shared data must sit beside the checkout")
    mesh = trimesh.load(DRAGON, process=False)
    assert mesh.is_watertight and mesh.volume > 0
    return mesh


@pytest.fixture(scope="module")
def noisy(dragon):
    """Dragon vertices + 0.2%-of-diagonal noise, and 200 outliers at least 5% of the diagonal away
    from the surface. Returns (points with outliers last, number of outliers)."""
    rng = np.random.default_rng(7)
    v = np.asarray(dragon.vertices)
    diag = float(np.linalg.norm(dragon.extents))
    pts = v + rng.normal(scale=0.002 * diag, size=v.shape)
    lo, hi = v.min(axis=0), v.max(axis=0)
    cand = rng.uniform(lo - 0.15 * (hi - lo), hi + 0.15 * (hi - lo), size=(3000, 3))
    far = cKDTree(v).query(cand)[0] > 0.05 * diag
    outliers = cand[far][:200]
    assert len(outliers) == 200
    return np.vstack([pts, outliers]), len(outliers)


def truth_agreement(cloud: OrientedCloud, mesh) -> float:
    """Share of the cloud's normals within 90 degrees of the nearest mesh vertex's outward normal."""
    c = cloud.in_input_units()
    _, idx = cKDTree(mesh.vertices).query(c.points)
    truth = np.asarray(mesh.vertex_normals)[idx]
    return float(np.mean(np.einsum("ij,ij->i", c.normals, truth) > 0))


def single_view(mesh, direction, distance: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """The mesh vertices a pinhole camera sees from ``distance`` diagonals along ``direction``,
    and the camera position (ray casting against the mesh itself)."""
    import open3d as o3d

    v = np.asarray(mesh.vertices)
    diag = float(np.linalg.norm(mesh.extents))
    d = np.asarray(direction, dtype=np.float64)
    cam = mesh.bounds.mean(axis=0) + d / np.linalg.norm(d) * distance * diag
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)),
                        o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)))
    rays = v - cam
    dist = np.linalg.norm(rays, axis=1)
    rays = np.hstack([np.repeat(cam[None], len(v), axis=0), rays / dist[:, None]]).astype(np.float32)
    hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    return v[hit >= dist - 1e-4 * diag], cam


def write_xyz(path, rows: np.ndarray, header: str | None = None, sep: str = " ", count: bool = False):
    lines = [header] if header else []
    if count:
        lines.append(str(len(rows)))
    lines += [sep.join(f"{x:.6f}" for x in r) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def write_pcd(path, points, colors=None, mode: str = "binary"):
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    if colors is not None:
        pc.colors = o3d.utility.Vector3dVector(colors)
    assert o3d.io.write_point_cloud(str(path), pc, write_ascii=mode == "ascii",
                                    compressed=mode == "binary_compressed")
    return path


def assert_scan_cloud(cloud: OrientedCloud):
    assert cloud.modality == "scan"
    assert np.allclose(np.linalg.norm(cloud.normals, axis=1), 1.0)
    assert np.abs(cloud.points).max() <= 1.0 + 1e-9  # normalised to [-1, 1]^3
    for key in ("normals", "normals_flipped", "dropped_outliers", "colors", "one_sided"):
        assert key in cloud.info


# ------------------------------------------------------------------------------- whole scans
def test_vertices_only_ply_gets_outward_normals(dragon, tmp_path):
    path = tmp_path / "dragon_points.ply"
    rgb = np.array([0.2, 0.4, 0.6])
    write_cloud_ply(path, np.asarray(dragon.vertices), colors=np.tile(rgb, (len(dragon.vertices), 1)))
    assert pointcvx.detect(path).format == "ply-points"
    cloud = pointcvx.load(path)
    assert_scan_cloud(cloud)
    assert cloud.info["colors"] and np.allclose(cloud.colors, np.round(rgb * 255) / 255)
    assert cloud.info["normals"] == "estimated (PCA k=24) + oriented"
    assert not cloud.info["one_sided"]
    assert cloud.info["dropped_outliers"] < 0.03 * len(dragon.vertices)
    assert truth_agreement(cloud, dragon) > 0.96  # measured 0.978


@pytest.mark.parametrize("fmt", ["ply", "pcd", "xyz", "pts"])
def test_noisy_scan_with_outliers(dragon, noisy, tmp_path, fmt):
    points, n_out = noisy
    if fmt == "ply":
        path = tmp_path / "scan.ply"
        write_cloud_ply(path, points)
    elif fmt == "pcd":
        path = write_pcd(tmp_path / "scan.pcd", points, mode="ascii")
    elif fmt == "xyz":
        path = write_xyz(tmp_path / "scan.xyz", points)
    else:
        intensity = np.full((len(points), 1), -1200.0)
        rgb = np.tile([200.0, 120.0, 40.0], (len(points), 1))
        path = write_xyz(tmp_path / "scan.pts", np.hstack([points, intensity, rgb]), count=True)
    cloud = pointcvx.load(path)
    assert_scan_cloud(cloud)
    assert cloud.info["format"] == {"ply": "ply-points"}.get(fmt, fmt)
    kept = cloud.in_input_units().points
    outliers_left = int((cKDTree(kept).query(points[-n_out:])[0] < 1e-4).sum())
    assert outliers_left <= 0.05 * n_out  # measured 0 of 200
    assert cloud.info["dropped_outliers"] >= n_out - outliers_left
    assert truth_agreement(cloud, dragon) > 0.95  # measured 0.972 (PLY)
    if fmt == "pts":
        assert cloud.info["colors"]
        assert np.allclose(cloud.colors[0], np.array([200, 120, 40]) / 255.0, atol=1e-6)


@pytest.mark.parametrize(
    "direction, floor",
    [
        ((0.0, 0.0, 1.0), 0.97),  # measured: facing 0.997, truth agreement 0.983
        ((1.0, 0.0, 0.0), 0.88),  # head-on: occlusion splits the view; measured 0.921 / 0.912
        ((0.3, 1.0, 0.5), 0.97),  # measured 0.998 / 0.980
        ((0.0, -1.0, 0.0), 0.97),  # measured 0.997 / 0.987
    ],
)
def test_partial_scan_normals_face_the_viewer(dragon, tmp_path, direction, floor):
    visible, cam = single_view(dragon, direction)
    assert 0.2 * len(dragon.vertices) < len(visible) < 0.5 * len(dragon.vertices)
    path = tmp_path / "view.ply"
    write_cloud_ply(path, visible)
    cloud = pointcvx.load(path)
    assert_scan_cloud(cloud)
    assert cloud.info["one_sided"]
    c = cloud.in_input_units()
    facing = float(np.mean(np.einsum("ij,ij->i", c.normals, cam - c.points) > 0))
    assert facing > floor
    assert truth_agreement(cloud, dragon) > floor - 0.02


def test_one_sided_fix_leaves_closed_shapes_alone(dragon):
    v = np.asarray(dragon.vertices)
    normals = np.asarray(dragon.vertex_normals)
    out, openness, flipped = face_one_viewer(v, normals)
    assert openness < 0.1 and flipped == 0 and out is normals


# ------------------------------------------------------------------------------- normals in the file
def test_file_normals_kept_flipped_or_reoriented(dragon, tmp_path):
    v = np.asarray(dragon.vertices)
    n = np.asarray(dragon.vertex_normals)
    path = tmp_path / "with_normals.ply"

    write_cloud_ply(path, v, n)
    cloud = pointcvx.load(path, outlier_neighbors=0)
    assert cloud.info["normals"] == "from file" and cloud.info["normals_flipped"] == 0
    assert np.allclose(cloud.normals, n / np.linalg.norm(n, axis=1, keepdims=True), atol=1e-5)

    write_cloud_ply(path, v, -n)
    cloud = pointcvx.load(path, outlier_neighbors=0)
    assert cloud.info["normals"].startswith("from file, flipped outward")
    assert truth_agreement(cloud, dragon) == 1.0

    signs = np.where(np.random.default_rng(3).random(len(v)) < 0.5, -1.0, 1.0)
    write_cloud_ply(path, v, n * signs[:, None])
    cloud = pointcvx.load(path, outlier_neighbors=0)
    assert cloud.info["normals"].startswith("from file, re-oriented")
    assert truth_agreement(cloud, dragon) > 0.97  # measured 0.986


# ------------------------------------------------------------------------------- text formats
def test_xyz_with_header_and_extra_columns(dragon, tmp_path):
    v = np.asarray(dragon.vertices)[::4]
    rgb = np.tile([10.0, 20.0, 250.0], (len(v), 1))
    intensity = np.linspace(0, 1, len(v))[:, None]
    rows = np.hstack([v, intensity, rgb])
    path = write_xyz(tmp_path / "cloud.xyz", rows, header="# X,Y,Z,Intensity,R,G,B", sep=",")
    cloud = pointcvx.load(path)
    assert_scan_cloud(cloud)
    assert cloud.info["format"] == "xyz" and cloud.info["colors"]
    assert np.allclose(cloud.colors, np.array([10, 20, 250]) / 255.0, atol=1e-6)

    # A bare header line (no comment mark), semicolons, RGB before intensity: read by name.
    path = write_xyz(tmp_path / "bare.xyz", rows[:, [0, 1, 2, 4, 5, 6, 3]], header="x;y;z;red;green;blue;i",
                     sep=";")
    pts, normals, colors = read_xyz(path)
    assert np.allclose(pts, v, atol=1e-5) and normals is None
    assert np.allclose(colors, np.array([10, 20, 250]) / 255.0, atol=1e-6)
    cloud = load_scan_file(path, "xyz", LoadOptions())
    assert cloud.info["colors"] and len(cloud) > 0.95 * len(v)

    # Unnamed extra columns: normals are recognised as unit vectors, RGB as integers in [0, 255].
    n = np.asarray(dragon.vertex_normals)[::4]
    path = write_xyz(tmp_path / "n.xyz", np.hstack([v, n, rgb]), header="// exported scan")
    pts, normals, colors = read_xyz(path)
    assert np.allclose(normals, n, atol=1e-5) and np.allclose(pts, v, atol=1e-5)
    assert np.allclose(colors, np.array([10, 20, 250]) / 255.0, atol=1e-6)


def test_xyz_with_bare_header_is_detected(tmp_path):
    path = write_xyz(tmp_path / "bare.xyz", np.random.default_rng(0).random((50, 3)), header="X Y Z")
    assert pointcvx.detect(path).format == "xyz"


def test_non_finite_rows_of_scan_files_are_dropped_and_counted(dragon, tmp_path):
    # In scans NaN means "no measurement": those rows go, counted; the rest loads unchanged.
    v = np.asarray(dragon.vertices)[:500].copy()
    v[[3, 50, 400], 1] = np.nan
    v[7, 2] = np.inf
    finite = np.isfinite(v).all(axis=1)
    for path in (write_xyz(tmp_path / "holes.xyz", v), tmp_path / "holes.ply"):
        if path.suffix == ".ply":
            write_cloud_ply(path, v)
        cloud = pointcvx.load(path, normalize=False, outlier_neighbors=0, isolate="none")
        assert cloud.info["non_finite_dropped"] == 4 and len(cloud) == 496
        assert np.allclose(cloud.points, v[finite], atol=1e-5)
    assert pointcvx.load(tmp_path / "holes.ply").info["non_finite_dropped"] == 4
    # an error only when fewer than 4 finite points remain
    v[3:] = np.nan
    path = write_xyz(tmp_path / "empty.xyz", v)
    with pytest.raises(InputError, match=r"empty\.xyz: only 3 of 500 points are usable \(497 NaN or "
                       r"infinite\)"):
        pointcvx.load(path)
    # arrays handed to the API are the caller's own: NaN there stays an error
    with pytest.raises(InputError, match="NaN or infinite"):
        pointcvx.decompose(np.asarray(dragon.vertices)[:500] * np.r_[np.nan, np.ones(499)][:, None])


def test_points_beyond_the_coordinate_bound_are_dropped_or_refused(dragon, tmp_path):
    # 1e154 once overflowed squared distances (an IndexError in normal estimation)
    v = np.asarray(dragon.vertices)[:500].copy()
    v[:5] = 1e154
    cloud = pointcvx.load(write_xyz(tmp_path / "far.xyz", v), outlier_neighbors=0, isolate="none")
    assert cloud.info["out_of_range_dropped"] == 5 and len(cloud) == 495
    with pytest.raises(InputError, match=r"huge\.xyz: only 0 of 500 points are usable \(0 NaN or infinite, "
                       r"500 beyond 1e\+10\)"):
        pointcvx.load(write_xyz(tmp_path / "huge.xyz", np.asarray(dragon.vertices)[:500] * 1e154))


def test_text_corrupted_rows_raise(tmp_path):
    path = tmp_path / "ragged.xyz"
    path.write_text("1 2 3\n4 5 6\n7 8 9\n1 2 3\n4 5\n")
    with pytest.raises(InputError, match="ragged.xyz"):
        pointcvx.load(path)
    path = tmp_path / "word.xyz"
    path.write_text("1 2 3\n4 5 6\n7 8 9\n1 2 3\n4 5 6\nhello\n")
    with pytest.raises(InputError, match="word.xyz"):
        pointcvx.load(path)


def test_obj_vertices_only(dragon, tmp_path):
    v = np.asarray(dragon.vertices)[::2]
    path = tmp_path / "points.obj"
    path.write_text("# points\n" + "".join(f"v {x:.6f} {y:.6f} {z:.6f} 1 0 0\n" for x, y, z in v))
    assert pointcvx.detect(path).format == "obj-points"
    cloud = pointcvx.load(path)
    assert_scan_cloud(cloud)
    assert np.allclose(cloud.colors, [1, 0, 0])
    assert truth_agreement(cloud, dragon) > 0.92  # measured 0.938 (half the vertices: sparser)


# ------------------------------------------------------------------------------- PCD
def load_pcd(path, **options) -> OrientedCloud:
    """Load a PCD through the scan loader directly (see test_binary_pcd_is_detected)."""
    cloud = load_scan_file(path, "pcd", LoadOptions(**options))
    return finalize(cloud, LoadOptions(**options))


@pytest.mark.parametrize("mode", ["binary", "binary_compressed"])
def test_binary_pcd_is_detected(dragon, tmp_path, mode):
    path = write_pcd(tmp_path / f"{mode}.pcd", np.asarray(dragon.vertices)[:100], mode=mode)
    assert pointcvx.detect(path).format == "pcd"


@pytest.mark.parametrize("mode", ["ascii", "binary", "binary_compressed"])
def test_pcd_modes_round_trip_with_colours(dragon, tmp_path, mode):
    v = np.asarray(dragon.vertices)[::3]
    colors = np.random.default_rng(1).integers(0, 256, size=(len(v), 3)) / 255.0
    path = write_pcd(tmp_path / f"{mode}.pcd", v, colors, mode)
    cloud = load_pcd(path, normalize=False, outlier_neighbors=0)
    assert len(cloud) == len(v)
    assert np.allclose(cloud.points, v, atol=1e-4)
    assert np.allclose(cloud.colors, colors, atol=1e-6)


@pytest.mark.parametrize("mode", ["ascii", "binary", "binary_compressed"])
def test_pcd_truncated_raises(dragon, tmp_path, mode):
    path = write_pcd(tmp_path / "whole.pcd", np.asarray(dragon.vertices)[:2000], mode=mode)
    data = path.read_bytes()
    cut = tmp_path / "cut.pcd"
    cut.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(InputError, match=r"cut\.pcd: (truncated|corrupted)"):
        load_pcd(cut)


def test_organised_pcd_frame_drops_nan_holes_and_keeps_its_organisation(dragon, tmp_path):
    # A 20 x 30 frame with NaN where the sensor saw nothing, in all three encodings.
    v = np.asarray(dragon.vertices)[:600].astype(np.float32)
    v[::4] = np.nan
    header = ("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 30\n"
              "HEIGHT 20\nVIEWPOINT 0.5 0 -1 0 1 0 0\nPOINTS 600\nDATA {}\n")
    compressed = load_tool("hostile_corpus").lzf_literals(np.ascontiguousarray(v.T).tobytes())
    bodies = {"ascii": "".join(f"{a!r} {b!r} {c!r}\n" for a, b, c in v.tolist()).encode(),
              "binary": v.tobytes(),
              "binary_compressed": struct.pack("<II", len(compressed), v.nbytes) + compressed}
    for mode, body in bodies.items():
        path = tmp_path / f"{mode}.pcd"
        path.write_bytes(header.format(mode).encode() + body)
        cloud = pointcvx.load(path, normalize=False, outlier_neighbors=0, isolate="none")
        assert cloud.info["non_finite_dropped"] == 150 and len(cloud) == 450, mode
        assert cloud.info["organized"] == [30, 20] and cloud.info["viewpoint"] == [0.5, 0, -1, 0, 1, 0, 0]
        assert np.allclose(cloud.points, v[np.isfinite(v).all(axis=1)], atol=1e-6)


def depth_frame(mesh, cam, width: int = 160, height: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """An organised depth frame of ``mesh`` in front of a back wall and on a floor (one box mesh
    each), seen by a pinhole at ``cam`` looking along +z (rows going down -y): (height * width, 3)
    float32 points in pixel order, NaN where a ray hits nothing, and (height * width, 3) the
    outward normal of the mesh's face each ray hit (NaN off the mesh)."""
    import open3d as o3d

    lo, hi = mesh.bounds
    size = float(np.max(hi - lo))
    wall = trimesh.creation.box(extents=[2.5 * size, 8 * size, 0.1 * size])
    wall.apply_translation([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2] + 0.5 * size])
    floor = trimesh.creation.box(extents=[8 * size, 0.1 * size, 8 * size])
    floor.apply_translation([(lo[0] + hi[0]) / 2, lo[1] - 0.05 * size, (lo[2] + hi[2]) / 2])
    scene = o3d.t.geometry.RaycastingScene()
    for m in (mesh, wall, floor):
        scene.add_triangles(o3d.core.Tensor(np.asarray(m.vertices, np.float32)),
                            o3d.core.Tensor(np.asarray(m.faces, np.uint32)))
    u, v = np.meshgrid((np.arange(width) - width / 2) / width, (np.arange(height) - height / 2) / width)
    dirs = np.stack([u.ravel(), -v.ravel(), np.ones(u.size)], axis=1)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    rays = np.hstack([np.repeat(np.asarray(cam, float)[None], len(dirs), 0), dirs]).astype(np.float32)
    hit = scene.cast_rays(o3d.core.Tensor(rays))
    t = hit["t_hit"].numpy()
    pts = np.asarray(cam, float) + dirs * np.where(np.isfinite(t), t, np.nan)[:, None]
    on = hit["geometry_ids"].numpy() == 0
    truth = np.full(pts.shape, np.nan)
    truth[on] = mesh.face_normals[hit["primitive_ids"].numpy()[on]]
    return pts.astype(np.float32), truth


def test_an_organised_frames_normals_face_its_sensor(dragon, tmp_path):
    """One depth frame sees only surfaces that face its sensor: the dragon on a floor before a
    back wall, with the sensor away from the origin (PCD VIEWPOINT). The convex-hull vote read
    such a frame's far wall as the outside and turned it, and what the propagation joined to it,
    away from the sensor (the Kinect frame of raw_scans came out inward everywhere)."""
    lo, hi = dragon.bounds
    centre = (lo + hi) / 2
    cam = np.array([centre[0], centre[1] + 0.3 * (hi[1] - lo[1]), lo[2] - 1.5 * np.max(hi - lo)])
    v, truth = depth_frame(dragon, cam)
    assert np.isnan(v).any() and np.isfinite(truth).all(axis=1).sum() > 1000
    header = ("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 160\n"
              "HEIGHT 120\nVIEWPOINT {} {} {} 1 0 0 0\nPOINTS 19200\nDATA binary\n").format(*cam)
    path = tmp_path / "frame.pcd"
    path.write_bytes(header.encode() + v.tobytes())
    cloud = pointcvx.load(path, normalize=False, isolate="none", outlier_neighbors=0)
    assert cloud.info["normals"] == "estimated (PCA k=24), facing the sensor"
    facing = np.einsum("ij,ij->i", cloud.normals, cam - cloud.points)
    assert (facing > 0).all()
    # against the dragon's faces (the frame's points in pixel order, less its holes)
    truth = truth[np.isfinite(v).all(axis=1)]
    on_dragon = np.isfinite(truth).all(axis=1)
    assert len(truth) == len(cloud) and on_dragon.sum() > 1000
    assert np.mean(np.einsum("ij,ij->i", cloud.normals[on_dragon], truth[on_dragon]) > 0) > 0.95
    # normals read from the frame are turned the same way
    nrm = np.nan_to_num(v - cam)  # along the rays: away from the sensor, every one to flip
    nrm[~np.isfinite(v).all(axis=1)] = np.nan
    with_normals = tmp_path / "frame_normals.pcd"
    six = (header.replace("FIELDS x y z", "FIELDS x y z normal_x normal_y normal_z")
           .replace("SIZE 4 4 4", "SIZE 4 4 4 4 4 4").replace("TYPE F F F", "TYPE F F F F F F")
           .replace("COUNT 1 1 1", "COUNT 1 1 1 1 1 1"))
    with_normals.write_bytes(six.encode() + np.hstack([v, nrm.astype(np.float32)]).tobytes())
    cloud = pointcvx.load(with_normals, normalize=False, isolate="none", outlier_neighbors=0)
    assert cloud.info["normals"] == "from file, facing the sensor"
    assert cloud.info["normals_flipped"] == len(cloud)
    assert (np.einsum("ij,ij->i", cloud.normals, cam - cloud.points) > 0).all()


def test_pcd_declaring_far_more_points_than_it_holds(dragon, tmp_path):
    # open3d allocated what a compressed block declared (std::bad_alloc for 10^12 points)
    v = np.asarray(dragon.vertices)[:100]
    for mode in ("binary", "binary_compressed", "ascii"):
        path = write_pcd(tmp_path / f"{mode}.pcd", v, mode=mode)
        data = path.read_bytes().replace(b"POINTS 100", b"POINTS 1000000000000").replace(
            b"WIDTH 100", b"WIDTH 1000000000000")
        path.write_bytes(data)
        with pytest.raises(InputError, match=rf"{mode}\.pcd: (truncated|corrupted) PCD"):
            pointcvx.load(path)


def test_pcd_garbage_rows_raise(tmp_path):
    path = tmp_path / "garbage.pcd"
    path.write_text("VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 5\nHEIGHT 1\n"
                    "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 5\nDATA ascii\n"
                    "1 2 3\n4 5 6\nfoo bar baz\n1 1 1\n2 2 2\n")
    with pytest.raises(InputError, match="garbage.pcd"):
        pointcvx.load(path)


# ------------------------------------------------------------------------------- LAS
def test_las_round_trip(dragon, tmp_path):
    import laspy  # the [las] extra is part of the test install
    v = np.asarray(dragon.vertices)[::2] + np.array([512000.0, 5400000.0, 300.0])  # UTM-like
    header = laspy.LasHeader(point_format=2, version="1.2")
    header.scales = [0.001] * 3
    header.offsets = v.min(axis=0)
    las = laspy.LasData(header)
    las.x, las.y, las.z = v.T
    las.red = np.full(len(v), 65535, np.uint16)
    las.green = np.zeros(len(v), np.uint16)
    las.blue = np.full(len(v), 32768, np.uint16)
    path = tmp_path / "scan.las"
    las.write(str(path))
    cloud = pointcvx.load(path)
    assert_scan_cloud(cloud)
    assert cloud.info["format"] == "las"
    assert np.allclose(cloud.colors[0], [1.0, 0.0, 32768 / 65535], atol=1e-4)
    assert np.allclose(cloud.normalization.inverse(cloud.points).min(axis=0), v.min(axis=0), atol=0.01)

    data = path.read_bytes()
    cut = tmp_path / "cut.las"
    cut.write_bytes(data[: len(data) - 1000])
    with pytest.raises(InputError, match=r"cut\.las"):
        pointcvx.load(cut)


def test_las_headers_are_checked_before_anything_is_allocated(dragon, tmp_path):
    import tracemalloc

    import laspy

    v = np.asarray(dragon.vertices)[:300]
    header = laspy.LasHeader(point_format=2, version="1.2")
    header.scales, header.offsets = [0.001] * 3, v.min(axis=0)
    las = laspy.LasData(header)
    las.x, las.y, las.z = v.T
    las.write(str(tmp_path / "ok.las"))
    data = (tmp_path / "ok.las").read_bytes()
    # 10^9 points declared in 1 KB: laspy allocated 26 GB before finding the file short
    (tmp_path / "many.las").write_bytes(data[:107] + struct.pack("<I", 10**9) + data[111:1024])
    tracemalloc.start()
    try:
        with pytest.raises(InputError, match=r"many\.las: truncated or corrupted LAS: the header declares "
                           r"1000000000 points of 26 bytes"):
            pointcvx.load(tmp_path / "many.las")
        assert tracemalloc.get_traced_memory()[1] < 16 << 20
    finally:
        tracemalloc.stop()
    # a LAS signature and random bytes: refused by its header at once (it ran past 60 s)
    (tmp_path / "noise.las").write_bytes(b"LASF" + np.random.default_rng(2).bytes(4000))
    with pytest.raises(InputError, match=r"noise\.las: corrupted LAS header"):
        pointcvx.load(tmp_path / "noise.las")
    las.write(str(tmp_path / "ok.laz"))  # LAZ through lazrs: its errors are input errors too
    laz = (tmp_path / "ok.laz").read_bytes()
    (tmp_path / "cut.laz").write_bytes(laz[: len(laz) // 2])
    with pytest.raises(InputError, match=r"cut\.laz: truncated or corrupted LAS"):
        pointcvx.load(tmp_path / "cut.laz")
    laz_cloud = pointcvx.load(tmp_path / "ok.laz", normalize=False, outlier_neighbors=0, isolate="none")
    assert np.allclose(laz_cloud.points, v, atol=1e-3)


def test_las_without_laspy_names_the_extra(tmp_path, monkeypatch):
    path = tmp_path / "x.las"
    path.write_bytes(b"LASF" + bytes(400))
    monkeypatch.setitem(sys.modules, "laspy", None)
    msg = r"LAS input needs the optional package 'laspy'.*pointcvx\[las\]"
    with pytest.raises(MissingExtraError, match=msg):
        pointcvx.load(path)


# ------------------------------------------------------------------------------- arrays and options
def test_from_arrays_and_options(dragon):
    v = np.asarray(dragon.vertices)
    cloud = pointcvx.io.from_numpy(v, outlier_neighbors=0, normal_neighbors=16)
    assert cloud.info["normals"] == "estimated (PCA k=16) + oriented"
    assert len(cloud) == len(v) and cloud.info["dropped_outliers"] == 0
    assert truth_agreement(cloud, dragon) > 0.96  # measured 0.978

    voxel = 0.005 * float(np.linalg.norm(dragon.extents))
    small = cloud_from_points(v, voxel_size=voxel)
    assert small.info["voxel_downsampled_from"] == len(v)
    assert len(small) < 0.8 * len(v)
    assert truth_agreement(small, dragon) > 0.95  # measured 0.977

    capped = cloud_from_points(v, n_points=1000, seed=3)
    again = cloud_from_points(v, n_points=1000, seed=3)
    assert len(capped) == 1000 and capped.info["presampled_from"] == len(v)
    assert np.array_equal(capped.points, again.points) and np.array_equal(capped.normals, again.normals)

    with pytest.raises(InputError, match="2 of"):
        cloud_from_points(np.vstack([v[:100], [[np.nan, 0, 0], [0, np.inf, 0]]]))
