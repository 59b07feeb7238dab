"""Exports (OBJ, STL, GLB/GLTF, URDF, MJCF, JSON report) and engine per-hull limits: every cap
respected, every hull still contains its part, added volume reported, all deterministic."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections import Counter
from dataclasses import replace

import numpy as np
import pytest
import trimesh

import pointcvx
from pointcvx.cli import EXIT_INPUT, EXIT_USAGE, main
from pointcvx.decomposition.hull import convex_hull
from pointcvx.decomposition.limits import TARGETS, hull_limits, outside_distance, simplify_hull
from pointcvx.evaluate import load_hulls
from pointcvx.export import FORMATS

FAST = dict(features="model", n_points=3000, seed=0)
CAPS = {  # target -> (most vertices, most triangles) per hull
    "mujoco": (None, None), "bullet": (None, None), "physx": (255, 255),
    "physx-gpu": (64, 64), "newton": (64, None), "unity": (None, 255),
}


def _closed_convex_outward(vertices, faces) -> bool:
    """Every edge used by exactly two faces, in opposite directions; all vertices behind every
    face plane; positive volume."""
    directed = Counter(map(tuple, np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])))
    paired = all(n == 1 and directed.get((b, a)) == 1 for (a, b), n in directed.items())
    scale = float(np.ptp(vertices, axis=0).max())
    convex = outside_distance(vertices, vertices, faces).max() <= 1e-9 * scale
    return paired and convex and pointcvx.ConvexHull(vertices, faces, 0.0, 0).volume > 0


def _part_points(result, i):
    """(n, 3) float: the cloud points of hull i's part, in input units."""
    return result.cloud.normalization.inverse(result.cloud.points[result.labels == i])


# ------------------------------------------------------------------------------ limits
@pytest.mark.parametrize("target", sorted(TARGETS))
def test_engine_caps_hold_and_hulls_still_contain_their_parts(result, target):
    max_v, max_f = CAPS[target]
    limited = result.limit_hulls(target)
    assert len(limited) == len(result)
    reduced = 0
    for i, (before, after) in enumerate(zip(result.hulls, limited.hulls, strict=True)):
        assert max_v is None or len(after.vertices) <= max_v
        assert max_f is None or len(after.faces) <= max_f
        assert _closed_convex_outward(after.vertices, after.faces)
        scale = float(np.ptp(before.vertices, axis=0).max())
        assert outside_distance(before.vertices, after.vertices, after.faces).max() <= 1e-9 * scale
        assert outside_distance(_part_points(result, i), after.vertices, after.faces).max() <= 1e-9 * scale
        assert after.added_volume >= 0.0
        assert after.added_volume == pytest.approx(after.volume - before.volume, rel=1e-9, abs=1e-12)
        if after.vertices is before.vertices:
            assert after.added_volume == 0.0
        else:
            reduced += 1
            assert after.added_volume > 0.0
    if max_v is None and max_f is None:
        assert reduced == 0 and limited.added_volume == 0.0
    else:
        assert reduced == len(result)  # ~200-vertex hulls are over every cap
        assert 0 < limited.added_volume < 0.5 * sum(h.volume for h in result.hulls)
    report = limited.report()
    assert report["limits"]["target"] == target
    assert report["totals"]["added_volume"] == pytest.approx(limited.added_volume)
    assert [h["added_volume"] for h in report["hulls"]] == [h.added_volume for h in limited.hulls]
    assert limited.summary()["added_volume"] == pytest.approx(limited.added_volume)


def test_limits_are_deterministic_and_survive_recut(result):
    a, b = result.limit_hulls("physx-gpu"), result.limit_hulls("physx-gpu")
    for x, y in zip(a.hulls, b.hulls, strict=True):
        np.testing.assert_array_equal(x.vertices, y.vertices)
        np.testing.assert_array_equal(x.faces, y.faces)
        assert x.added_volume == y.added_volume
    coarser = a.recut(max_hulls=3)
    assert len(coarser) <= 3 and coarser.params["hull_limits"]["target"] == "physx-gpu"
    assert all(len(h.vertices) <= 64 and len(h.faces) <= 64 for h in coarser.hulls)
    assert all(h.added_volume > 0 for h in coarser.hulls)
    # limiting twice never loosens anything and keeps counting from the plain hulls
    twice = a.limit_hulls(max_vertices=12)
    assert all(len(h.vertices) <= 12 for h in twice.hulls)
    assert all(t.added_volume >= h.added_volume for t, h in zip(twice.hulls, a.hulls, strict=True))


