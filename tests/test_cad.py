"""CAD loading (STEP/STP, IGES) through gmsh: every dev part, multi-body merging, the sample part,
corrupted files and a missing gmsh."""

from __future__ import annotations

import sys
import time

import gmsh  # noqa: E402 - the [cad] extra is part of the test install
import numpy as np
import pytest

import pointcvx
from conftest import DATA
from pointcvx import InputError, MissingExtraError
from pointcvx.io.cad import gmsh_session, tessellate_cad, write_step_sample
from pointcvx.solid import Solid

CAD = DATA / "dev" / "cad"
STEPS = sorted(p for p in CAD.glob("*") if p.suffix.lower() in (".step", ".stp")) if CAD.is_dir() else []
MULTI_BODY = "box_sides.STEP"  # the only dev part with several solids (10)


@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    path = tmp_path_factory.mktemp("cad") / "bracket.step"
    assert write_step_sample(path) == path
    return path


@pytest.mark.parametrize("path", STEPS, ids=[p.name for p in STEPS])
def test_every_dev_step_loads(path):
    cloud = pointcvx.load(path, n_points=2000, cad_mesh_size=0.03)
    assert cloud.modality == "cad"
    assert len(cloud) == 2000
    assert np.allclose(np.linalg.norm(cloud.normals, axis=1), 1.0)
    assert np.abs(cloud.points).max() <= 1.0 + 1e-9
    info = cloud.info
    assert info["format"] == "step" and info["bodies"] >= 1 and info["surfaces"] >= 1
    assert info["surfaces_failed"] == 0 and info["triangles"] > 100
    assert cloud.mesh is not None and cloud.mesh.is_watertight
    # outward: stepping a little along the normal leaves the solid
    probe = cloud.points[::10] + 2e-3 * cloud.normals[::10]
    assert Solid.from_trimesh(cloud.mesh).contains(probe).mean() < 0.05
    assert not gmsh.isInitialized()


def test_default_tessellation_time_and_determinism():
    path = CAD / "bug3883_xr2-ct-214_l-bracket.stp"
    t0 = time.perf_counter()
    cloud = pointcvx.load(path)
    elapsed = time.perf_counter() - t0
    assert elapsed < 20.0  # measured 1.1 s (all dev parts: 0.3-5.4 s at the defaults)
    assert cloud.info["triangles"] > 20000 and len(cloud) == 20000
    again = pointcvx.load(path)
    assert np.array_equal(cloud.points, again.points) and np.array_equal(cloud.normals, again.normals)


def test_multi_body_step_is_merged():
    mesh = tessellate_cad(CAD / MULTI_BODY, mesh_size=0.03)
    meta = mesh.metadata["cad"]
    assert meta["bodies"] == 10 and meta["surfaces"] == 417
    assert len(mesh.split(only_watertight=False)) == 10  # one closed piece per body
    assert mesh.is_watertight
    cloud = pointcvx.load(CAD / MULTI_BODY, n_points=3000, cad_mesh_size=0.03)
    assert cloud.info["bodies"] == 10 and cloud.info["components"] == 10


def test_sample_part_is_small_and_non_convex(sample):
    assert sample.stat().st_size < 200_000
    assert pointcvx.detect(sample).format == "step"
    mesh = tessellate_cad(sample)
    assert mesh.metadata["cad"]["bodies"] == 1 and mesh.is_watertight
    assert mesh.volume < 0.6 * mesh.convex_hull.volume  # measured 0.445
    cloud = pointcvx.load(sample, n_points=5000)
    assert cloud.modality == "cad" and len(cloud) == 5000


def test_iges_faces_are_sewn(sample, tmp_path):
    path = tmp_path / "bracket.igs"
    with gmsh_session(gmsh):
        gmsh.model.occ.importShapes(str(sample))
        gmsh.model.occ.synchronize()
        gmsh.write(str(path))
    # gmsh leaves the IGES start section blank: detection must not depend on it
    assert path.read_text().split("\n")[0][:72].strip() == ""
    cloud = pointcvx.load(path, n_points=3000)
    assert cloud.info["format"] == "iges"
    # IGES holds loose faces; they are sewn into the solid before meshing
    assert cloud.info["healed"] and cloud.info["bodies"] == 1 and cloud.info["watertight"]


