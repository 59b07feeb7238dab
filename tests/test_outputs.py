"""Outputs as careful users expect them: a multi-file output appears whole or not at all (also
under kill -9), ``--overwrite`` replaces the whole previous output and nothing else, two formats
of one input never share a folder, and leftovers of killed runs go with the next run."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest

import pointcvx
from conftest import ROOT
from pointcvx.apps.batch import BatchOptions, Manifest, run_batch
from pointcvx.cli import EXIT_INPUT, main
from pointcvx.export import write_files
from pointcvx.io.files import atomic_path
from pointcvx.io.outputs import MANIFEST, TEMP_PREFIX, process_alive, replace_folder, temp_name


def _tree(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (hidden ones included): relative path -> content."""
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(TEMP_PREFIX))


def _dead_pid() -> int:
    """The id of a process that has just ended (and been reaped)."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


# ------------------------------------------------------------------------------ --overwrite
def test_overwrite_replaces_the_whole_previous_output(result, tmp_path):
    assert len(result) >= 3
    fewer = replace(result, hulls=result.hulls[:2])
    for kind, path, n_files in [("obj", tmp_path / "parts", lambda n: n),
                                ("stl", tmp_path / "parts.stl", lambda n: n),
                                ("urdf", tmp_path / "torus.urdf", lambda n: n + 2),
                                ("mjcf", tmp_path / "torus.xml", lambda n: n + 2)]:
        first = result.export(path, per_hull=kind == "obj")
        folder = first[-1].parent
        assert len(first) == n_files(len(result)), kind
        assert sorted(os.listdir(folder)) == sorted([MANIFEST, *(f.name for f in first)])
        with pytest.raises(pointcvx.OutputError, match="exists"):
            fewer.export(path, per_hull=kind == "obj")
        second = fewer.export(path, per_hull=kind == "obj", overwrite=True)
        # exactly the new files (and the manifest listing them): no stale hull_002.. or
        # *_collision_2.obj, whatever the format
        assert len(second) == n_files(2), kind
        assert sorted(os.listdir(folder)) == sorted([MANIFEST, *(f.name for f in second)]), kind
        listed = json.loads((folder / MANIFEST).read_text())
        assert sorted(listed["files"]) == sorted(f.name for f in second) and listed["format"] == kind
    assert sorted(os.listdir(tmp_path)) == ["parts", "parts_stl", "torus_mjcf", "torus_urdf"]


def test_files_pointcvx_did_not_write_are_never_deleted(result, tmp_path, source):
    # a folder of the user's own files (`-o .`, `-o ~/Desktop/`): refused, even with overwrite
    desk = tmp_path / "Desktop"
    desk.mkdir()
    (desk / "notes.txt").write_text("mine")
    (desk / "hull_000.obj").write_text("my own hull file")
    before = _tree(desk)
    for overwrite in (False, True):
        with pytest.raises(pointcvx.OutputError, match="did not write .* a folder of its own"):
            result.export(desk, overwrite=overwrite)
        with pytest.raises(pointcvx.OutputError, match="did not write"):
            result.export(desk, "urdf", overwrite=overwrite)
    assert _tree(desk) == before
    # an empty folder is the user's way to say where: taken
    (tmp_path / "empty").mkdir()
    assert len(result.export(tmp_path / "empty")) == len(result)
    # a pointcvx output the user has put a file into: the output is not replaced, the file kept
    robot = result.export(tmp_path / "robot.urdf")[0].parent
    (robot / "tuning.yaml").write_text("mine")
    (robot / "textures").mkdir()
    before = _tree(robot)
    with pytest.raises(pointcvx.OutputError, match=r"holds textures/ and 1 more, which pointcvx did not"):
        result.export(tmp_path / "robot.urdf", overwrite=True)
    assert _tree(robot) == before
    # a manifest pointcvx cannot read: it cannot tell, so it refuses
    (robot / "tuning.yaml").unlink()
    (robot / "textures").rmdir()
    (robot / MANIFEST).write_text("{not json")
    with pytest.raises(pointcvx.OutputError, match="unreadable"):
        result.export(tmp_path / "robot.urdf", overwrite=True)
    # an output that holds the input being decomposed is not replaced
    inside = result.export(tmp_path / "again.urdf")[0].parent
    mine = replace(result, cloud=replace(result.cloud, info={**result.cloud.info,
                                                               "source": str(inside / "again.obj")}))
    with pytest.raises(pointcvx.OutputError, match="holds the input file"):
        mine.export(tmp_path / "again.urdf", overwrite=True)
    assert (inside / "again.obj").is_file()
    assert not [p for p in tmp_path.rglob(f"{TEMP_PREFIX}*")]


def test_the_readme_exports_of_one_input_do_not_collide(source, tmp_path, capsys, monkeypatch):
    """``-o mug.xml`` then ``-o mug.urdf`` (README) write two folders; the summary says where;
    a folder of someone else's files is refused before decomposing, in one line."""
    monkeypatch.chdir(tmp_path)
    args = ["decompose", str(source), "--features", "model", "-n", "2000", "-k", "3"]
    for out, folder, main_name in [("t.xml", "t_mjcf", "t.xml"), ("t.urdf", "t_urdf", "t.urdf")]:
        assert main([*args, "-o", out]) == 0
        line = capsys.readouterr().out.strip()
        files = sorted(os.listdir(folder))
        assert main_name in files and MANIFEST in files
        where = f"{folder}{os.sep}"
        assert line.endswith(f"-> {where}{main_name} ({len(files) - 1} files in {where})"), line
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "a.txt").write_text("mine")
    t0 = time.perf_counter()
    assert main([*args, "-o", "mine", "--overwrite"]) == EXIT_INPUT
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "pointcvx did not write (a.txt)" in err, err
    assert time.perf_counter() - t0 < 5.0  # refused before the decomposition
    assert sorted(os.listdir(tmp_path)) == ["mine", "t_mjcf", "t_urdf"]


