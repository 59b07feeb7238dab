"""USD export (``usda``): the text read back by a small parser in this file, then by OpenUSD's own
``pxr`` (usd-core, in the ``sim`` extra): a rigid body root, one convex-hull collider Mesh per hull
holding exactly the hull, the input mesh as visual, and the writes refused / atomic as elsewhere."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import trimesh

import pointcvx
from pointcvx.cli import main
from pointcvx.export import format_for, mass_properties, usd_identifier, usda_text, visual_mesh

COLLIDER_APIS = ["PhysicsCollisionAPI", "PhysicsMeshCollisionAPI"]
BODY_APIS = ["PhysicsRigidBodyAPI", "PhysicsMassAPI"]


# ------------------------------------------------------------------------------ a small parser
_DEF = re.compile(r'^ *def (\w+) "(\w+)"( \()?$')
_ATTR = re.compile(r"^ *(uniform )?([\w\[\]]+) ([\w:]+) = (.+)$")
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def parse_usda(text: str) -> tuple[dict[str, str], dict[str, dict]]:
    """(layer metadata, prim path -> {type, meta: [lines], attrs: name -> (type, value, uniform)})
    of the subset of USD text the exporter writes; any other line fails the test."""
    lines = text.splitlines()
    assert lines[0] == "#usda 1.0" and lines[1] == "("
    end = lines.index(")")
    layer = dict(line.strip().split(" = ", 1) for line in lines[2:end])
    prims: dict[str, dict] = {}
    stack: list[dict] = []
    pending, in_meta = None, False
    for line in lines[end + 1:]:
        s = line.strip()
        if (m := _DEF.match(line)) is not None:
            path = "/".join(["", *(p["name"] for p in stack), m.group(2)])
            pending = {"type": m.group(1), "name": m.group(2), "path": path, "meta": [], "attrs": {}}
            in_meta = m.group(3) is not None
        elif in_meta:
            if s == ")":
                in_meta = False
            else:
                pending["meta"].append(s)
        elif s == "{":
            assert pending is not None and pending["path"] not in prims
            prims[pending["path"]] = pending
            stack.append(pending)
            pending = None
        elif s == "}":
            stack.pop()
        elif (m := _ATTR.match(line)) is not None:
            assert stack, line
            stack[-1]["attrs"][m.group(3)] = (m.group(2), m.group(4), m.group(1) is not None)
        else:
            assert s == "", f"unparsed line {line!r}"
    assert not stack and not in_meta
    return layer, prims


def numbers(value: str) -> np.ndarray:
    return np.array([float(x) for x in _NUMBER.findall(value)])


def api_schemas(prim: dict) -> list[str]:
    meta = [m for m in prim["meta"] if m.startswith("prepend apiSchemas = ")]
    return re.findall(r'"(\w+)"', meta[0]) if meta else []


def token(prim: dict, name: str) -> str | None:
    if name not in prim["attrs"]:
        return None
    kind, value, uniform = prim["attrs"][name]
    assert kind == "token" and uniform
    return value.strip('"')


def mesh_arrays(prim: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(v, 3) float points, (f,) int counts, (f, 3) int indices, (2, 3) float extent."""
    attrs = prim["attrs"]
    assert attrs["points"][0] == "point3f[]" and attrs["extent"][0] == "float3[]"
    assert attrs["faceVertexCounts"][0] == "int[]" and attrs["faceVertexIndices"][0] == "int[]"
    points = numbers(attrs["points"][1]).reshape(-1, 3)
    counts = numbers(attrs["faceVertexCounts"][1]).astype(np.int64)
    indices = numbers(attrs["faceVertexIndices"][1]).astype(np.int64).reshape(-1, 3)
    return points, counts, indices, numbers(attrs["extent"][1]).reshape(2, 3)


