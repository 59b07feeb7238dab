"""Start-up: a command imports only what it uses (issue 20).

Each check runs the real command in a fresh interpreter with ``python -X importtime``, which
names every module the process imported, so a test fails as soon as a heavy library is pulled
in where it is not needed. Times are not asserted (shared CI machines are noisy); the measured
ones are in docs/benchmarks.md ("One-shot start-up").
"""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from conftest import ROOT

MUG = ROOT / "io" / "mug.obj"
#: Libraries that cost a noticeable part of a second (or several) to import.
HEAVY = ("torch", "open3d", "sklearn", "skimage", "scipy", "trimesh", "manifold3d", "numpy")


def imported(*args: str, code: str | None = None, module: str = "pointcvx", status: int = 0) -> set[str]:
    """The modules a fresh ``python -X importtime`` process imports running ``-m MODULE ARGS``
    (or ``-c CODE``); the process must exit with ``status``."""
    run = ["-c", code] if code is not None else ["-m", module, *args]
    cmd = [sys.executable, "-X", "importtime", *run]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert res.returncode == status, res.stderr[-2000:]
    names = set(re.findall(r"^import time:\s+\d+ \|\s+\d+ \|\s*(\S+)$", res.stderr, re.M))
    assert "pointcvx" in names or code is not None, res.stderr[-2000:]  # the log was read
    return names


def heavy(names: set[str]) -> set[str]:
    return {h for h in HEAVY if h in names}


@pytest.mark.parametrize("args", [["--help"], ["--version"], ["info", "--help"], ["train", "--help"],
                                  ["evaluate", "--help"]])
def test_help_imports_no_numpy_or_heavier(args):
    names = imported(*args)
    assert heavy(names) == set(), heavy(names)
    assert "pointcvx.cli.info" in names and "pointcvx.cli.bench" in names  # every parser was built
    assert not any(n.startswith(("pointcvx.pipeline", "pointcvx.export", "pointcvx.io")) for n in names)


@pytest.mark.parametrize("command", ["decompose", "batch", "bench"])
def test_help_of_the_decomposing_commands_imports_no_torch(command):
    # their --help lists the output formats, read from pointcvx.export (numpy): no more than that
    names = imported(command, "--help")
    assert heavy(names) <= {"numpy"}, heavy(names)


def test_info_on_a_mesh_imports_no_torch(tmp_path):
    names = imported("info", str(MUG), "--json")
    assert "trimesh" in names and "pointcvx.io.mesh" in names  # it did load the mesh
    assert not {"torch", "sklearn", "skimage"} & names
    assert not any(n.startswith(("pointcvx.pipeline", "pointcvx.model", "pointcvx.features",
                                 "pointcvx.decomposition")) for n in names)


def test_evaluate_imports_no_torch(tmp_path):
    import trimesh

    hull = tmp_path / "hull.obj"
    trimesh.load(MUG, force="mesh").convex_hull.export(hull)
    names = imported("evaluate", str(MUG), str(hull), "--samples", "500")
    assert "pointcvx.evaluate" in names
    assert not {"torch", "sklearn"} & names


def test_import_pointcvx_is_the_face_only():
    names = imported(code="import pointcvx")
    assert heavy(names) == set(), heavy(names)
    assert {n for n in names if n.startswith("pointcvx")} <= {"pointcvx", "pointcvx.syslibs",
                                                               "pointcvx.errors", "pointcvx.version"}


