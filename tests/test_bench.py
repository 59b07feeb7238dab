"""``pointcvx bench``: real runs of pointcvx, CoACD and both V-HACDs on a tiny L-shaped block.

One small benchmark (module fixture) is shared by most tests; every method runs for real in its
own worker process, with small settings (3000 points, 2000 metric samples, low V-HACD
resolution) so that the whole file takes well under a minute.
"""

from __future__ import annotations

import argparse
import csv
import math

import numpy as np
import pytest
import trimesh
from shapes import l_block

from pointcvx.apps import bench
from pointcvx.cli import build_parser, main
from pointcvx.cli.bench import bench_options
from pointcvx.cli.bench import run as cmd_bench
from pointcvx.cloud import Normalization
from pointcvx.evaluate import evaluate, load_hulls

FAST = ["-n", "3000", "--eval-samples", "2000", "--vhacd-resolution", "20000", "--search-runs", "4",
        "-q"]
METHODS = "pointcvx,coacd,vhacd,vhacdx"


def _args(argv: list[str]) -> argparse.Namespace:
    return build_parser().parse_args(["bench", *argv])


def _bench(argv: list[str]) -> int:
    """``pointcvx bench ARGV``: its exit status."""
    return main(["bench", *argv])


def _rows(out) -> list[dict]:
    with open(out / "results.csv", newline="") as f:
        return list(csv.DictReader(f))


