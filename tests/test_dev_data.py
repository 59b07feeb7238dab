"""Every real shape in shared/data/dev loads, through the API and through the CLI, into an
oriented cloud with unit normals in [-1, 1]^3; so do the raw sensor frames of shared/data/raw_scans,
their NaN holes dropped and counted."""

from __future__ import annotations

import json

import numpy as np
import pytest

import pointcvx
from conftest import DATA, collision_vertices, dev_files, largest_move, load_tool
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


RAW = sorted((DATA / "raw_scans").glob("*.pcd"))


def _non_finite_rows(path) -> tuple[int, int]:
    """(rows, rows with a NaN or infinite coordinate) of a PCD, as open3d reads it."""
    from pointcvx.syslibs import import_open3d

    o3d = import_open3d()
    points = np.asarray(o3d.io.read_point_cloud(str(path), remove_nan_points=False).points)
    return len(points), int((~np.isfinite(points).all(axis=1)).sum())


def test_raw_scans_are_all_there():
    assert [p.stem for p in RAW] == ["five_people", "kinect_frame", "lamppost", "office1"]


@pytest.mark.parametrize("path", RAW, ids=[p.stem for p in RAW])
def test_raw_scan_loads_with_its_nan_holes_dropped(path, capsys):
    # Organised depth frames mark "no measurement" with NaN: those rows are dropped and counted.
    rows, holes = _non_finite_rows(path)
    cloud = pointcvx.load(path, n_points=2000, seed=1)
    assert cloud.modality == "scan" and cloud.info["format"] == "pcd"
    assert cloud.info["non_finite_dropped"] == holes
    assert cloud.info["input_points"] == rows - holes
    assert np.isfinite(cloud.points).all() and np.isfinite(cloud.normals).all()
    assert 100 <= len(cloud) <= 2000
    if path.stem != "lamppost":  # 640 x 480 Kinect frames with tens of thousands of holes
        assert holes > 30000 and cloud.info["organized"] == [640, 480]
        # one frame sees only what faces its sensor (at the origin of these frames)
        assert cloud.info["normals"].endswith("facing the sensor")
        raw = pointcvx.load(path, n_points=2000, seed=1, normalize=False)
        assert (np.einsum("ij,ij->i", raw.normals, -raw.points) > 0).all()
    assert len(cloud.info["viewpoint"]) == 7
    assert main(["info", str(path), "-n", "2000", "--seed", "1", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["non_finite_dropped"] == holes and report["points"] == len(cloud)


def test_the_lampposts_sparse_head_is_cut_at_what_its_samples_resolve(tmp_path, capsys):
    """The LiDAR lamppost's head is a second object of 289 points: at 0.1 (two of its sample
    spacings) it became 20 hulls of 5-30 points, each still about 0.1. It is cut at four
    spacings instead, and the summary line and the report say so; the post keeps 0.1."""
    out = tmp_path / "lamppost.json"
    assert main(["decompose", str(DATA / "raw_scans" / "lamppost.pcd"), "-o", str(out)]) == 0
    assert "too sparse to resolve threshold 0.1, so cut at" in capsys.readouterr().out
    objects = json.loads(out.read_text())["objects"]
    sparse = [o for o in objects if "resolved_threshold" in o]
    assert len(sparse) == 1 and sparse[0]["points"] < 400 and len(sparse[0]["hulls"]) <= 6
    assert sparse[0]["resolved_threshold"] > 0.15
    for o in objects:
        assert o["max_concavity"] <= o.get("resolved_threshold", 0.1)


def test_the_kinect_frames_objects_reach_the_floor_and_rest_on_it_in_mujoco(tmp_path):
    """kinect_frame.pcd: three objects on a floor. Isolation removes the floor with its band,
    and the objects' bottoms with it; their hulls are extended down to the floor
    (decomposition.ground), so in the MJCF scene the largest (in hulls, standing on its own) rests
    where it stood (with the bases left open it dropped 7 mm onto the floor). The thin board
    leaning on it, whose centre of mass is not over its foot, is static (it toppled before):
    nothing in the scene moves more than 1 cm in a second."""
    import mujoco

    result = pointcvx.decompose(DATA / "raw_scans" / "kinect_frame.pcd", seed=0)
    plane = result.support
    n, offset = np.asarray(plane["normal"]), plane["offset"]
    assert result.cloud.info["grounded_hulls"] >= 3
    for obj in result.objects:  # each object stood on the floor: its lowest hull reaches it
        low = min(float((result.hulls[h].vertices @ n).min() - offset) for h in obj["hulls"])
        assert abs(low) < 1e-6, (obj["name"], low)
    box = max(range(len(result.objects)), key=lambda k: len(result.objects[k]["hulls"]))
    xml = next(p for p in result.export(tmp_path / "kinect.xml") if str(p).endswith(".xml"))
    model = mujoco.MjModel.from_xml_path(str(xml))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    # motion is that of the hulls' vertices: a body's frame can sit far from its object, where a
    # turn of a fraction of a degree reads as a centimetre (it did, with frames at the origin)
    start, start_box = collision_vertices(model, data), collision_vertices(model, data, 1 + box)
    for _ in range(100):
        mujoco.mj_step(model, data)
    assert largest_move(model, data, start_box, 1 + box) < 0.002
    assert [o["rests_on"] for o in result.objects] == ["support"] * 3
    leaning = [o["name"] for o in result.objects if not o["stands"]]
    assert len(leaning) == 1 and leaning != [result.objects[box]["name"]]
    assert model.body_jntnum[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, leaning[0])] == 0
    for _ in range(400):
        mujoco.mj_step(model, data)
    assert largest_move(model, data, start) < 0.01
    # The hulls keep out of the space the sensor saw through (in front of what it measured):
    # 1.6 % of their volume (tools/frame_free_space.py). With the frame's normals turned away
    # from the sensor (the convex-hull vote's orientation) it was 15 %, one hull 49 %.
    share, worst = load_tool("frame_free_space").seen_through_share(
        DATA / "raw_scans" / "kinect_frame.pcd", result.hulls)
    assert share < 0.04 and worst < 0.3, (share, worst)


def test_the_office_frames_wall_is_static_and_frees_its_objects(tmp_path):
    """office1.pcd sees a room's back wall straight on, a side wall that steps 0.35 m proud
    over a third of its length, and a strip of floor: the floor is the support (up is its
    normal), both walls (planes bounding the view) are removed and reported, what stood against
    them falls into several objects (it was one, joined by the walls), and the MJCF scene has
    the walls as static boxes that MuJoCo loads and steps."""
    import mujoco

    result = pointcvx.decompose(DATA / "raw_scans" / "office1.pcd", seed=0)
    iso = result.cloud.info["isolation"]
    assert iso["removed"]["walls"] > 10000 and len(iso["walls"]) >= 1
    assert iso["walls"][0]["normal"][2] < -0.99  # the back wall, facing the sensor
    assert any(w["normal"][0] < -0.95 for w in iso["walls"])  # the side wall, on the right
    floor = np.asarray(result.report()["support_plane"]["normal"])
    assert floor @ [0.0, -1.0, 0.0] > 0.99 and result.cloud.info["up"] == floor.tolist()
    assert len(result.objects) >= 3
    assert result.report()["isolation"]["walls"] == iso["walls"]
    written = result.export(tmp_path / "office.xml")
    xml = next(p for p in written if str(p).endswith(".xml"))
    assert 'name="wall_00" type="box"' in xml.read_text()
    model = mujoco.MjModel.from_xml_path(str(xml))
    assert model.nbody - 1 == len(result.objects)  # the world, then one body per object
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    start = collision_vertices(model, data)
    for _ in range(500):
        mujoco.mj_step(model, data)
    assert np.isfinite(data.qpos).all()
    # What the frame shows held up by nothing in view (chairs whose legs the sensor missed,
    # things on the walls) is static, like what would tip over: nothing falls in a second.
    assert any(o["rests_on"] is None and o["static"] for o in result.objects)
    assert all(o["static"] == (not o["stands"]) for o in result.objects)
    assert largest_move(model, data, start) < 0.01
    # URDF: the floor and the walls box collisions of the root link; USD: static colliders
    import xml.etree.ElementTree as ET

    root = ET.parse(result.export(tmp_path / "office.urdf")[0]).getroot().find("link")
    names = [c.get("name") for c in root.findall("collision")]
    assert names == ["support"] + [f"wall_{k:02d}" for k in range(len(iso["walls"]))]
    from pxr import Usd, UsdPhysics

    stage = Usd.Stage.Open(str(result.export(tmp_path / "office.usda")[0]))
    wall = stage.GetPrimAtPath("/office/wall_00/box")
    assert wall.IsValid() and wall.HasAPI(UsdPhysics.CollisionAPI)
    assert not wall.GetParent().HasAPI(UsdPhysics.RigidBodyAPI)
    # the wall's box spans the wall's points
    lo, hi = np.asarray(iso["walls"][0]["bounds"])
    geom = model.geom(model.geom("wall_00").id)
    assert geom.size[0] * 2 >= 0.9 * min(hi[0] - lo[0], hi[1] - lo[1])