# ------------------------------------------------------------------------------ the text
def test_usda_text_holds_every_hull_exactly(result, source, tmp_path):
    path = result.export(tmp_path / "2 torus-v1.usda")[0]
    assert path == tmp_path / "2 torus-v1.usda"
    text = path.read_text()
    layer, prims = parse_usda(text)
    name = "_2_torus_v1"
    assert layer["defaultPrim"] == f'"{name}"' and layer["upAxis"] == '"Z"' and layer["metersPerUnit"] == "1"

    root = prims[f"/{name}"]
    assert root["type"] == "Xform" and api_schemas(root) == BODY_APIS
    mass = float(root["attrs"]["physics:mass"][1])
    pairs = [(h.vertices, h.faces) for h in result.hulls]
    expected_mass, expected_center, _ = mass_properties(pairs, 1000.0)
    assert mass == pytest.approx(expected_mass, rel=1e-8)
    assert mass == pytest.approx(1000.0 * sum(h.volume for h in result.hulls), rel=1e-6)
    center = numbers(root["attrs"]["physics:centerOfMass"][1])
    np.testing.assert_allclose(center, expected_center, rtol=0, atol=1e-8)
    assert np.abs(center).max() < 0.01  # about the torus's centre of symmetry, the origin
    assert prims[f"/{name}/collision"]["type"] == "Xform"

    hulls = {p: prim for p, prim in prims.items() if p.startswith(f"/{name}/collision/")}
    assert sorted(hulls) == [f"/{name}/collision/hull_{i:03d}" for i in range(len(result.hulls))]
    assert len(result.hulls) >= 2
    for i, h in enumerate(result.hulls):
        prim = hulls[f"/{name}/collision/hull_{i:03d}"]
        assert prim["type"] == "Mesh"
        points, counts, indices, extent = mesh_arrays(prim)
        np.testing.assert_allclose(points, h.vertices, rtol=1e-12, atol=0)
        assert (counts == 3).all() and np.array_equal(indices, h.faces)
        bounds = [h.vertices.min(axis=0), h.vertices.max(axis=0)]
        np.testing.assert_allclose(extent, bounds, rtol=1e-12, atol=0)
        assert api_schemas(prim) == COLLIDER_APIS
        assert token(prim, "physics:approximation") == "convexHull"
        assert token(prim, "purpose") == "guide"
        assert token(prim, "subdivisionScheme") == "none"
        solid = trimesh.Trimesh(points, indices, process=False)  # wound outward: positive volume
        assert solid.volume == pytest.approx(h.volume, rel=1e-9)

    visual = prims[f"/{name}/visual"]
    assert visual["type"] == "Mesh" and api_schemas(visual) == [] and token(visual, "purpose") is None
    points, counts, indices, extent = mesh_arrays(visual)
    mesh_v, mesh_f = visual_mesh(result)
    np.testing.assert_allclose(points, mesh_v, rtol=1e-12, atol=0)
    assert (counts == 3).all() and np.array_equal(indices, mesh_f)
    original = trimesh.load(source, force="mesh")
    assert len(indices) == len(original.faces)
    np.testing.assert_allclose(extent, original.bounds, atol=1e-9)  # input units
    assert trimesh.Trimesh(points, indices, process=False).volume == pytest.approx(original.volume, rel=1e-9)

    heavier = parse_usda(result.export(tmp_path / "light.usda", density=500.0)[0].read_text())[1]
    assert float(heavier["/light"]["attrs"]["physics:mass"][1]) == pytest.approx(mass / 2, rel=1e-8)


def test_usda_text_without_visual_and_with_faceless_hulls():
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    segment = (np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), np.zeros((0, 3), dtype=np.int64))
    hulls = [(box.vertices, box.faces), segment, (box.vertices + 5.0, box.faces)]
    _, prims = parse_usda(usda_text("b", hulls, None, 12.0, np.array([2.5, 2.5, 2.5])))
    assert sorted(prims) == ["/b", "/b/collision", "/b/collision/hull_000", "/b/collision/hull_002"]
    np.testing.assert_array_equal(numbers(prims["/b"]["attrs"]["physics:centerOfMass"][1]), [2.5, 2.5, 2.5])
    np.testing.assert_array_equal(mesh_arrays(prims["/b/collision/hull_002"])[0], box.vertices + 5.0)


def test_names_suffixes_and_cli_choice(tmp_path, capsys):
    assert [usd_identifier(n) for n in ("torus", "my part.v2", "3d", "", "é")] == \
        ["torus", "my_part_v2", "_3d", "_", "_"]
    assert format_for(tmp_path / "x.usda") == "usda" and format_for(tmp_path / "x.usd") == "usda"
    assert format_for(tmp_path / "x.usd", "usda") == "usda"
    with pytest.raises(pointcvx.OutputError, match="does not match"):
        format_for(tmp_path / "x.obj", "usda")
    with pytest.raises(SystemExit):
        main(["decompose", "--help"])
    assert "usda" in capsys.readouterr().out