def test_corrupted_step_raises(tmp_path):
    real = (CAD / "OCC2368.stp").read_bytes()
    cut = tmp_path / "cut.stp"
    cut.write_bytes(real[: len(real) // 2])
    with pytest.raises(InputError, match=r"cut\.stp: corrupted or unreadable STEP \(.*end of file"):
        pointcvx.load(cut)
    garbage = tmp_path / "garbage.step"
    garbage.write_text("ISO-10303-21;\nHEADER;\nFILE_DESCRIPTION((''),'2;1');\nENDSEC;\nDATA;\n"
                       "#1=CARTESIAN_POINT('',(0.,0.,\n#2=(((;\nENDSEC;\nEND-ISO-10303-21;\n")
    with pytest.raises(InputError, match=r"garbage\.step: corrupted or unreadable STEP"):
        pointcvx.load(garbage)
    assert not gmsh.isInitialized()


def test_step_without_surfaces_raises(tmp_path):
    path = tmp_path / "wire.step"
    with gmsh_session(gmsh):
        occ = gmsh.model.occ
        occ.addLine(occ.addPoint(0, 0, 0), occ.addPoint(10, 0, 0))
        occ.synchronize()
        gmsh.write(str(path))
    with pytest.raises(InputError, match=r"wire\.step: the STEP holds no solid or surface"):
        pointcvx.load(path)


def test_callers_gmsh_session_is_left_alone(sample):
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("mine")
        gmsh.option.setNumber("Mesh.MeshSizeMax", 123.0)
        tessellate_cad(sample, mesh_size=0.05)  # in a child process
        tessellate_cad(sample, mesh_size=0.05, isolate=False)  # in the caller's gmsh
        assert gmsh.isInitialized()
        assert gmsh.model.getCurrent() == "mine"
        assert gmsh.option.getNumber("Mesh.MeshSizeMax") == 123.0
    finally:
        gmsh.finalize()


def test_missing_gmsh_names_the_extra(sample, monkeypatch):
    monkeypatch.setitem(sys.modules, "gmsh", None)
    msg = r"STEP/IGES input needs the optional package 'gmsh': pip install 'pointcvx\[cad\]'"
    with pytest.raises(MissingExtraError, match=msg):
        pointcvx.load(sample)
    with pytest.raises(MissingExtraError, match=msg):
        write_step_sample(sample.parent / "other.step")


# ------------------------------------------------------------------------------ child process
def test_tessellation_in_a_child_equals_in_process_and_leaves_the_caller_alone(sample):
    import locale

    before = locale.setlocale(locale.LC_ALL)
    isolated = tessellate_cad(CAD / "linkrods.step")  # the default: a fresh child process
    assert locale.setlocale(locale.LC_ALL) == before  # gmsh resets the locale of its process
    assert not gmsh.isInitialized()
    here = tessellate_cad(CAD / "linkrods.step", isolate=False)
    assert np.array_equal(isolated.vertices, here.vertices) and np.array_equal(isolated.faces, here.faces)
    assert isolated.metadata["cad"] == here.metadata["cad"]
    # a file gmsh cannot read gives the same one-line error through the child
    junk = sample.parent / "junk.step"
    junk.write_text("ISO-10303-21;\nDATA;\n#1=(((;\nENDSEC;\nEND-ISO-10303-21;\n")
    messages = []
    for isolate in (True, False):
        with pytest.raises(InputError, match=r"junk\.step: corrupted or unreadable STEP") as info:
            tessellate_cad(junk, isolate=isolate)
        messages.append(str(info.value))
    assert messages[0] == messages[1] and "\n" not in messages[0]


def test_a_crash_in_the_child_is_an_input_error(sample, monkeypatch):
    from pointcvx.io import cad

    crash = [sys.executable, "-c", "import os, signal; os.kill(os.getpid(), signal.SIGSEGV)"]
    monkeypatch.setattr(cad, "_child_command", lambda *args: crash)
    crashed = r"bracket\.step: gmsh/OpenCASCADE crashed reading the STEP \(SIGSEGV\)"
    with pytest.raises(InputError, match=crashed):
        pointcvx.load(sample)


def test_an_interrupted_tessellation_kills_its_child(sample, tmp_path, monkeypatch):
    import os

    from pointcvx.apps.batch import AssetTimeout
    from pointcvx.apps.batch import Guard as _Guard
    from pointcvx.io import cad

    pid_file = tmp_path / "child.pid"
    slow = [sys.executable, "-c",
            f"import os, time; open({str(pid_file)!r}, 'w').write(str(os.getpid())); time.sleep(60)"]
    monkeypatch.setattr(cad, "_child_command", lambda *args: slow)
    guard = _Guard(timeout=1.0, max_mb=None).start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(AssetTimeout):
            tessellate_cad(sample)
    finally:
        guard.stop()
    assert time.perf_counter() - t0 < 10.0
    pid = int(pid_file.read_text())
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)
