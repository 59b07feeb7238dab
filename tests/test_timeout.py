"""``decompose(timeout=...)`` and ``pointcvx decompose --timeout``: a clear error, on time, and
no output; library warnings kept off the terminal."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

import pointcvx
from conftest import DATA
from pointcvx.deadline import Deadline
from pointcvx.errors import TimeLimitError


def test_deadline_checks_and_names_the_stage():
    none = Deadline(None)
    none.check("anything")
    assert none.left() == float("inf") and none.watch(None) is None
    past = Deadline(1e-9)
    time.sleep(0.01)
    seen = []
    report = past.watch(lambda *a: seen.append(a))
    with pytest.raises(TimeLimitError, match=r"1e-09 s \(while split\); nothing was written"):
        report("split", 1, 4)
    assert seen == []  # the callback is not reached once the time is up


class _SplitReached(Exception):
    """Ends a measuring run at its first split report."""


def test_api_timeout_stops_the_feature_optimisation():
    """A limit that falls inside the feature optimisation ends the decomposition at its next
    check, saying so. The feature stage's window is measured first, in this process, warm (its
    start and length follow the machine: about 0.3 to 2 s into a warm run of chair.off quiet,
    several times that busy; the measuring run stops at the split), and the limit aimed at its
    first third (a slower machine moves the window later, not earlier); the longest stretch
    without a check is the sampling of the convex pairs at the stage's start (about 0.3 s
    quiet, 1 s busy)."""
    path = DATA / "vhacd61" / "chair.off"
    seen = {}

    def note(stage, done, total):
        if stage == "split":
            raise _SplitReached
        seen.setdefault(stage, time.monotonic() - t0)  # first report of each stage
        seen[stage + " last"] = time.monotonic() - t0

    pointcvx.decompose(path, features="optimize", n_points=2000)  # first-call costs paid first
    t0 = time.monotonic()
    with pytest.raises(_SplitReached):
        pointcvx.decompose(path, features="optimize", progress=note)
    assert 0 < seen["features"] < seen["features last"], seen
    limit = round(seen["features"] + (seen["features last"] - seen["features"]) / 3, 2)
    t = time.monotonic()
    with pytest.raises(TimeLimitError, match=rf"{limit:g} s \(while features\)"):
        pointcvx.decompose(path, features="optimize", timeout=limit)
    took = time.monotonic() - t
    assert limit <= took < limit + 5.0, (took, seen)


def test_cli_watchdog_ends_a_run_without_steps(tmp_path):
    """Loading reports no steps; the command's watchdog ends it shortly after the limit. A
    40-times subdivided soup of overlapping triangles keeps the mesh loader busy for seconds."""
    import numpy as np
    import trimesh

    rng = np.random.default_rng(0)
    tri = rng.random((60000, 3, 3))
    soup = trimesh.Trimesh(tri.reshape(-1, 3), np.arange(len(tri) * 3).reshape(-1, 3), process=False)
    stl = tmp_path / "soup.stl"
    soup.export(stl)
    out = tmp_path / "soup.obj"
    t = time.monotonic()
    run = subprocess.run([sys.executable, "-m", "pointcvx", "decompose", str(stl), "-o", str(out),
                          "-q", "--timeout", "0.5"], capture_output=True, text=True, timeout=120)
    took = time.monotonic() - t
    assert run.returncode == 1, run.stderr
    assert run.stderr.strip().splitlines() == [
        "pointcvx: error: stopped after the time limit of 0.5 s; nothing was written"], run.stderr
    assert not out.exists()
    assert took < 15, took  # start-up plus the 0.5 s limit and its 1 s grace


def test_api_timeout_checked():
    with pytest.raises(pointcvx.InputError, match="timeout"):
        pointcvx.decompose(DATA / "vhacd61" / "cup.off", timeout=0)


def test_generous_timeout_changes_nothing():
    kw = dict(features="model", n_points=3000, max_hulls=4)
    a = pointcvx.decompose(DATA / "vhacd61" / "cup.off", **kw)
    b = pointcvx.decompose(DATA / "vhacd61" / "cup.off", timeout=600, **kw)
    assert len(a.hulls) == len(b.hulls)
    for x, y in zip(a.hulls, b.hulls, strict=True):
        assert (x.vertices == y.vertices).all()


def test_cli_timeout_one_line_no_output(tmp_path):
    out = tmp_path / "chair.obj"
    run = subprocess.run([sys.executable, "-m", "pointcvx", "decompose", str(DATA / "vhacd61" / "chair.off"),
                          "-o", str(out), "--features", "optimize", "--timeout", "2"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 1, run.stderr
    lines = [line for line in run.stderr.splitlines() if line.strip() and "\r" not in line]
    assert lines[-1].startswith("pointcvx: error: stopped after the time limit of 2 s"), run.stderr
    assert "Traceback" not in run.stderr
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_cli_rejects_bad_timeout():
    run = subprocess.run([sys.executable, "-m", "pointcvx", "decompose", "x.obj", "--timeout", "-1"],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "timeout" in run.stderr


def test_cli_keeps_library_warnings_off_stderr(tmp_path):
    """A library warning raised inside a command is not printed (only with -v, as a log line)."""
    code = ("import warnings, sys; from pointcvx import cli; from pointcvx.cli import info; "
            "real = info.run\n"
            "def run(args):\n"
            "    warnings.warn('overflow encountered', RuntimeWarning)\n"
            "    return real(args)\n"
            "info.run = run\n"
            "sys.exit(cli.main(sys.argv[1:]))")
    cup = str(DATA / "vhacd61" / "cup.off")
    quiet = subprocess.run([sys.executable, "-c", code, "info", cup], capture_output=True, text=True,
                           timeout=120)
    assert quiet.returncode == 0 and "overflow" not in quiet.stderr, quiet.stderr
    loud = subprocess.run([sys.executable, "-c", code, "info", cup, "-v"], capture_output=True,
                          text=True, timeout=120)
    assert loud.returncode == 0 and "RuntimeWarning: overflow encountered" in loud.stderr


def test_a_scenes_objects_at_once_stop_within_a_step_of_the_limit():
    """With two worker threads a scene's objects run at once and report only whole objects to
    the user; each of their steps still checks the limit, so the Kinect frame (three objects,
    about 5 s warm) stops within a step of a 3 s limit, naming the object's stage (checked
    only between objects, it ran on to the first object's end, over 4 s)."""
    from pointcvx import workers

    workers.set_threads(2)
    try:
        t = time.monotonic()
        with pytest.raises(TimeLimitError, match=r"3 s \(while object [123]/3 "):
            pointcvx.decompose(DATA / "raw_scans" / "kinect_frame.pcd", timeout=3.0, seed=0)
        took = time.monotonic() - t
    finally:
        workers.set_threads(None)
    assert 3.0 <= took < 4.2, took