# ------------------------------------------------------------------------------ OpenUSD itself
def test_openusd_reads_the_rigid_body_and_its_colliders(result, tmp_path):
    pytest.importorskip("pxr")
    from pxr import Usd, UsdGeom, UsdPhysics

    for path in (tmp_path / "torus.usda", tmp_path / "torus.usd"):
        result.export(path)
        assert path.read_text().startswith("#usda 1.0\n")
        stage = Usd.Stage.Open(str(path))
        assert stage is not None
        root = stage.GetDefaultPrim()
        assert root.GetPath() == "/torus" and root.IsA(UsdGeom.Xform)
        assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
        assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
        assert root.HasAPI(UsdPhysics.RigidBodyAPI) and root.HasAPI(UsdPhysics.MassAPI)
        mass = UsdPhysics.MassAPI(root).GetMassAttr().Get()
        assert mass == pytest.approx(1000.0 * sum(h.volume for h in result.hulls), rel=1e-6)

        colliders = [p for p in Usd.PrimRange(root) if p.HasAPI(UsdPhysics.CollisionAPI)]
        assert [p.GetName() for p in colliders] == [f"hull_{i:03d}" for i in range(len(result.hulls))]
        for prim, h in zip(colliders, result.hulls, strict=True):
            mesh = UsdGeom.Mesh(prim)
            assert mesh and prim.GetParent().GetPath() == "/torus/collision"
            points = np.array(mesh.GetPointsAttr().Get(), dtype=np.float64)  # point3f: float32
            np.testing.assert_allclose(points, h.vertices, rtol=1e-6, atol=1e-6 * np.abs(h.vertices).max())
            assert list(mesh.GetFaceVertexCountsAttr().Get()) == [3] * len(h.faces)
            assert np.array_equal(np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3), h.faces)
            assert mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.rightHanded
            assert UsdGeom.Imageable(prim).ComputePurpose() == UsdGeom.Tokens.guide
            assert prim.HasAPI(UsdPhysics.MeshCollisionAPI)
            approximation = UsdPhysics.MeshCollisionAPI(prim).GetApproximationAttr().Get()
            assert approximation == UsdPhysics.Tokens.convexHull
            assert UsdPhysics.CollisionAPI(prim).GetCollisionEnabledAttr().Get()
            computed = np.array(UsdGeom.Boundable.ComputeExtentFromPlugins(mesh, Usd.TimeCode.Default()))
            np.testing.assert_allclose(np.array(mesh.GetExtentAttr().Get()), computed, rtol=1e-6)

        visual = stage.GetPrimAtPath("/torus/visual")
        assert visual.IsA(UsdGeom.Mesh) and not visual.HasAPI(UsdPhysics.CollisionAPI)
        assert UsdGeom.Imageable(visual).ComputePurpose() == UsdGeom.Tokens.default_
        assert len(UsdGeom.Mesh(visual).GetFaceVertexCountsAttr().Get()) == len(visual_mesh(result)[1])

        if _has_validation():
            from pxr import UsdValidation

            validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
            errors = UsdValidation.ValidationContext(validators).Validate(stage)
            assert [(e.GetName(), e.GetMessage()) for e in errors] == []


def _has_validation() -> bool:
    try:
        from pxr import UsdValidation  # noqa: F401  (OpenUSD 24.11 and later)
    except ImportError:
        return False
    return True


# ------------------------------------------------------------------------------ writing
def test_usda_write_is_refused_over_a_file_and_atomic(result, tmp_path, monkeypatch):
    path = tmp_path / "t.usda"
    path.write_text("mine")
    with pytest.raises(pointcvx.OutputError, match="exists"):
        result.export(path)
    assert path.read_text() == "mine"

    def broken(self, *args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Path, "write_text", broken)
    with pytest.raises(pointcvx.OutputError, match="nothing was written"):
        result.export(path, overwrite=True)
    monkeypatch.undo()
    assert path.read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["t.usda"]

    assert result.export(path, overwrite=True) == [path]
    assert path.read_text().startswith("#usda 1.0\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.usda"]


def test_usd_colliders_thicken_flat_hulls_as_the_robot_files_do(result, tmp_path):
    """A flat hull (PhysX cannot cook a coplanar convex mesh) is written as a thin slab that
    contains it, the same collider URDF and MJCF get."""
    from dataclasses import replace

    from pointcvx.decomposition.hull import convex_hull
    from pointcvx.decomposition.limits import outside_distance

    ang = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    flat = convex_hull(np.stack([np.cos(ang), np.sin(ang), 0 * ang], axis=1) * 0.3 + [0, 0, 2.0])
    assert flat.dim == 2
    odd = replace(result, hulls=[*result.hulls, pointcvx.ConvexHull(flat.vertices, flat.faces, 0.0, 12)])
    _, prims = parse_usda(odd.export(tmp_path / "odd.usda")[0].read_text())
    root = f"/{usd_identifier('odd')}/collision"
    points, counts, faces, _ = mesh_arrays(prims[f"{root}/hull_{len(result):03d}"])
    slab = trimesh.Trimesh(points, faces, process=False)
    assert slab.is_watertight and slab.volume > 0
    assert outside_distance(flat.vertices, points, faces).max() <= 1e-12
    urdf_slab = trimesh.load(odd.export(tmp_path / "odd.urdf")[0].parent / f"odd_collision_{len(result)}.obj",
                             process=False)
    assert np.allclose(np.sort(points, axis=0), np.sort(urdf_slab.vertices, axis=0), rtol=0, atol=1e-12)