def _one(rows: list[dict], method: str, setting: str) -> dict:
    found = [r for r in rows if r["method"] == method and r["setting"] == setting]
    assert len(found) == 1, (method, setting, found)
    return found[0]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A benchmark of every method on one L block (plus a README that must be ignored)."""
    ds = tmp_path_factory.mktemp("blocks")
    l_block().export(ds / "l_block.obj")
    (ds / "README.md").write_text("not a shape\n")
    out = tmp_path_factory.mktemp("bench") / "out"
    argv = [str(ds), "-o", str(out), "--methods", METHODS, *FAST]
    assert _bench(argv) == 0
    return {"ds": ds, "out": out, "argv": argv, "rows": _rows(out)}


def test_every_method_gives_a_row_with_finite_metrics(run):
    rows = run["rows"]
    got = sorted((r["method"], r["setting"]) for r in rows)
    assert got == sorted([("pointcvx", "fixed"), ("coacd", "fixed"), ("coacd", "matched"),
                          ("vhacd", "fixed"), ("vhacd", "matched"), ("vhacdx", "fixed"),
                          ("vhacdx", "matched")])
    for r in rows:
        assert r["error"] == "", r
        assert (r["dataset"], r["category"], r["shape"], r["modality"]) == (
            run["ds"].name, run["ds"].name, "l_block", "mesh")
        assert int(r["hulls"]) >= 1
        for key in ("concavity", "reconstruction", "iou", "coverage", "seconds", "peak_mb"):
            assert math.isfinite(float(r[key])), (r["method"], key)
        assert 0.0 <= float(r["iou"]) <= 1.0 and 0.0 <= float(r["coverage"]) <= 1.0
        assert 0.0 < float(r["seconds"]) < 120.0
        # the worker's own peak (interpreter + library + run), not the parent's inherited one
        assert 10.0 < float(r["peak_mb"]) < 8000.0
    # the paper's fixed settings, recorded in the rows
    assert float(_one(rows, "coacd", "fixed")["param"]) == pytest.approx(0.1)
    assert _one(rows, "vhacd", "fixed")["param_name"] == "concavity"
    assert float(_one(rows, "pointcvx", "fixed")["threshold"]) == pytest.approx(0.1)
    # pointcvx's torch stack costs far more memory than CoACD's bare library in its own process;
    # a worker's peak is its own (about 40 MB here), not the larger one of the test process
    coacd_mb = float(_one(rows, "coacd", "fixed")["peak_mb"])
    assert coacd_mb < 150.0
    assert float(_one(rows, "pointcvx", "fixed")["peak_mb"]) > coacd_mb


def test_one_shot_times_are_real_and_beside_the_warm_ones(run):
    rows = run["rows"]
    for r in rows:
        if r["setting"] == "fixed":
            # a one-shot run of every method, with the warm run's hull count (else oneshot_error)
            assert r["oneshot_error"] == "", r
            assert 0.0 < float(r["oneshot_seconds"]) < 300.0, r
        else:  # the matched searches are timed warm only
            assert (r["oneshot_seconds"], r["oneshot_error"]) == ("", ""), r
    ours = _one(rows, "pointcvx", "fixed")
    # the whole process also pays the interpreter, the imports (torch, open3d, scikit-learn...),
    # and reading and writing the files: seconds more than the warm call on this small block
    assert float(ours["oneshot_seconds"]) > float(ours["seconds"]) + 0.5
    text = (run["out"] / "summary.md").read_text()
    head = "Time: one-shot (whole process) and warm (the method's call)"
    assert head in text
    table = text.split(head)[1].splitlines()
    line = next(ln for ln in table if ln.startswith("| pointcvx | fixed | 0.1 | 1 | "))
    once, warm = (float(x) for x in line.split("|")[5:7])
    assert once == pytest.approx(float(ours["oneshot_seconds"]), rel=1e-3)
    assert warm == pytest.approx(float(ours["seconds"]), rel=1e-3)
    assert line.endswith("| 1 | 1 |")  # pointcvx over itself
    coacd = _one(rows, "coacd", "fixed")
    ratio = float(next(ln for ln in table if ln.startswith("| coacd | fixed | – | 1 | ")).split("|")[7])
    assert ratio == pytest.approx(float(coacd["oneshot_seconds"]) / float(ours["oneshot_seconds"]),
                                  rel=5e-3)  # printed to 3 digits
    lines = bench.final_summary(bench.BenchReport(rows, 0, run["out"])).splitlines()
    assert any(ln.lstrip().startswith("pointcvx fixed 0.1") and "one-shot s " in ln for ln in lines)


def test_results_without_the_one_shot_columns_still_read_and_summarise(run, tmp_path):
    # a results.csv written before the one-shot columns existed
    old = [c for c in bench.COLUMNS if not c.startswith("oneshot_")]
    path = tmp_path / "results.csv"
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, old, extrasaction="ignore", lineterminator="\n")
        w.writeheader()
        w.writerows(run["rows"])
    rows = bench.read_results(path)
    assert len(rows) == len(run["rows"]) and all(r["oneshot_seconds"] == "" for r in rows)
    text = bench.summarize(rows)
    assert "median seconds of the baseline / median seconds of pointcvx" in text
    assert "one-shot" not in text


def test_one_shot_runs_pointcvx_at_the_bench_settings(tmp_path):
    from pointcvx.apps.bench.oneshot import decompose_flags
    from pointcvx.errors import InputError
    from pointcvx.flags import options_from_args
    from pointcvx.options import DecomposeOptions, LoadOptions

    opts = bench.BenchOptions.create(features="model", n_points=3000, seed=7, merge=False,
                                     blend=0.25, max_hulls=9, outlier_std=1.75)
    params = {**opts.decompose.as_dict(), **opts.load.as_dict(), "threshold": 0.05}
    flags = decompose_flags(params)
    assert "--no-merge" in flags and flags[flags.index("--threshold") + 1] == "0.05"
    args = build_parser().parse_args(["decompose", "in.obj", "-o", "out.obj", *flags])
    assert options_from_args(args, DecomposeOptions).as_dict() == {**opts.decompose.as_dict(),
                                                                   "threshold": 0.05}
    assert options_from_args(args, LoadOptions) == opts.load
    assert decompose_flags(bench.BenchOptions().decompose.as_dict()) == []  # defaults: no flag
    # an API-only setting cannot be run as the command: refused before any run, unless one-shot
    # runs are off
    api_only = bench.BenchOptions.create(mesh_points=5000)
    with pytest.raises(InputError, match="mesh_points"):
        api_only.check()
    bench.BenchOptions.create(mesh_points=5000, oneshot=False).check()


def test_hull_files_exist_load_and_reproduce_the_metrics(run):
    out = run["out"]
    rows = run["rows"]
    for r in rows:
        path = out / r["hull_file"]
        assert path == out / "hulls" / r["method"] / r["setting"] / "l_block.obj"
        hulls = load_hulls(path)
        assert len(hulls) == int(r["hulls"])
        # every method decomposed the same mesh normalised to [-1, 1]^3
        v = np.concatenate(hulls)
        assert np.abs(v).max() < 1.2, r["method"]
    # the row's metrics are evaluate() of that file against the normalised block
    mesh = l_block()
    norm = Normalization.to_unit_cube(mesh.vertices)
    unit = trimesh.Trimesh(norm.forward(mesh.vertices), mesh.faces, process=False)
    r = _one(rows, "pointcvx", "fixed")
    ev = evaluate(unit, load_hulls(out / r["hull_file"]), n_samples=2000, n_volume_samples=10000, seed=0)
    assert ev["hulls"] == int(r["hulls"])
    assert ev["concavity"] == pytest.approx(float(r["concavity"]), rel=1e-4, abs=1e-6)
    assert ev["reconstruction"] == pytest.approx(float(r["reconstruction"]), rel=1e-4)


def test_matched_granularity_is_at_least_as_close_as_fixed(run):
    rows = run["rows"]
    h = int(_one(rows, "pointcvx", "fixed")["hulls"])
    fixed, matched = _one(rows, "coacd", "fixed"), _one(rows, "coacd", "matched")
    assert abs(int(matched["hulls"]) - h) <= abs(int(fixed["hulls"]) - h)
    assert int(matched["target_hulls"]) == h
    assert 1 <= int(matched["search_runs"]) <= 4
    assert 0.01 <= float(matched["param"]) <= 1.0
    vfixed, vmatched = _one(rows, "vhacd", "fixed"), _one(rows, "vhacd", "matched")
    assert abs(int(vmatched["hulls"]) - h) <= abs(int(vfixed["hulls"]) - h)
    assert 1e-5 <= float(vmatched["param"]) <= 0.1
    # vhacdx takes the hull count directly: one run, at most H hulls
    x = _one(rows, "vhacdx", "matched")
    assert (int(float(x["param"])), int(x["search_runs"])) == (h, 1)
    assert 1 <= int(x["hulls"]) <= h
    assert int(_one(rows, "vhacdx", "fixed")["param"]) == 64


def test_summary_has_stats_and_the_win_loss_table(run):
    text = (run["out"] / "summary.md").read_text()
    assert f"## Dataset `{run['ds'].name}` (1 shapes)" in text
    assert "pointcvx against each baseline at matched granularity" in text
    assert "median seconds of the baseline / median seconds of pointcvx" in text
    for b in ("coacd", "vhacd", "vhacdx"):
        c = bench.win_tie_loss(run["rows"], b, "concavity")
        rec = bench.win_tie_loss(run["rows"], b, "reconstruction")
        assert sum(c) == 1 and sum(rec) == 1  # one shape, one pair
        line = f"| {b} | 0.1 | 1 | {c[0]} / {c[1]} / {c[2]} | {rec[0]} / {rec[1]} / {rec[2]} |"
        assert line in text
    # hand-check one pairing against the rows (lower is better)
    ours = float(_one(run["rows"], "pointcvx", "fixed")["concavity"])
    theirs = float(_one(run["rows"], "coacd", "matched")["concavity"])
    if abs(ours - theirs) <= bench.TIE_RTOL * max(ours, theirs):
        expect = (0, 1, 0)
    else:
        expect = (1, 0, 0) if ours < theirs else (0, 0, 1)
    assert bench.win_tie_loss(run["rows"], "coacd", "concavity") == expect
    png = run["out"] / "granularity.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(run["out"].glob(".bench-*"))  # temporary folders are gone


def test_timeout_is_an_error_row_and_non_meshes_skip_the_baselines(tmp_path):
    ds = tmp_path / "mixed"
    ds.mkdir()
    l_block().export(ds / "l_block.obj")
    rng = np.random.default_rng(0)
    p = rng.normal(size=(400, 3))
    np.savetxt(ds / "ball.xyz", p / np.linalg.norm(p, axis=1, keepdims=True))
    out = tmp_path / "out"
    # V-HACD at 8 million voxels takes seconds: killed after 1 s; two shapes at once
    argv = [str(ds), "-o", str(out), "--methods", "vhacd", "--no-match", "--timeout", "1",
            "--vhacd-resolution", "8000000", "--jobs", "2", "-q"]
    assert _bench(argv) == 0
    rows = {r["shape"]: r for r in _rows(out)}
    assert set(rows) == {"l_block", "ball"}
    slow = rows["l_block"]
    assert slow["error"] == "timeout after 1 s"
    assert 1.0 <= float(slow["seconds"]) < 30.0
    assert slow["hulls"] == "" and slow["hull_file"] == ""
    assert rows["ball"]["error"] == "skipped: needs a mesh"
    assert rows["ball"]["modality"] == "scan"
    text = (out / "summary.md").read_text()
    assert "| vhacd | fixed | – | 0 | 1 | 1 |" in text


def test_missing_or_bad_input_is_a_one_line_error(tmp_path, monkeypatch, capsys):
    def error(argv: list[str]) -> str:
        """Run ``pointcvx bench ARGV``, which must fail with status 1; its one-line error."""
        assert _bench(argv) == 1
        captured = capsys.readouterr()
        assert captured.out == ""
        lines = captured.err.splitlines()
        assert len(lines) == 1 and lines[0].startswith("pointcvx: error: "), captured.err
        return lines[0]

    assert "no such file or folder" in error([str(tmp_path / "nowhere"), "-o", str(tmp_path / "out"), "-q"])
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "README.md").write_text("x")
    assert "no shape file" in error([str(empty), "-o", str(tmp_path / "out"), "-q"])
    assert "unknown method 'vhacd3'" in error([str(empty), "-o", str(tmp_path / "out"),
                                               "--methods", "pointcvx,vhacd3", "-q"])
    monkeypatch.setitem(bench.PACKAGES, "coacd", "coacd_is_not_installed")
    assert "pip install 'pointcvx[baselines]'" in error([str(empty), "-o", str(tmp_path / "out"),
                                                         "--methods", "coacd", "-q"])
    assert not (tmp_path / "out").exists()
    # bad usage (a missing -o) is argparse's exit status 2
    with pytest.raises(SystemExit) as exc:
        _bench([str(empty), "-q"])
    assert exc.value.code == 2


def test_parser_defaults_and_options():
    args = _args(["a", "b", "-o", "out"])
    assert args.func is cmd_bench
    opts = bench_options(args)
    assert (args.datasets, args.output, args.jobs, args.limit) == (["a", "b"], "out", 1, None)
    assert (opts.methods, opts.thresholds, opts.match, opts.timeout, opts.decompose.features) == (
        ("pointcvx", "coacd", "vhacd"), (0.1,), True, 600.0, "auto")
    assert opts == bench.BenchOptions()  # the flags' defaults are the API's
    assert opts.oneshot and not bench_options(_args(["a", "-o", "o", "--no-oneshot"])).oneshot
    opts = bench_options(_args(["a", "--output", "o", "--methods", "PointCVX, vhacdx",
                                "--thresholds", "0.05,0.2", "--no-match", "--timeout", "5",
                                "--features", "model"]))
    assert (opts.methods, opts.thresholds, opts.match, opts.timeout, opts.decompose.features) == (
        ("pointcvx", "vhacdx"), (0.05, 0.2), False, 5.0, "model")
    # pointcvx's settings by name, as the API takes them
    opts = bench.BenchOptions.create(methods=("pointcvx",), features="model", n_points=3000, seed=4)
    assert (opts.decompose.features, opts.load.n_points, opts.seed) == ("model", 3000, 4)
    assert bench.BenchOptions.from_dict(opts.to_dict()) == opts


def test_search_bisects_to_the_closest_count():
    calls = []

    def fake_run(x: float):  # a synthetic count, falling as the parameter grows
        calls.append(x)
        return bench.Run("coacd", x, True, hulls=int(round(0.5 / x)))

    reused = bench.Run("coacd", 0.1, True, hulls=5)
    best, tried = bench.search_parameter(fake_run, 0.01, 1.0, 10, 6, reuse=[reused])
    assert best.hulls == 10 and tried[-1] is best
    assert tried[0] is reused and 0.1 not in calls  # the midpoint's run was reused, not rerun
    assert len(tried) <= 6
    # a target out of reach: the closest count at the edge, never more than max_runs probes
    best, tried = bench.search_parameter(fake_run, 0.01, 1.0, 500, 3)
    assert len(tried) == 3 and best.hulls == max(r.hulls for r in tried)
    # a failing probe moves the search to coarser settings
    def failing(x: float):
        if x < 0.05:
            return bench.Run("coacd", x, False, error="timeout after 1 s")
        return fake_run(x)

    best, tried = bench.search_parameter(failing, 0.01, 1.0, 10, 4)
    assert best is not None and best.param >= 0.05 and not tried[1].ok


def test_rerun_resumes_and_redoes_only_missing_rows(run):
    out = run["out"]
    before = (out / "results.csv").read_text()
    stamp = {p: p.stat().st_mtime_ns for p in (out / "hulls").rglob("*.obj")}
    report = bench.run_bench([run["ds"]], out, bench_options(_args(run["argv"])))
    assert report.new_rows == 0
    assert (out / "results.csv").read_text() == before
    assert {p: p.stat().st_mtime_ns for p in (out / "hulls").rglob("*.obj")} == stamp
    # drop one row: only that one runs again
    rows = [r for r in run["rows"] if (r["method"], r["setting"]) != ("vhacdx", "fixed")]
    bench.write_results(out / "results.csv", rows)
    report = bench.run_bench([run["ds"]], out, bench_options(_args(run["argv"])))
    assert report.new_rows == 1
    again = _rows(out)
    assert len(again) == len(run["rows"])
    assert _one(again, "vhacdx", "fixed")["error"] == ""
    changed = [p for p, t in stamp.items() if p.stat().st_mtime_ns != t]
    assert changed == [out / "hulls" / "vhacdx" / "fixed" / "l_block.obj"]


_ORPHAN = r"""
import multiprocessing, os, sys, time
from pathlib import Path

