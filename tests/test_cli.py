"""The command line: reports, outputs, and one-line errors with non-zero exits on bad input."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from bad_inputs import CASES, bad_inputs

from conftest import DATA, ROOT
from pointcvx.cli import EXIT_INPUT, EXIT_USAGE, main

MUG = DATA / "dev/objects/mug.obj"


def run_cli(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    """Run the real console entry point in a subprocess."""
    cmd = [sys.executable, "-m", "pointcvx", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env, cwd=ROOT)


def test_info_reports_detection(capsys):
    assert main(["info", str(MUG), "--json", "-n", "2000"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["modality"] == "mesh" and report["format"] == "obj"
    assert report["points"] == 2000 and report["faces"] == 864
    assert "ray parity" in report["normals"]
    np.testing.assert_allclose(report["bbox_min"], [-0.041, -0.041, 0.0], atol=1e-3)


def test_info_writes_cloud_in_input_units(tmp_path, capsys):
    from plyfile import PlyData

    out = tmp_path / "mug_cloud.ply"
    assert main(["info", str(MUG), "-o", str(out), "-n", "1500", "-q"]) == 0
    assert capsys.readouterr().out == ""
    v = PlyData.read(str(out))["vertex"]
    pts = np.c_[v["x"], v["y"], v["z"]]
    assert len(pts) == 1500 and pts[:, 2].min() >= -1e-6 and pts[:, 2].max() <= 0.1 + 1e-6
    # Existing output is not replaced without --overwrite; the file stays intact.
    before = out.read_bytes()
    assert main(["info", str(MUG), "-o", str(out)]) == EXIT_INPUT
    assert "exists" in capsys.readouterr().err and out.read_bytes() == before
    assert main(["info", str(MUG), "-o", str(out), "--overwrite", "--normalized", "-q"]) == 0
    v = PlyData.read(str(out))["vertex"]
    assert np.isclose(max(np.ptp(v[c]) for c in "xyz"), 2.0, atol=1e-4)


def test_quiet_json_prints_the_report_and_no_bar(tmp_path):
    """``-q --json``: no progress bar and no human summary, but the JSON report that --json
    asks for (a script's way to read hulls and timings); ``-q`` alone prints nothing."""
    out = tmp_path / "mug.obj"
    run = run_cli("decompose", str(MUG), "-o", str(out), "-n", "3000", "-q", "--json")
    assert run.returncode == 0, run.stderr
    report = json.loads(run.stdout)
    assert report["hulls"] >= 1 and report["output"] == str(out) and "total" in report["timings"]
    assert run.stderr == ""
    quiet = run_cli("decompose", str(MUG), "-o", str(out), "-n", "3000", "-q", "--overwrite")
    assert quiet.returncode == 0 and quiet.stdout == quiet.stderr == ""
    info = run_cli("info", str(MUG), "-q", "--json", "-n", "2000")
    assert info.returncode == 0 and json.loads(info.stdout)["points"] == 2000


def test_refuses_to_overwrite_its_input(tmp_path, capsys):
    src = tmp_path / "in.ply"
    src.write_bytes((ROOT / "io" / "mug_scan.ply").read_bytes())
    before = src.read_bytes()
    assert main(["info", str(src), "-o", str(src), "--overwrite"]) == EXIT_INPUT
    assert "input" in capsys.readouterr().err and src.read_bytes() == before


@pytest.mark.parametrize("case", CASES)
def test_bad_input_gives_one_line_error(tmp_path, capsys, case):
    path, fragment = bad_inputs(str(tmp_path))[case]
    assert main(["info", path]) == EXIT_INPUT
    err = capsys.readouterr().err.strip()
    assert err.startswith("pointcvx: error:") and "\n" not in err
    assert fragment.lower() in err.lower()


@pytest.mark.parametrize("case", CASES)
def test_bad_input_api_raises_typed_error(tmp_path, case):
    import pointcvx

    path, fragment = bad_inputs(str(tmp_path))[case]
    with pytest.raises(pointcvx.PointcvxError) as info:
        pointcvx.load(path)
    assert isinstance(info.value, pointcvx.InputError)
    assert fragment.lower() in str(info.value).lower()


def test_bad_inputs_in_a_real_process_never_trace_back(tmp_path):
    cases = bad_inputs(str(tmp_path))
    for name in ("truncated ply", "unknown", "nan", "collinear", "fifo", "huge count", "huge coordinates"):
        res = run_cli("info", cases[name][0])
        assert res.returncode == EXIT_INPUT, (name, res.stderr)
        assert "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1


def test_step_without_cad_extra(tmp_path):
    """With gmsh unavailable, a STEP file names the extra to install and exits 1."""
    code = (
        "import sys; sys.modules['gmsh'] = None\n"
        "from pointcvx.cli import main\n"
        f"sys.exit(main(['info', {str(ROOT / 'io' / 'bracket.step')!r}]))\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == EXIT_INPUT
    assert "pip install 'pointcvx[cad]'" in res.stderr and "Traceback" not in res.stderr


def test_usage_errors_and_help():
    res = run_cli("info")
    assert res.returncode == EXIT_USAGE and "Traceback" not in res.stderr
    res = run_cli("info", str(MUG), "--points", "many")
    assert res.returncode == EXIT_USAGE
    res = run_cli("info", str(MUG), "--min-opacity", "2")
    assert res.returncode == EXIT_USAGE and "min_opacity must be in [0, 1), got 2.0" in res.stderr
    res = run_cli("info", "--help")
    assert res.returncode == 0
    for flag in ("--output", "--points", "--seed", "--min-opacity", "--floater-ratio",
                 "--samples-per-gaussian", "--voxel-size", "--outlier-std", "--cad-mesh-size",
                 "--overwrite", "--json", "--quiet"):
        assert flag in res.stdout
    assert run_cli("--version").stdout.startswith("pointcvx ")


def test_console_script_runs_on_every_bundled_sample():
    exe = os.path.join(os.path.dirname(sys.executable), "pointcvx")
    for sample in sorted((ROOT / "io").iterdir()):
        if sample.suffix == ".md":
            continue
        res = subprocess.run([exe, "info", str(sample), "--json"], capture_output=True, text=True,
                             timeout=300)
        assert res.returncode == 0, (sample, res.stderr)
        report = json.loads(res.stdout)
        assert report["points"] > 1000
