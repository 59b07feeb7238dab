"""``pointcvx batch``: real batches of shapes from ``../shared/data/dev`` (read in place) on the
local process pool and on a Ray instance started on the loopback interface, with an injected
corrupt asset and a worker killed (SIGKILL, by its process id) while it runs an asset.

Every run uses the bundled model, 3000 points and at most 8 hulls, so that each asset is quick on
one core.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from shapes import l_block

from conftest import DATA
from pointcvx.apps import batch
from pointcvx.apps.batch import BatchOptions, Manifest, asset_seed, find_assets, run_batch
from pointcvx.cli import main
from pointcvx.errors import InputError, MissingExtraError, OutputError

FAST = BatchOptions.create(features="model", n_points=3000, max_hulls=8, timeout=300)
FAST_ARGS = ["--features", "model", "-n", "3000", "-k", "8", "--timeout", "300", "-q"]
DEV = DATA / "dev"
# A dozen real shapes of every category (each quick with FAST on one core).
DOZEN = ["objects/mug.obj", "objects/duck.obj", "objects/Kettle.obj", "objects/truck.obj",
         "characters/spot.obj", "characters/teddy.obj", "characters/cheburashka.obj",
         "scans/fertility.off", "scans/max_planck.obj", "cad/abc3.stl", "cad/fandisk.obj",
         "splats/donut.ply"]


def _manifest_file(tmp_path: Path, names: list[str], bad: bool = True) -> tuple[Path, Path]:
    """A text manifest of dev shapes (absolute paths) plus, last, a corrupt file in tmp_path."""
    for n in names:
        if not (DEV / n).is_file():
            pytest.fail(f"{DEV / n} not found: the shared data must sit beside the checkout")
    corrupt = tmp_path / "inputs" / "corrupt.obj"
    corrupt.parent.mkdir(exist_ok=True)
    corrupt.write_bytes(b"\x00\x01garbage, not a shape\xff" * 8)
    lines = ["# dev shapes, read in place", *[str(DEV / n) for n in names]]
    if bad:
        lines.append("corrupt.obj")  # relative to the manifest
    listing = tmp_path / "inputs" / "assets.txt"
    listing.write_text("\n".join(lines) + "\n")
    return listing, corrupt


def _records(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / batch.MANIFEST).read_text().splitlines() if line.strip()]


def _by_id(report) -> dict[str, dict]:
    return {r["id"]: r for r in report.rows}


def _killer(delay: float = 0.3):
    """A progress callback that, after the first asset done, kills (SIGKILL) the worker process
    that ran it ``delay`` seconds later, i.e. while that worker runs its next asset."""
    killed: dict = {}

    def progress(done: int, total: int, rec: dict) -> None:
        if killed or rec["status"] != "done":
            return
        pid = int(rec["worker"].rsplit(":", 1)[1])
        assert pid != os.getpid()
        killed["pid"] = pid
        threading.Timer(delay, os.kill, (pid, signal.SIGKILL)).start()

    return progress, killed


def _check_killed_run(report, killed: dict, corrupt_id: str) -> str:
    """Every asset done but the corrupt one and the one the killed worker was running."""
    failed = {r["id"]: r for r in report.rows if r["status"] == "failed"}
    assert corrupt_id in failed and "unknown format" in failed[corrupt_id]["error"]
    victims = [r for i, r in failed.items() if i != corrupt_id]
    assert len(victims) == 1, failed
    victim = victims[0]
    assert "worker died" in victim["error"], victim
    assert victim["worker"].endswith(f":{killed['pid']}")
    assert report.summary["done"] == len(report.rows) - 2 and report.summary["pending"] == 0
    for r in report.rows:
        if r["status"] == "done":
            obj = report.outdir / r["output"]
            assert obj.is_file() and obj.read_text().count("\no hull_") == int(r["hulls"]) >= 1
            assert r["seed"] == asset_seed(0, r["id"])
    return victim["id"]


# ------------------------------------------------------------------------------------ inputs
def test_asset_ids_from_folders_globs_and_manifests(tmp_path):
    root = tmp_path / "shapes"
    (root / "a").mkdir(parents=True)
    (root / "b").mkdir()
    (root / ".hidden").mkdir()
    for rel in ("a/mug.obj", "a/mug.ply", "b/mug.obj", "b/notes.md", ".hidden/x.obj", "b/odd name!.stl"):
        (root / rel).write_text("x")
    out = root / "out"  # an output folder inside an input folder is never read as input
    (out / "hulls").mkdir(parents=True)
    (out / "hulls" / "a.obj").write_text("x")
    assets = find_assets([root], exclude=out)
    assert [a.id for a in assets] == ["a/mug", "a/mug_ply", "b/mug", "b/odd_name_"]
    assert all(Path(a.path).is_absolute() for a in assets)

    assert [a.id for a in find_assets([str(root / "*" / "mug.obj")])] == ["a/mug", "b/mug"]
    # a file given twice (directly and through a folder) is one asset
    assert len(find_assets([root / "a" / "mug.obj", root / "a"])) == 2

    listing = tmp_path / "list.json"
    listing.write_text(json.dumps([{"path": "shapes/a/mug.obj", "id": "cups/blue"}, "shapes/b/mug.obj",
                                   "shapes/b/missing.obj", str(DEV / "objects" / "mug.obj")]))
    ids = [a.id for a in find_assets([listing])]
    # relative to the manifest; outside it: folder/name; a missing entry is kept (it fails later)
    assert ids == ["cups/blue", "shapes/b/mug", "shapes/b/missing", "objects/mug"]

    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "README.md").write_text("not a shape")
    with pytest.raises(InputError, match="no shape file in this folder"):
        find_assets([tmp_path / "docs"])
    with pytest.raises(InputError, match="no such file, folder or pattern"):
        find_assets([tmp_path / "nope"])
    with pytest.raises(InputError, match="matches this pattern"):
        find_assets([str(tmp_path / "*.stp")])
    bad = tmp_path / "bad.json"
    bad.write_text("[not json")
    with pytest.raises(InputError, match="not a JSON manifest"):
        find_assets([bad])
    empty = tmp_path / "empty.txt"
    empty.write_text("# nothing\n\n")
    with pytest.raises(InputError, match="lists no asset"):
        find_assets([empty])


def test_asset_seed_depends_only_on_batch_seed_and_id():
    assert asset_seed(0, "objects/mug") == asset_seed(0, "objects/mug")
    seeds = {asset_seed(0, "objects/mug"), asset_seed(1, "objects/mug"), asset_seed(0, "objects/cup")}
    assert len(seeds) == 3
    assert 0 <= asset_seed(7, "x") < 2**31


def test_manifest_survives_a_line_cut_short(tmp_path):
    path = tmp_path / batch.MANIFEST
    path.write_text(json.dumps({"id": "a", "status": "done"}) + "\n" + '{"id": "b", "sta')
    m = Manifest(path)
    assert m.read() == {"a": {"id": "a", "status": "done"}}
    m.open()
    m.append({"id": "b", "status": "failed"})
    m.append({"id": "a", "status": "failed"})  # the last record of an asset wins
    m.close()
    assert m.read() == {"a": {"id": "a", "status": "failed"}, "b": {"id": "b", "status": "failed"}}


def test_guard_interrupts_past_time_and_memory_limits():
    guard = batch.Guard(timeout=0.3, max_mb=None, interval=0.02).start()
    t0 = time.monotonic()
    with pytest.raises(batch.AssetTimeout):
        while time.monotonic() - t0 < 30:
            sum(range(1000))
    guard.stop()
    assert guard.reason == "timeout after 0.3 s" and time.monotonic() - t0 < 5
    guard = batch.Guard(timeout=60, max_mb=batch.rss_mb() + 200, interval=0.02).start()
    with pytest.raises(batch.AssetMemoryError):
        hog = []
        for _ in range(200):
            hog.append(np.ones(2**20 // 8 * 10))  # 10 MB each
            time.sleep(0.005)
    guard.stop()
    del hog
    assert guard.reason.startswith("memory limit:")


def test_worker_loads_the_model_once_and_runs_assets_with_it(tmp_path, monkeypatch):
    """The per-asset function of both engines, in this process: the worker's start loads the
    model; later assets reuse it; a failing asset is a record, not an exception."""
    from pointcvx.apps.batch import worker
    from pointcvx.model.weights import cache_info

    monkeypatch.setattr(worker, "limit_threads", lambda threads: None)  # keep the tests' threads
    opts = batch.init_worker(FAST, workers_here=2)
    assert opts.max_memory_mb > 0  # resolved: a share of this machine's memory
    loads = cache_info().misses
    outs = [batch.run_asset({"id": "nope", "path": str(tmp_path / "nope.obj")}, opts, str(tmp_path)),
            batch.run_asset({"id": "objects/mug", "path": str(DEV / "objects" / "mug.obj")}, opts,
                            str(tmp_path))]
    assert cache_info().misses == loads  # no model loaded during the assets
    assert outs[0]["record"]["status"] == "failed" and "no such file" in outs[0]["record"]["error"]
    assert outs[0]["files"] == {}
    rec = outs[1]["record"]
    assert rec["status"] == "done" and rec["output"] == "hulls/objects/mug.obj", rec
    assert list(outs[1]["files"]) == [rec["output"]] == rec["files"] and not outs[1]["recycle"]
    assert outs[1]["files"][rec["output"]].count("\no hull_") == rec["hulls"] >= 1
    assert rec["seed"] == asset_seed(0, "objects/mug") and rec["worker"].endswith(f":{os.getpid()}")
    assert 0 < rec["cpu_seconds"] and 0 < rec["seconds"]
    assert not (tmp_path / "hulls").exists()  # workers never write: the driver does


def test_bad_batch_inputs_are_one_line_errors(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["batch", str(tmp_path / "empty"), "-o", str(tmp_path / "out")]) == 1
    bad = tmp_path / "list.json"
    bad.write_text('{"not": "a list"}')
    assert main(["batch", str(bad), "-o", str(tmp_path / "out")]) == 1
    afile = tmp_path / "taken"
    afile.write_text("x")
    assert main(["batch", str(DEV / "objects" / "mug.obj"), "-o", str(afile)]) == 1
    with pytest.raises(SystemExit) as usage:  # a usage error: exit status 2
        main(["batch", str(DEV / "objects" / "mug.obj"), "-o", str(tmp_path / "o"), "--jobs", "0"])
    assert usage.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and all(line.startswith("pointcvx: error: ") for line in err)
    assert "no shape file in this folder" in err[0]
    assert "a JSON manifest must be a list" in err[1]
    assert "exists and is not a folder" in err[2]
    assert "--jobs: must be positive" in err[3]
    with pytest.raises(OutputError):
        run_batch([DEV / "objects" / "mug.obj"], afile, FAST)
    with pytest.raises(InputError, match="jobs must be at least 1"):
        run_batch([DEV / "objects" / "mug.obj"], tmp_path / "o", FAST, jobs=0)


def test_ray_engine_without_ray_names_the_extra(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # as if ray were not installed
    with pytest.raises(MissingExtraError, match=r"pip install 'pointcvx\[ray\]'"):
        run_batch([DEV / "objects" / "mug.obj"], tmp_path / "out", FAST, engine="ray")
    assert main(["batch", str(DEV / "objects" / "mug.obj"), "-o", str(tmp_path / "out"),
                 "--engine", "ray"]) == 1
    assert "pointcvx[ray]" in capsys.readouterr().err


# ------------------------------------------------------------------------------------ local pool
@pytest.fixture(scope="module")
def local_run(tmp_path_factory):
    """Five dev shapes and a corrupt file on two local workers; one worker killed mid-run; then
    resumed through the CLI after the corrupt file is replaced by a real shape."""
    tmp = tmp_path_factory.mktemp("local")
    listing, corrupt = _manifest_file(tmp, DOZEN[:5])
    out = tmp / "out"
    progress, killed = _killer()
    first = run_batch([listing], out, FAST, jobs=2, progress=progress)
    first_records = _records(out)
    first_json = json.loads((out / batch.REPORT_JSON).read_text())
    first_csv = (out / batch.REPORT_CSV).read_text().splitlines()
    mtimes = {r["id"]: (out / r["output"]).stat().st_mtime_ns for r in first.rows if r["status"] == "done"}
    l_block().export(corrupt, file_type="obj")  # the bad asset is fixed before resuming
    t0 = time.perf_counter()
    code = main(["batch", str(listing), "-o", str(out), "--jobs", "2", *FAST_ARGS])
    return {"out": out, "listing": listing, "first": first, "killed": killed, "code": code,
            "first_records": first_records, "first_json": first_json, "first_csv": first_csv,
            "mtimes": mtimes, "resume_seconds": time.perf_counter() - t0}


def test_local_batch_records_a_bad_asset_and_a_killed_worker(local_run):
    first = local_run["first"]
    assert len(first.rows) == 6
    _check_killed_run(first, local_run["killed"], "corrupt")
    assert first.summary["failed"] == 2 and first.summary["run"] == 6
    assert first.summary["assets_per_minute"] > 0 and first.summary["mean_hulls"] >= 1
    report = local_run["first_json"]
    assert report["summary"]["done"] == 4 and len(report["assets"]) == 6
    assert report["assets"] == json.loads(json.dumps(first.rows))
    csv_lines = local_run["first_csv"]
    assert csv_lines[0].split(",")[:3] == ["id", "status", "error"] and len(csv_lines) == 7
    done = [r for r in first.rows if r["status"] == "done"]
    assert all(0 < float(r["seconds"]) < 300 and 100 < float(r["peak_mb"]) < 8000 for r in done)


def test_local_batch_resumes_without_redoing_done_assets(local_run):
    out = local_run["out"]
    assert local_run["code"] == 0  # every asset done
    records = _records(out)
    new = records[len(local_run["first_records"]):]
    first_failed = {r["id"] for r in local_run["first"].rows if r["status"] == "failed"}
    assert {r["id"] for r in new} == first_failed and all(r["status"] == "done" for r in new)
    for ident, mtime in local_run["mtimes"].items():  # done assets were not written again
        assert (out / "hulls" / f"{ident}.obj").stat().st_mtime_ns == mtime
    summary = json.loads((out / batch.REPORT_JSON).read_text())["summary"]
    assert (summary["done"], summary["failed"], summary["skipped"], summary["run"]) == (6, 0, 4, 2)
    # nothing left: a third run starts no worker
    again = run_batch([local_run["listing"]], out, FAST, jobs=2)
    assert again.summary["run"] == 0 and again.summary["done"] == 6
    assert len(_records(out)) == len(records)


def test_same_hulls_with_one_or_two_workers(local_run, tmp_path):
    """Hulls depend only on the asset: one worker gives byte-identical files to two workers."""
    out = tmp_path / "one"
    report = run_batch([local_run["listing"]], out, FAST, jobs=1)
    assert report.summary["done"] == 6 and report.summary["jobs"] == 1
    two = local_run["out"] / "hulls"
    files = sorted(p.relative_to(two) for p in two.rglob("*.obj"))
    assert len(files) == 6
    for rel in files:
        assert (out / "hulls" / rel).read_bytes() == (two / rel).read_bytes(), rel


def test_timeout_is_a_recorded_failure_then_retried(tmp_path):
    mug = DEV / "objects" / "mug.obj"
    out = tmp_path / "out"
    opts = FAST.replace(timeout=0.01)
    report = run_batch([mug], out, opts, jobs=1)
    (row,) = report.rows
    assert row["status"] == "failed" and row["error"] == "timeout after 0.01 s"
    assert report.summary["failed"] == 1
    # the time limit is not part of the settings' fingerprint: the retry resumes the same batch
    report = run_batch([mug], out, FAST, jobs=1)
    assert report.rows[0]["status"] == "done" and report.summary["run"] == 1


# ------------------------------------------------------------------------------------ Ray
def test_ray_batch_survives_a_killed_worker_and_resumes(tmp_path, monkeypatch):
    """A dozen dev shapes and a corrupt file on two Ray actors of a local Ray instance on
    127.0.0.1; one actor's process is killed (SIGKILL) while it runs an asset; every other asset
    is done; a second run completes the batch; the hulls equal the local engine's."""
    monkeypatch.setenv("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")  # Ray on loopback only
    # Ray starts workers at niceness 15: on a busy machine they would wait behind everything else
    monkeypatch.setenv("RAY_worker_niceness", "0")
    ray = pytest.importorskip("ray")
    listing, corrupt = _manifest_file(tmp_path, DOZEN)
    out = tmp_path / "out"
    with batch.ray_session(None, num_cpus=2):
        assert ray.util.get_node_ip_address() == "127.0.0.1"
        progress, killed = _killer()
        first = run_batch([listing], out, FAST, engine="ray", jobs=2, progress=progress)
        assert len(first.rows) == 13 and first.summary["engine"] == "ray"
        victim = _check_killed_run(first, killed, "corrupt")
        n_first = len(_records(out))
        second = run_batch([listing], out, FAST, engine="ray", jobs=2)
    assert not ray.is_initialized()
    assert second.summary["skipped"] == 11 and second.summary["run"] == 2
    rows = _by_id(second)
    assert rows[victim]["status"] == "done"
    assert rows["corrupt"]["status"] == "failed"  # still corrupt: failed again, recorded again
    assert {r["id"] for r in _records(out)[n_first:]} == {victim, "corrupt"}
    assert second.summary["done"] == 12
    # same code path per asset: the local engine gives the same hulls for the same asset id
    listing2 = tmp_path / "inputs" / "one.txt"
    listing2.write_text(str(DEV / DOZEN[0]) + "\n")
    local = run_batch([listing2], tmp_path / "local", FAST, jobs=1)
    assert local.rows[0]["id"] == "objects/mug" == first.rows[0]["id"]
    assert ((tmp_path / "local" / local.rows[0]["output"]).read_bytes()
            == (out / first.rows[0]["output"]).read_bytes())