def child(flag):
    from pointcvx.apps.common import Orphaned, stop_if_orphaned
    stop_if_orphaned()  # parent alive: nothing happens
    Path(flag).write_text("started")
    for _ in range(200):
        time.sleep(0.05)
        try:
            stop_if_orphaned()
        except Orphaned:
            Path(flag).write_text("stopped")
            return
    Path(flag).write_text("ran on")

if __name__ == "__main__":
    ctx = multiprocessing.get_context("spawn")
    p = ctx.Process(target=child, args=(sys.argv[1],))
    p.start()
    while not Path(sys.argv[1]).exists():
        time.sleep(0.05)
    os._exit(0)  # the benchmark dies without shutting its workers down
"""


def test_pool_worker_of_a_dead_benchmark_stops(tmp_path):
    import subprocess
    import sys
    import time

    script = tmp_path / "orphan.py"
    script.write_text(_ORPHAN)
    flag = tmp_path / "flag.txt"
    subprocess.run([sys.executable, str(script), str(flag)], check=True, timeout=60)
    deadline = time.time() + 30
    while flag.read_text() == "started" and time.time() < deadline:
        time.sleep(0.1)
    assert flag.read_text() == "stopped"


def test_worker_warms_imports_and_model_before_the_timed_call():
    """The timed pointcvx call must not pay library imports or the one-time weight load. The
    model's features run in numpy (pointcvx.model.numpy_net), so warming for them loads no
    torch."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from pointcvx.apps.bench import worker as w\n"
        "from pointcvx.model import weights\n"
        "w.warm_pointcvx({'features': sys.argv[1], 'model': None})\n"
        "missing = [m for m in ('open3d', 'sklearn.cluster', 'skimage.measure', 'trimesh',\n"
        "                       'pointcvx.model.numpy_net') if m not in sys.modules]\n"
        "print(missing, weights._cached.cache_info().currsize, 'torch' in sys.modules)\n"
    )
    for features in ("model", "auto"):  # "auto" uses the model on splats: load it once, before
        out = subprocess.run([sys.executable, "-c", code, features], capture_output=True, text=True,
                             timeout=300)
        assert out.returncode == 0, out.stderr
        assert out.stdout.split("\n")[0] == "[] 1 False", features