def test_the_lazy_face_gives_every_public_name():
    code = (
        "import pointcvx, sys\n"
        "assert 'numpy' not in sys.modules\n"
        "from pointcvx import decompose, load, OrientedCloud, InputError, Decomposition\n"
        "from pointcvx.pipeline import decompose as d\n"
        "from pointcvx.errors import InputError as E\n"
        "assert decompose is d and pointcvx.decompose is d and InputError is E\n"
        "assert pointcvx.io.from_numpy is not None   # a sub-package as an attribute\n"
        "ns = {}\n"
        "exec('from pointcvx import *', ns)\n"
        "missing = [n for n in pointcvx.__all__ if n not in ns]\n"
        "assert not missing, missing\n"
        "assert set(pointcvx.__all__) <= set(dir(pointcvx))\n"
        "try:\n"
        "    pointcvx.no_such_name\n"
        "except AttributeError as exc:\n"
        "    assert 'no_such_name' in str(exc)\n"
        "else:\n"
        "    raise SystemExit('no AttributeError')\n"
        "print('ok')\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert res.returncode == 0 and res.stdout.strip() == "ok", res.stderr[-2000:]


def test_the_baselines_one_shot_wrapper_adds_nothing_heavy():
    # the thin wrapper process of CoACD and V-HACD: what it imports before the library's own
    # (run without arguments it prints its usage and exits with status 2, having loaded all it
    # loads before a job: the package face and this module)
    names = imported(module="pointcvx.apps.bench.oneshot", status=2)
    assert "pointcvx.apps.bench" in names
    assert heavy(names) == set(), heavy(names)
    assert not {n for n in names if n.startswith("pointcvx.apps.bench.")}  # no other bench module


def test_open3d_comes_without_its_plotly_drawing_until_that_is_called(tmp_path):
    """pointcvx's open3d import skips dash and plotly (half of open3d's import); a user's call of
    open3d's plotly drawing still loads and runs the real one."""
    code = ("import sys, numpy as np; from pointcvx.syslibs import import_open3d; o3d = import_open3d(); "
            "assert 'open3d.pybind' in sys.modules and 'dash' not in sys.modules; "
            "pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.random.rand(20, 3))); "
            "fig = o3d.visualization.get_plotly_fig([pcd]); "
            "assert type(fig).__name__ == 'Figure' and len(fig.data) == 1, fig; "
            "assert 'dash' in sys.modules")
    names = imported(code=code)
    assert "open3d" in names and "plotly" in names
    # A mesh decomposed with the fast features: open3d is used, dash never imported.
    names = imported("decompose", str(MUG), "-o", str(tmp_path / "mug.obj"),
                     "-q", "--features", "fast", "-n", "3000")
    assert "open3d" in names and "dash" not in names and "torch" not in names


def test_decompose_on_a_mesh_at_default_settings_imports_no_torch_or_scikit_learn(tmp_path):
    """The default path of a mesh (per-shape optimised features, the numpy field, and the
    numpy two-way k-means of the split) writes its hulls without torch or scikit-learn, which
    cost a one-shot process about 2 s to import."""
    out = tmp_path / "mug.obj"
    names = imported("decompose", str(MUG), "-o", str(out), "-q", "-n", "3000")
    assert {"pointcvx.features.field", "pointcvx.decomposition.kmeans", "open3d"} <= names
    assert not {"torch", "sklearn"} & names, sorted({"torch", "sklearn"} & names)
    assert out.read_text().count("\no ") >= 1


def test_decompose_on_a_splat_with_the_models_features_imports_no_torch(tmp_path):
    """A splat's default features are the bundled model's, run in numpy
    (:mod:`pointcvx.model.numpy_net`): torch's import was about 1.5 s of a one-shot run."""
    out = tmp_path / "splat.obj"
    names = imported("decompose", str(ROOT / "io" / "mug_splat.ply"), "-o", str(out), "-q", "-n", "3000")
    assert "pointcvx.model.numpy_net" in names
    assert "torch" not in names, sorted(n for n in names if n.startswith("torch"))
    assert out.read_text().count("\no ") >= 1


def test_one_shot_commands_exit_without_the_interpreters_teardown(tmp_path):
    """`pointcvx decompose` and `info` end the process as soon as they return (about 0.1 s of
    module finalisers saved on a one-shot run): an exit handler never runs, yet everything they
    printed through a pipe and every file they wrote is there, with their exit status. Other
    commands exit as usual."""
    out = tmp_path / "mug.obj"

    def console(*args: str) -> subprocess.CompletedProcess:
        code = ("import atexit, sys\n"
                "atexit.register(lambda: print('TEARDOWN', flush=True))\n"
                f"sys.argv = ['pointcvx', *{list(args)!r}]\n"
                "from pointcvx.cli import console\nconsole()\n")
        return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              timeout=300, cwd=ROOT)

    res = console("decompose", str(MUG), "-o", str(out), "-n", "3000", "--features", "fast")
    assert res.returncode == 0, res.stderr[-2000:]
    assert "TEARDOWN" not in res.stdout
    last = res.stdout.strip().splitlines()[-1]
    n_hulls = int(last.split()[0])
    assert last.endswith(str(out)) and out.read_text().count("\no ") == n_hulls >= 1
    res = console("info", str(MUG), "--json")
    assert res.returncode == 0 and "TEARDOWN" not in res.stdout and res.stdout.rstrip().endswith("}")
    res = console("info", str(tmp_path / "missing.obj"))
    assert res.returncode == 1 and "TEARDOWN" not in res.stdout
    assert res.stderr.count("\n") == 1 and "error" in res.stderr
    res = console()  # no command: usage, exit status 2, the usual exit
    assert res.returncode == 2 and "TEARDOWN" in res.stdout


def test_a_profiled_one_shot_command_still_exits_through_the_profiler(tmp_path):
    """Under ``python -m cProfile`` (or a tracer, or coverage) decompose and info exit the usual
    way, so the tool writes its results at exit."""
    stats = tmp_path / "info.prof"
    res = subprocess.run([sys.executable, "-m", "cProfile", "-o", str(stats), "-m", "pointcvx", "info",
                          str(MUG)], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert res.returncode == 0, res.stderr[-2000:]
    assert stats.stat().st_size > 1000