def _ellipsoid_hull(n=1500, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p = p / np.linalg.norm(p, axis=1, keepdims=True) * [2.0, 1.0, 0.5] + [10.0, -3.0, 7.0]
    return convex_hull(p)


@pytest.mark.parametrize("caps", [{"target": "physx"}, {"target": "unity"}, {"max_vertices": 4},
                                  {"max_vertices": 7}, {"max_faces": 20},
                                  {"target": "physx-gpu", "max_vertices": 40}])
def test_simplify_a_large_hull(caps):
    hull = _ellipsoid_hull()
    limits = hull_limits(**caps)
    v, f, added = simplify_hull(hull.vertices, hull.faces, limits)
    assert limits.allows(v, f) and len(v) <= limits.vertex_budget()
    assert _closed_convex_outward(v, f)
    assert outside_distance(hull.vertices, v, f).max() <= 1e-9 * 4.0
    assert added > 0 and added == pytest.approx(pointcvx.ConvexHull(v, f, 0, 0).volume - hull.volume)
    if limits.vertex_budget() >= 100:  # a generous budget costs little volume
        assert added < 0.1 * hull.volume
    v2, f2, added2 = simplify_hull(hull.vertices, hull.faces, limits)
    np.testing.assert_array_equal(v, v2)
    np.testing.assert_array_equal(f, f2)
    assert added == added2


def test_simplify_a_flat_hull_stays_flat_and_contains_it():
    ang = np.linspace(0, 2 * np.pi, 300, endpoint=False)
    rot = np.array([[1, 0, 0], [0, 0.6, 0.8], [0, -0.8, 0.6]])
    flat = convex_hull(np.stack([np.cos(ang), np.sin(ang), 0 * ang], axis=1) @ rot + [1, 2, 3])
    assert flat.dim == 2
    v, f, added = simplify_hull(flat.vertices, flat.faces, hull_limits("physx-gpu"))
    assert len(v) <= 64 and len(f) <= 64 and added == 0.0
    out = convex_hull(v)
    assert out.dim == 2
    assert (flat.vertices @ out.equations[:, :3].T + out.equations[:, 3]).max() <= 1e-9
    assert out.area / 2 >= flat.area / 2


def test_bad_limits_are_refused():
    with pytest.raises(pointcvx.InputError, match="unknown engine target"):
        hull_limits("havok")
    with pytest.raises(pointcvx.InputError, match="at least 4"):
        hull_limits(max_vertices=3)
    assert hull_limits("physx", max_vertices=100).max_vertices == 100
    assert hull_limits("newton", max_vertices=100).max_vertices == 64
    assert hull_limits("unity").vertex_budget() == 129  # 2 v - 4 triangles


def test_decompose_applies_engine_caps_and_refuses_bad_ones_before_work(source, result):
    capped = pointcvx.decompose(source, target="physx-gpu", max_hull_vertices=40, **FAST)
    assert len(capped) == len(result)
    assert max(len(h.vertices) for h in capped.hulls) <= 40
    assert capped.params["hull_limits"]["max_vertices"] == 40
    assert capped.added_volume > 0
    with pytest.raises(pointcvx.InputError, match="unknown target 'havok'"):
        pointcvx.decompose(source / "missing.obj", target="havok")  # refused before loading


# ------------------------------------------------------------------------------ exports
def test_every_format_writes_what_it_promises(result, tmp_path):
    n = len(result)
    pairs = [(h.vertices, h.faces) for h in result.hulls]
    # combined OBJ: one object per hull
    out = result.export(tmp_path / "t.obj")
    assert out == [tmp_path / "t.obj"] and out[0].read_text().count("\no hull_") == n
    back = load_hulls(out[0])
    assert len(back) == n
    for v, h in zip(back, result.hulls, strict=True):  # full precision: read-back hulls are the hulls
        assert np.array_equal(np.asarray(v, dtype=np.float64), h.vertices)
    # per-hull STL in the folder named by the stem
    stl = result.export(tmp_path / "parts.stl")
    assert [p.name for p in stl] == [f"hull_{i:03d}.stl" for i in range(n)]
    for p, (v, f) in zip(stl, pairs, strict=True):
        mesh = trimesh.load(p)
        assert mesh.is_watertight and len(mesh.faces) == len(f)
        np.testing.assert_allclose(np.sort(mesh.vertices, axis=0), np.sort(v, axis=0), rtol=1e-6)
    # GLB and GLTF: a node per hull
    for fmt in ("glb", "gltf"):
        (path,) = result.export(tmp_path / f"t.{fmt}")
        scene = trimesh.load(path)
        assert sorted(scene.graph.nodes_geometry) == [f"hull_{i:03d}" for i in range(n)]
        got = scene.geometry[scene.graph["hull_000"][1]]
        np.testing.assert_allclose(np.sort(got.vertices, axis=0), np.sort(pairs[0][0], axis=0), rtol=1e-6)
    # JSON report
    (path,) = result.export(tmp_path / "t.json")
    rep = json.loads(path.read_text())
    assert [h["vertices"] for h in rep["hulls"]] == [len(v) for v, _ in pairs]
    assert [h["concavity"] for h in rep["hulls"]] == pytest.approx(result.concavity.tolist())
    assert rep["totals"]["hulls"] == n and rep["totals"]["volume"] == pytest.approx(
        sum(h.volume for h in result.hulls))
    assert rep["seed"] == 0 and rep["parameters"]["features"] == "model"
    assert rep["timings"]["total"] > 0 and rep["limits"] is None
    assert rep["totals"]["points"] == len(result.labels)


def test_urdf_has_a_collision_per_hull_and_the_input_as_visual(result, tmp_path, source):
    files = result.export(tmp_path / "torus.urdf", density=500.0)
    folder = tmp_path / "torus_urdf"
    assert files[0] == folder / "torus.urdf" and all(f.parent == folder for f in files)
    root = ET.parse(files[0]).getroot()
    (link,) = root.findall("link")
    collisions = link.findall("collision")
    assert len(collisions) == len(result)
    for i, c in enumerate(collisions):
        mesh = folder / c.find("geometry/mesh").get("filename")
        got = trimesh.load(mesh, process=False)
        np.testing.assert_allclose(got.vertices, result.hulls[i].vertices, rtol=1e-15, atol=1e-15)
        np.testing.assert_array_equal(got.faces, result.hulls[i].faces)
    (visual,) = link.findall("visual")
    shape = trimesh.load(folder / visual.find("geometry/mesh").get("filename"))
    np.testing.assert_allclose(shape.bounds, trimesh.load(source).bounds, atol=1e-9)
    mass = float(link.find("inertial/mass").get("value"))
    assert mass == pytest.approx(500.0 * sum(h.volume for h in result.hulls), rel=1e-6)
    # pybullet (the [baselines] extra) loads it: one collision shape per hull
    import pybullet

    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(files[0]), physicsClientId=client)
        shapes = pybullet.getCollisionShapeData(body, -1, physicsClientId=client)
        assert len(shapes) == len(result)
    finally:
        pybullet.disconnect(client)