def test_default_features_are_auto_and_the_model_is_part_of_their_fingerprint(tmp_path):
    """With "auto" a splat's output depends on the model: another checkpoint is another batch;
    with per-shape optimisation the checkpoint plays no part."""
    opts = BatchOptions()
    assert opts.decompose.features == "auto"
    opts.check()
    other = tmp_path / "other.pt"
    other.write_bytes(b"not the bundled weights")
    assert BatchOptions.create(model=str(other)).fingerprint() != opts.fingerprint()
    assert (BatchOptions.create(features="optimize", model=str(other)).fingerprint()
            == BatchOptions.create(features="optimize").fingerprint())
    with pytest.raises(InputError, match="no such model checkpoint"):
        BatchOptions.create(model=str(tmp_path / "missing.pt")).check()
    with pytest.raises(InputError, match="unknown features"):
        BatchOptions.create(features="best").check()


def test_subsurface_option_reaches_decompose_and_is_checked(tmp_path):
    from pointcvx.cli import build_parser
    from pointcvx.cli.batch import batch_options

    opts = batch_options(build_parser().parse_args(["batch", "in", "-o", "out", "--subsurface", "0.05"]))
    assert opts.decompose.subsurface == 0.05 and opts.decompose_kwargs(0)["subsurface"] == 0.05
    assert opts.fingerprint() != BatchOptions().fingerprint()
    with pytest.raises(InputError, match="subsurface must be positive"):
        BatchOptions.create(subsurface=0.0).check()