# ------------------------------------------------------------------------------ kill -9
WRITER = """
import sys
from pathlib import Path
from pointcvx.apps.batch import BatchOptions, Manifest, run_batch
from pointcvx.export import write_files
folder, gen, n, size = Path(sys.argv[1]), sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
body = "v 0 0 0\\n" * (size // 8)
files = {folder / f"hull_{i:04d}.obj": f"# {gen}\\n{body}# end {gen} {i}\\n" for i in range(n)}
write_files(files, overwrite=True, folder=folder, about={"gen": gen})
"""
GENERATIONS = {"a": (300, 200), "b": (100, 40_000), "c": (7, 100)}  # files, bytes per file


def _write(folder: Path, gen: str) -> subprocess.Popen:
    n, size = GENERATIONS[gen]
    return subprocess.Popen([sys.executable, "-c", WRITER, str(folder), gen, str(n), str(size)], cwd=ROOT)


def _generation(folder: Path) -> str | None:
    """The generation ``folder`` holds, checked whole (every listed file complete, nothing else),
    or None where it is absent."""
    if not folder.exists():
        return None
    manifest = json.loads((folder / MANIFEST).read_text())
    gen = manifest["gen"]
    names = sorted(os.listdir(folder))
    assert names == sorted([MANIFEST, *manifest["files"]])
    assert len(manifest["files"]) == GENERATIONS[gen][0]
    for name in manifest["files"]:
        text = (folder / name).read_text()
        assert text.startswith(f"# {gen}\n") and text.endswith(f"# end {gen} {int(name[5:9])}\n"), name
    return gen


def _kill_when(proc: subprocess.Popen, ready, limit: float = 60.0) -> bool:
    """SIGKILL ``proc`` as soon as ``ready()`` holds; whether it was killed before it ended."""
    t0 = time.monotonic()
    while proc.poll() is None and time.monotonic() - t0 < limit:
        if ready():
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            return True
    proc.wait()
    return False


def _temps(parent: Path) -> list[Path]:
    return [p for p in parent.iterdir() if p.name.startswith(TEMP_PREFIX)]