def test_mjcf_follows_obj2mjcf_and_mujoco_loads_it(result, tmp_path):
    import mujoco

    files = result.export(tmp_path / "torus.mjcf")
    assert files[0] == tmp_path / "torus_mjcf" / "torus.xml"
    model = mujoco.MjModel.from_xml_path(str(files[0]))
    groups = Counter(int(g) for g in model.geom_group)
    assert groups == {2: 1, 3: len(result)}
    visual = [g for g in range(model.ngeom) if model.geom_group[g] == 2]
    assert all(model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0 for g in visual)
    assert model.nmesh == len(result) + 1 and model.nbody == 2 and model.njnt == 1
    assert model.body_mass[1] == pytest.approx(1000.0 * sum(h.volume for h in result.hulls), rel=1e-6)
    static = result.export(tmp_path / "fixed.xml", free_joint=False)
    assert mujoco.MjModel.from_xml_path(str(static[0])).njnt == 0


def test_robot_files_thicken_flat_hulls_so_simulators_take_them(result, tmp_path):
    import mujoco

    ang = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    flat = convex_hull(np.stack([np.cos(ang), np.sin(ang), 0 * ang], axis=1) * 0.3 + [0, 0, 2.0])
    assert flat.dim == 2
    odd = replace(result, hulls=[*result.hulls, pointcvx.ConvexHull(flat.vertices, flat.faces, 0.0, 12)])
    files = odd.export(tmp_path / "odd.xml")
    model = mujoco.MjModel.from_xml_path(str(files[0]))  # MuJoCo refuses coplanar meshes
    assert int((model.geom_group == 3).sum()) == len(odd)
    slab = trimesh.load(tmp_path / "odd_mjcf" / f"odd_collision_{len(result)}.obj", process=False)
    assert slab.is_watertight and slab.volume > 0
    assert outside_distance(flat.vertices, slab.vertices, slab.faces).max() <= 1e-12


def test_format_dispatch_and_bad_choices(result, tmp_path):
    (tmp_path / "a").mkdir()
    assert result.export(tmp_path / "a", "json")[0] == tmp_path / "a" / "hulls.json"
    assert result.export(tmp_path / "robot", "urdf")[0] == tmp_path / "robot" / "robot.urdf"
    assert result.export(tmp_path / "m.xml")[0].name == "m.xml"
    for bad, fmt, match in [("x.ply", None, "unsupported output format"),
                            ("x.obj", "urdf", "does not match"),
                            ("x.obj", "fbx", "unknown output format")]:
        with pytest.raises(pointcvx.OutputError, match=match):
            result.export(tmp_path / bad, fmt)
        assert not (tmp_path / bad).exists()
    assert set(FORMATS) == {"obj", "stl", "glb", "gltf", "urdf", "mjcf", "usda", "json"}


