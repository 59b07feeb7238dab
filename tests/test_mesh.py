"""Mesh loading: formats, cleaning, outward orientation on real meshes, sampling."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import pointcvx
from conftest import DATA
from pointcvx.errors import InputError
from pointcvx.io.mesh import clean_mesh, cloud_from_mesh, plain_off, read_mesh, winding_signs
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


@pytest.mark.parametrize("rel", ["vhacd61/bunny.off", "vhacd61/chair.off", "dev/characters/knight.off"])
def test_plain_off_files_are_read_as_trimesh_reads_them(rel):
    path = DATA / rel
    arrays = plain_off(path.read_bytes())
    assert arrays is not None, "a plain OFF took trimesh's slow path"
    ref = trimesh.load(path, file_type="off", force="mesh", process=False)
    assert arrays[0].dtype == np.float64 and arrays[1].dtype == np.int64
    assert np.array_equal(arrays[0], ref.vertices) and np.array_equal(arrays[1], ref.faces)
    mesh = read_mesh(path, "off")
    assert np.array_equal(mesh.vertices, ref.vertices) and np.array_equal(mesh.faces, ref.faces)


@pytest.mark.parametrize("text", [
    "OFF\n# a comment\n4 1 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n",  # comments
    "OFF\n4 1 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n4 0 1 2 3\n",  # a quad
    "COFF\n3 1 0\n0 0 0 255 0 0 255\n1 0 0 255 0 0 255\n0 1 0 255 0 0 255\n3 0 1 2\n",  # colours
    "OFF\n3 1 0\n0 0 0 9\n1 0 0\n0 1 0\n3 0 1 2\n",  # a vertex line with an extra value
    "OFF\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",  # fewer faces than declared
    "OFF\n3 1 0\n0\x0c0 0\n1 0 0\n0 1 0\n3 0 1 2\n",  # a form feed: a line break to trimesh
])
def test_off_files_that_are_not_plain_go_to_trimesh_and_still_load(tmp_path, text):
    assert plain_off(text.encode()) is None
    path = tmp_path / "x.off"
    path.write_text(text)
    try:
        mesh = read_mesh(path, "off")
    except InputError:
        return  # what trimesh cannot read is refused, typed
    assert len(mesh.faces) >= 1


def test_a_one_line_off_header_is_plain():
    vertices, faces = plain_off(b"OFF 4 2 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 1 3\n")
    assert vertices.shape == (4, 3) and faces.tolist() == [[0, 1, 2], [0, 1, 3]]


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


# ------------------------------------------------------------------------- hostile meshes
def _obj(mesh: trimesh.Trimesh, extra: str = "") -> str:
    return ("".join(f"v {a} {b} {c}\n" for a, b, c in mesh.vertices)
            + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in mesh.faces) + extra)


def test_obj_face_index_0_names_its_line(tmp_path):
    # OBJ counts from 1; trimesh read 0 as -1 (the last vertex) and loaded the file silently
    box = trimesh.creation.box()
    path = tmp_path / "zero.obj"
    path.write_text(_obj(box, "f 1 0 2\n"))
    with pytest.raises(InputError, match=r"zero\.obj: corrupted OBJ: line 21 has a face with vertex index 0"):
        pointcvx.load(path)
    path.write_text(_obj(box, "v 0 0 0\nf 10 20 1\n").replace("f 10 20 1", "f 1 2 3"))
    assert pointcvx.load(path, n_points=100).modality == "mesh"  # a vertex at 0 0 0 is no index


def test_unused_non_finite_vertices_are_dropped_used_ones_refused(tmp_path):
    box = trimesh.creation.box()
    path = tmp_path / "box.ply"  # PLY keeps every vertex (trimesh's OBJ reader drops unused ones)
    v = np.vstack([box.vertices, [[np.nan, 0, 0]]])
    path.write_text("ply\nformat ascii 1.0\nelement vertex 9\nproperty double x\nproperty double y\n"
                    "property double z\nelement face 12\nproperty list uchar int vertex_indices\nend_header\n"
                    + "".join(f"{a} {b} {c}\n" for a, b, c in v)
                    + "".join(f"3 {a} {b} {c}\n" for a, b, c in box.faces))
    cloud = pointcvx.load(path, n_points=500, normalize=False)
    assert cloud.info["non_finite_dropped"] == 1 and np.isclose(cloud.mesh.area, box.area)
    path = tmp_path / "box.obj"
    path.write_text(_obj(box).replace("v ", "v nan ", 1))  # a NaN vertex of faces
    with pytest.raises(InputError, match=r"1 of 8 mesh vertices used by faces have NaN"):
        pointcvx.load(path)
    path.write_text(_obj(trimesh.Trimesh(box.vertices * 1e154, box.faces, process=False)))
    with pytest.raises(InputError, match=r"of \d+ mesh vertices used by faces lie beyond 1e\+10"):
        pointcvx.load(path)


def test_binary_stl_with_a_wrong_triangle_count_says_so(tmp_path):
    data = trimesh.creation.box().export(file_type="stl")
    for count in (5, 10**6, 0):
        path = tmp_path / f"count{count}.stl"
        path.write_bytes(data[:80] + np.uint32(count).tobytes() + data[84:])
        with pytest.raises(InputError, match=rf"count{count}\.stl: truncated or corrupted binary STL: "
                           rf"its header declares {count} triangles \({84 + 50 * count} bytes\), the file "
                           r"has 684"):
            pointcvx.load(path)
    (tmp_path / "cut.stl").write_bytes(data[:300])
    with pytest.raises(InputError, match="truncated or corrupted binary STL"):
        pointcvx.load(tmp_path / "cut.stl")


def _gltf(buffer: dict, views: list[dict], count: int = 3) -> dict:
    return {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}], "buffers": [buffer],
            "bufferViews": views,
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": count, "type": "VEC3",
                           "min": [0, 0, 0], "max": [1, 1, 0]}]}


def _glb(tree: dict, binary: bytes) -> bytes:
    import json
    import struct

    js = json.dumps(tree).encode()
    js += b" " * (-len(js) % 4)
    binary += bytes(-len(binary) % 4)
    body = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def test_glb_whose_sizes_lie_is_an_input_error(tmp_path):
    # trimesh's glTF reader asserted these (a bare AssertionError, reported as an internal error)
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype="<f4").tobytes()
    cases = {
        "short": (_gltf({"byteLength": 36}, [{"buffer": 0, "byteLength": 36}]), tri[:12],
                  "buffer 0 declares 36"),
        "offset": (_gltf({"byteLength": 36}, [{"buffer": 0, "byteOffset": 2**40, "byteLength": 36}]), tri,
                   "lies outside buffer 0"),
        "count": (_gltf({"byteLength": 36}, [{"buffer": 0, "byteLength": 36}], count=10**12), tri,
                  "declares 1000000000000 elements"),
    }
    for name, (tree, binary, fragment) in cases.items():
        path = tmp_path / f"{name}.glb"
        path.write_bytes(_glb(tree, binary))
        with pytest.raises(InputError, match=rf"{name}\.glb: .*{fragment}"):
            pointcvx.load(path)
    path = tmp_path / "ok.glb"
    path.write_bytes(_glb(_gltf({"byteLength": 36}, [{"buffer": 0, "byteLength": 36}]), tri))
    assert pointcvx.load(path, n_points=100).modality == "mesh"
    path.write_bytes(b"glTF" + (2).to_bytes(4, "little") + (1000).to_bytes(4, "little") + b"[" * 200)
    with pytest.raises(InputError, match="truncated GLB"):
        pointcvx.load(path)


def test_gltf_buffer_uris_outside_the_folder_are_blocked_saying_why(tmp_path):
    import json
    import os

    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype="<f4").tobytes()
    (tmp_path / "outside.bin").write_bytes(tri)
    folder = tmp_path / "model"
    folder.mkdir()
    (folder / "tri.bin").write_bytes(tri)
    os.mkfifo(folder / "pipe.bin")  # reading it would block forever
    views = [{"buffer": 0, "byteLength": 36}]
    cases = {"../outside.bin": "climbs out with '..'", str(tmp_path / "outside.bin"): "absolute path",
             "file:///etc/passwd": "is a URL", "http://example.com/x.bin": "is a URL",
             "pipe.bin": "is not a regular file", "nope.bin": "is missing"}
    for uri, why in cases.items():
        path = folder / "scene.gltf"
        path.write_text(json.dumps(_gltf({"byteLength": 36, "uri": uri}, views)))
        with pytest.raises(InputError) as info:
            pointcvx.load(path)
        message = str(info.value)
        assert why in message and uri[:40] in message, message
        assert "trimesh" not in message and "allow" not in message and "\n" not in message
    path.write_text(json.dumps(_gltf({"byteLength": 36, "uri": "tri.bin"}, views)))
    assert pointcvx.load(path, n_points=100).modality == "mesh"


def test_outward_test_on_a_triangle_soup_works_on_a_bounded_sample(tmp_path, monkeypatch):
    # Rays through a soup of overlapping triangles cross it hundreds of times: the outward test
    # scores a sample sized to the crossing budget instead of every face (1.5M random triangles
    # kept `info` busy for minutes).
    from pointcvx.io import mesh as M

    rng = np.random.default_rng(0)
    n = 20000
    soup = trimesh.Trimesh((rng.random((n, 1, 3)) + 0.05 * rng.normal(size=(n, 3, 3))).reshape(-1, 3),
                           np.arange(3 * n).reshape(-1, 3), process=False)
    monkeypatch.setattr(M, "ORIENT_CROSSINGS", 1_000_000)
    sample = M.scored_faces(soup, 8, 0)
    assert sample is not None and M.ORIENT_PILOT <= len(sample) < n // 2
    out, _, method = M.orient_outward(soup)
    assert f"from {len(sample)} of {n} faces" in method and len(out.faces) == n


def _loose_dragon():
    """The dragon cut into 27 loose pieces, each wound at random: (the true mesh, the pieces)."""
    truth = _true_mesh("scans/dragon_50k.ply")
    centres = truth.triangles_center
    cell = np.floor((centres - truth.bounds[0]) / (truth.extents + 1e-9) * 3).astype(int)
    cell = cell @ [9, 3, 1]
    rng = np.random.default_rng(4)
    pieces = []
    for c in np.unique(cell):
        piece = truth.submesh([np.flatnonzero(cell == c)], append=True)
        middle = piece.vertices.mean(axis=0)
        piece.vertices = middle + 0.995 * (piece.vertices - middle)  # loose: a gap to the next
        if rng.random() < 0.5:
            piece.invert()
        pieces.append(piece)
    return truth, trimesh.util.concatenate(pieces)


def _outward_share(truth, cloud) -> float:
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(truth.triangles_center).query(cloud.points)
    return float((np.einsum("ij,ij->i", truth.face_normals[nearest], cloud.normals) > 0).mean())


def test_a_sampled_outward_test_still_finds_the_outside(monkeypatch):
    # With a tenth of its faces scored (round the pieces), every piece still turns outward.
    from pointcvx.io import mesh as M

    truth, bad = _loose_dragon()
    monkeypatch.setattr(M, "ORIENT_FACES", len(bad.faces) // 10)
    cloud = cloud_from_mesh(bad, n_points=5000, seed=3)
    assert f"from {len(bad.faces) // 10} of {len(bad.faces)} faces" in cloud.info["normals"]
    assert cloud.info["components"] >= 27
    assert _outward_share(truth, cloud) > 0.98


def test_the_pieces_votes_come_from_a_sample_and_conflicted_faces_all_score(monkeypatch):
    # Consistently wound pieces vote with ORIENT_VOTE_FACES faces round the pieces; faces of a
    # piece that cannot be wound consistently are all scored, each deciding its own side.
    from pointcvx.io import mesh as M

    truth, bad = _loose_dragon()
    monkeypatch.setattr(M, "ORIENT_VOTE_FACES", 3000)
    cloud = cloud_from_mesh(bad, n_points=5000, seed=3)
    assert f"from 3000 of {len(bad.faces)} faces" in cloud.info["normals"]
    assert _outward_share(truth, cloud) > 0.98
    labels = np.repeat(np.arange(4), 50)
    conflicted = labels == 2
    sample = M.vote_sample(None, labels, conflicted, seed=0)
    assert sample is None  # under the cap: every face scores
    monkeypatch.setattr(M, "ORIENT_VOTE_FACES", 30)
    sample = M.vote_sample(None, labels, conflicted, seed=0)
    assert set(np.flatnonzero(conflicted)) <= set(sample) and len(sample) == 80
    assert set(labels[sample]) == {0, 1, 2, 3}  # every piece votes
    np.testing.assert_array_equal(sample, M.vote_sample(None, labels, conflicted, seed=0))