def test_a_multi_file_output_is_whole_or_absent_under_kill_9(tmp_path):
    moments = {  # where the writer of generation b is killed: (the output before, ready(), what
        # a reader then sees: nothing, the previous output whole or the new one whole)
        "temp folder made": (None, lambda parent, target, ino: bool(_temps(parent)), None),
        "half the files written": (None, lambda parent, target, ino: any(
            len(os.listdir(t)) >= GENERATIONS["b"][0] // 2 for t in _temps(parent) if t.is_dir()), None),
        "while writing over a": ("a", lambda parent, target, ino: any(
            len(os.listdir(t)) >= 20 for t in _temps(parent) if t.is_dir()), "a"),
        "deleting the old a": ("a", lambda parent, target, ino: os.stat(target).st_ino != ino, "b"),
    }
    hits = []
    for moment, (before, ready, expected) in moments.items():
        parent = tmp_path / moment.replace(" ", "_")
        parent.mkdir()
        target = parent / "hulls"
        if before:
            assert _write(target, before).wait() == 0
        ino = os.stat(target).st_ino if before else None
        killed = _kill_when(_write(target, "b"), lambda r=ready, p=parent, t=target, i=ino: r(p, t, i))
        hits.append(killed)
        seen = _generation(target)  # checks that what is there is whole
        assert seen == (expected if killed else "b"), (moment, seen)
        assert [p.name for p in parent.iterdir() if not p.name.startswith(".")] == (
            ["hulls"] if seen else []), moment  # nothing else visible
        # the next run into the same place succeeds, replaces it whole and cleans what was left
        assert _write(target, "c").wait() == 0
        assert _generation(target) == "c" and not _temps(parent), moment
    assert hits[:3] == [True, True, True], hits  # the last moment lasts a few milliseconds


def test_a_killed_single_file_write_leaves_nothing_the_next_run_keeps(tmp_path):
    target = tmp_path / "hulls.obj"
    target.write_text("the previous output\n")
    code = (f"import sys, time\nfrom pointcvx.io.files import atomic_path\n"
            f"with atomic_path({str(target)!r}) as tmp:\n    tmp.write_text('half')\n"
            "    print('ready', flush=True)\n    time.sleep(60)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    assert proc.stdout.readline().strip() == "ready"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert target.read_text() == "the previous output\n" and len(_temps(tmp_path)) == 1
    with atomic_path(target) as tmp:  # this process's first write into the folder
        tmp.write_text("new\n")
    assert target.read_text() == "new\n" and not _temps(tmp_path)
    assert os.stat(target).st_mode & 0o777 == 0o666 & ~_umask()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_replacing_without_an_atomic_swap_and_the_set_aside_output_put_back(tmp_path):
    """Where the system cannot swap two folders, the old output is renamed aside, the new one in;
    a run killed between the two renames left only the set-aside output, which the next run puts
    back before deciding anything; a live process's temporaries are left alone."""
    old = tmp_path / "parts"
    write_files({old / "hull_000.obj": "old 0\n", old / "hull_001.obj": "old 1\n"}, folder=old)
    new = tmp_path / ".new"
    new.mkdir()
    (new / "hull_000.obj").write_text("new 0\n")
    (new / MANIFEST).write_text(json.dumps({"name": "parts", "files": ["hull_000.obj"]}))
    replace_folder(new, old, exchange=False)
    assert _tree(old)["hull_000.obj"] == b"new 0\n" and len(_tree(old)) == 2
    assert sorted(os.listdir(tmp_path)) == ["parts"]
    # the state a kill between the two renames leaves: the previous output aside, no target
    write_files({old / "hull_000.obj": "old 0\n", old / "hull_001.obj": "old 1\n"}, folder=old,
                overwrite=True)
    saved = _tree(old)
    place = tmp_path / "place"  # a folder this process has not written into yet
    place.mkdir()
    old.rename(place / temp_name("old", "parts", pid=_dead_pid()))
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        live = place / temp_name("new", "parts", pid=sleeper.pid)
        live.mkdir()
        with pytest.raises(pointcvx.OutputError, match="exists"):  # put back: not replaced unasked
            write_files({place / "parts" / "hull_000.obj": "x\n"}, folder=place / "parts")
        assert _tree(place / "parts") == saved and _hidden(place) == [live.name]
    finally:
        sleeper.kill()
        sleeper.wait()


def test_a_leftover_is_told_by_its_process(tmp_path):
    """A temporary is a leftover when its process is gone, a zombie, or (pid reused) started after
    the temporary was last touched."""
    assert not process_alive(_dead_pid())
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        assert process_alive(sleeper.pid, since=time.time())
        assert not process_alive(sleeper.pid, since=time.time() - 3600)  # the pid's earlier owner
        sleeper.kill()
        time.sleep(0.2)
        assert not process_alive(sleeper.pid)  # killed, not yet reaped: a zombie
    finally:
        sleeper.kill()
        sleeper.wait()


def test_batch_replaces_an_asset_folder_whole(source, tmp_path):
    """A batch writes a folder format through the same writer: a rerun with other settings
    replaces each asset's folder whole (no stale collision files), and resume trusts it."""
    shape = tmp_path / "in" / "torus.obj"
    shape.parent.mkdir()
    shape.write_bytes(source.read_bytes())
    out = tmp_path / "out"
    folder = out / "hulls" / "torus_urdf"
    kept = []
    for hulls in (4, 2):
        opts = BatchOptions.create(format="urdf", features="model", n_points=2000, max_hulls=hulls)
        (row,) = run_batch([shape], out, opts, jobs=1).rows
        assert row["status"] == "done" and row["output"] == "hulls/torus_urdf/torus.urdf", row
        rec = Manifest(out / "batch_manifest.jsonl").read()["torus"]
        assert sorted(os.listdir(folder)) == sorted([MANIFEST, *(Path(f).name for f in rec["files"])])
        assert len(rec["files"]) == row["hulls"] + 2
        kept.append(_tree(folder))
    assert kept[0] != kept[1] and not _temps(out / "hulls")
    again = run_batch([shape], out, opts, jobs=1)  # resumed: done, nothing rewritten
    assert again.summary["skipped"] == 1 and _tree(folder) == kept[1]