def test_folder_exports_are_all_or_nothing(result, tmp_path):
    (tmp_path / "blocked").write_text("a file, not a folder")
    with pytest.raises(pointcvx.OutputError, match="cannot create the output folder"):
        result.export(tmp_path / "blocked" / "x.xml")
    # a failure half-way through writing leaves nothing behind: with a 240-character name the
    # folder, the robot file and the temporary names fit the file system's 255 bytes, but the
    # first hull's file, NAME_collision_0.obj, does not
    name = "n" * 240
    with pytest.raises(pointcvx.OutputError, match="cannot write"):
        result.export(tmp_path / f"{name}.urdf")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocked"]  # no folder, no temporary
    assert result.export(tmp_path / "robot.urdf")[0].is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocked", "robot_urdf"]


def test_export_never_writes_over_the_input(result, source):
    before = source.read_bytes()
    with pytest.raises(pointcvx.OutputError, match="input"):
        result.export(source, overwrite=True)
    assert source.read_bytes() == before


# ------------------------------------------------------------------------------ command line
def _exit_code(argv) -> int:
    """``main``'s status; usage errors leave through argparse's SystemExit."""
    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code)


def test_cli_target_format_and_refusals(source, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    args = ["decompose", str(source), "--features", "model", "-n", "3000"]
    assert main([*args, "--format", "mjcf", "--target", "physx-gpu", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    main_file = tmp_path / "torus_hulls_mjcf" / "torus_hulls.xml"
    assert summary["output"] == str(main_file) and main_file.is_file()
    assert summary["format"] == "mjcf" and summary["max_hull_vertices"] <= 64
    assert summary["added_volume"] > 0 and summary["hull_limits"]["target"] == "physx-gpu"
    assert summary["files"] == summary["hulls"] + 2  # xml, visual, one OBJ per hull
    before = {p: p.stat().st_mtime_ns for p in main_file.parent.iterdir()}
    # refused before decomposing, one line, nothing touched
    for extra, code, fragment in [
        (["--format", "mjcf"], EXIT_INPUT, "exists"),
        (["--format", "ply"], EXIT_USAGE, "invalid choice"),
        (["--target", "havok"], EXIT_USAGE, "unknown target 'havok'"),
        (["--max-hull-vertices", "2"], EXIT_USAGE, "at least 4"),
        (["-o", "x.obj", "--format", "urdf"], EXIT_INPUT, "does not match"),
        (["-o", "x.glb", "--per-hull"], EXIT_INPUT, "--per-hull"),
        (["-o", str(source), "--overwrite"], EXIT_INPUT, "input"),
    ]:
        assert _exit_code([*args, *extra]) == code, extra
        err = capsys.readouterr().err.strip()
        assert err.startswith("pointcvx: error:") and "\n" not in err and fragment in err, err
    assert {p: p.stat().st_mtime_ns for p in main_file.parent.iterdir()} == before
    assert not (tmp_path / "x.obj").exists() and not (tmp_path / "x").exists()
    # the text summary reports the caps and the added volume
    assert main([*args, "-o", "h.obj", "--max-hull-vertices", "16"]) == 0
    line = capsys.readouterr().out.strip()
    assert "vertices <= 16" in line and "added volume" in line and line.endswith("h.obj")
    assert max(len(v) for v in load_hulls(tmp_path / "h.obj")) <= 16


def test_cli_and_api_apply_a_target_the_same_way(source, tmp_path, capsys, monkeypatch):
    """``--target`` on the command line and ``target=`` in the API record the same caps and give
    the same hulls, also for an engine without caps (MuJoCo), which the command line once
    skipped."""
    monkeypatch.chdir(tmp_path)
    assert main(["decompose", str(source), "--features", "model", "-n", "3000", "--target", "mujoco",
                 "-o", "mujoco.obj", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    api = pointcvx.decompose(source, features="model", n_points=3000, target="mujoco")
    assert summary["hull_limits"] == api.params["hull_limits"]
    assert summary["hull_limits"]["target"] == "mujoco"
    assert summary["hulls"] == len(api.hulls)
    assert summary["max_hull_vertices"] == max(len(h.vertices) for h in api.hulls)
    assert summary["added_volume"] == pytest.approx(api.added_volume, rel=1e-9, abs=1e-12)
