"""System libraries: open3d without a system libusb, one-line errors for missing libraries, and
outputs with the user's umask."""

from __future__ import annotations

import ctypes
import os
import stat
import subprocess
import sys

import pytest

from conftest import ROOT
from pointcvx.errors import MissingLibraryError
from pointcvx.syslibs import LIBUSB, bundled_libusb, install_hint, missing_library

MUG = ROOT / "io" / "mug.obj"


def _system_has_libusb() -> bool:
    """Whether the dynamic loader finds a libusb-1.0 of the system's (checked in a fresh process,
    since this one may already hold the bundled copy under the same soname)."""
    code = f"import ctypes\ntry:\n    ctypes.CDLL({LIBUSB!r})\nexcept OSError:\n    raise SystemExit(1)"
    return subprocess.run([sys.executable, "-c", code]).returncode == 0


def _run(code: str, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                          timeout=300, **kwargs)


def test_open3d_imports_after_pointcvx_with_or_without_a_system_libusb():
    """The loaded libusb is the system's where it has one, else the copy of libusb-package."""
    res = _run("import pointcvx, open3d\n"
               "print(pointcvx.syslibs.preload_libusb())\n"
               "print([l.split()[-1] for l in open('/proc/self/maps') if 'libusb-1.0' in l][0])")
    assert res.returncode == 0, res.stderr
    source, mapped = res.stdout.split()
    if _system_has_libusb():
        assert source == "system" and "libusb_package" not in mapped
    else:
        assert bundled_libusb() is not None, "libusb-package is a dependency on Linux"
        assert source == mapped == str(bundled_libusb())


# libusb-package not importable (Python's own way to block an import), as after an install without
# it: open3d's native module then really fails to load.
_WITHOUT_LIBUSB_PACKAGE = """
import sys
sys.modules["libusb_package"] = None
"""


def test_cli_names_what_to_install_when_open3d_cannot_load(tmp_path):
    out = tmp_path / "h.obj"
    args = ["decompose", str(MUG), "-n", "2000", "-k", "2", "-q", "-o", str(out)]
    res = _run(_WITHOUT_LIBUSB_PACKAGE + f"from pointcvx.cli import main\nsys.exit(main({args!r}))")
    if _system_has_libusb():  # open3d links the system's copy; nothing is missing
        assert res.returncode == 0, res.stderr
        return
    assert res.returncode == 1, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr
    assert lines[0] == ("pointcvx: error: open3d needs the system library libusb-1.0.so.0, which this "
                        "machine lacks: pip install libusb-package (or apt-get install libusb-1.0-0)")
    assert not out.exists()


def test_api_raises_a_typed_error_when_open3d_cannot_load():
    res = _run(_WITHOUT_LIBUSB_PACKAGE + "import pointcvx\n"
               "try:\n    pointcvx.syslibs.import_open3d()\n"
               "except pointcvx.MissingLibraryError as exc:\n    print(exc.library); sys.exit(7)")
    assert res.returncode == (0 if _system_has_libusb() else 7), res.stderr
    if res.returncode == 7:
        assert res.stdout.strip() == LIBUSB


def test_missing_library_reads_the_dynamic_loaders_message():
    with pytest.raises(OSError) as info:
        ctypes.CDLL("libpointcvx-test-absent.so.3")
    assert missing_library(info.value) == "libpointcvx-test-absent.so.3"
    assert missing_library(OSError("permission denied")) is None
    # what gmsh's wheel reports on a machine without GLU, and what open3d's reports without libusb
    assert missing_library(OSError("libGLU.so.1: cannot open shared object file: No such file or "
                                   "directory")) == "libGLU.so.1"
    assert missing_library(ImportError(f"{LIBUSB}: cannot open shared object file: No such file "
                                       "or directory")) == LIBUSB


@pytest.mark.parametrize("library, hint", [
    ("libGLU.so.1", "apt-get install libglu1-mesa (Debian/Ubuntu)"),
    ("libXcursor.so.1", "apt-get install libxcursor1 (Debian/Ubuntu)"),
    ("libEGL.so.1", "apt-get install libegl1 (Debian/Ubuntu)"),
    ("libGL.so.1", "apt-get install libgl1 (Debian/Ubuntu)"),
    ("libusb-1.0.so.0", "pip install libusb-package (or apt-get install libusb-1.0-0)"),
    ("libunheard-of.so.2", "install it with the system's package manager"),
])
def test_install_hints(library, hint):
    assert install_hint(library) == hint
    err = MissingLibraryError("gmsh", library, install_hint(library))
    assert isinstance(err, ImportError) and "\n" not in str(err)


@pytest.mark.parametrize("mask", [0o022, 0o027, 0o077])
def test_outputs_follow_the_umask(tmp_path, mask):
    """Every file and folder pointcvx makes gets 0o666 (folders 0o777) less the umask: decomposed
    hulls, per-hull files, URDF and MJCF folders (their manifest too), `info -o` clouds, and a
    batch's folders, hull folders, manifest, lock and reports."""
    small = [str(MUG), "-n", "2000", "-k", "2", "-q", "--features", "model"]
    runs = [["decompose", *small, "-o", str(tmp_path / "h.obj")],
            ["decompose", *small, "-o", str(tmp_path / "per"), "--per-hull"],
            ["decompose", *small, "-o", str(tmp_path / "new" / "robot.urdf")],
            ["info", str(MUG), "-n", "500", "-q", "-o", str(tmp_path / "c.ply")]]
    expected = {"h.obj", "c.ply", "per/hull_000.obj", "per/.pointcvx.json", "new/robot_urdf/robot.urdf",
                "new/robot_urdf/robot_collision_0.obj", "new/robot_urdf/.pointcvx.json"}
    if mask == 0o027:  # a batch (a worker process: slow) once, where every mode bit differs
        runs.append(["batch", *small, "-o", str(tmp_path / "batch"), "--format", "mjcf", "--jobs", "1"])
        expected |= {"batch/batch_report.csv", "batch/batch_report.json", "batch/batch_manifest.jsonl",
                     "batch/.batch.lock", "batch/hulls/mug_mjcf/mug.xml",
                     "batch/hulls/mug_mjcf/mug_collision_0.obj"}
    code = (f"import os, sys\nos.umask({mask})\nfrom pointcvx.cli import main\n"
            f"sys.exit(max(main(args) for args in {runs!r}))")
    res = _run(code)
    assert res.returncode == 0, res.stderr
    made = sorted(tmp_path.rglob("*"))
    assert expected <= {p.relative_to(tmp_path).as_posix() for p in made}
    for f in made:
        want = (0o777 if f.is_dir() else 0o666) & ~mask
        assert stat.S_IMODE(os.stat(f).st_mode) == want, f
