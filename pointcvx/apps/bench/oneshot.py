"""One-shot runs: each method as a whole process, the way a user runs it, timed from outside.

A user who decomposes one file pays the interpreter's start, the imports, loading the model,
reading the file and writing the hulls. :func:`time_oneshot` starts that process and times it
from just before its start to its exit:

``pointcvx``
    ``python -m pointcvx decompose SHAPE -o OUT.obj`` with the bench's settings as flags
    (:func:`decompose_flags`).
``coacd``, ``vhacd``, ``vhacdx``
    ``python -m pointcvx.apps.bench.oneshot METHOD JOB.json``: a thin wrapper that imports the
    library, reads the mesh (trimesh, as CoACD's own example does; ``pybullet.vhacd`` reads the
    OBJ itself), runs the method and writes the hulls as an OBJ. This module imports nothing
    beyond the standard library at module level and ``pointcvx.apps.bench`` is lazy, so the
    wrapper adds only a few milliseconds of pointcvx to the baseline's own start-up.

Every method reads the same file as its warm run (the normalised mesh, or the original splat
or scan for pointcvx). The job file is the warm run's (see :mod:`.worker`): ``input``,
``params`` and ``hulls`` (where the wrapper writes).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

MODULE = "pointcvx.apps.bench.oneshot"
"""The module the baselines' one-shot processes run (``python -m``)."""


# ------------------------------------------------------------------------- the parent side
def decompose_flags(params: dict) -> list[str]:
    """The ``pointcvx decompose`` flags that reproduce ``params`` (keyword arguments of
    :func:`pointcvx.decompose`): one for every option that differs from the command's default.
    An option that differs and has no flag (API only) is an
    :class:`~pointcvx.errors.InputError`: the command cannot run it."""
    from dataclasses import fields

    from ...errors import InputError
    from ...options import DECOMPOSE_POINTS, DecomposeOptions, LoadOptions, spec_of, split_kwargs

    dec, load = split_kwargs(params)
    load.setdefault("n_points", DECOMPOSE_POINTS)  # as pointcvx.decompose does
    out: list[str] = []
    for opts, defaults in ((DecomposeOptions(**dec), {}),
                           (LoadOptions(**load), {"n_points": DECOMPOSE_POINTS})):
        for f in fields(opts):
            value, default = getattr(opts, f.name), defaults.get(f.name, f.default)
            if value == default:
                continue
            spec = spec_of(f)
            if spec.flag is None:
                raise InputError(f"the one-shot run of pointcvx is the command `pointcvx decompose`, "
                                 f"which has no flag for {f.name}; leave it at its default or pass "
                                 "--no-oneshot")
            if spec.kind is bool:
                out.append(spec.flag if value else f"--no-{spec.flag[2:]}")
            elif value is None:  # an optional setting turned off: the command's default is off too
                raise InputError(f"the command `pointcvx decompose` cannot set {f.name} to None")
            elif isinstance(value, tuple):
                out += [spec.flag, ",".join(repr(float(x)) for x in value)]
            else:
                out += [spec.flag, repr(value) if isinstance(value, float) else str(value)]
    return out


def oneshot_command(job: dict) -> list[str]:
    """The command line of ``job``'s one-shot run."""
    if job["method"] == "pointcvx":
        return [sys.executable, "-m", "pointcvx", "decompose", job["input"], "-o", job["hulls"],
                "--overwrite", *decompose_flags(job["params"])]
    return [sys.executable, "-m", MODULE, job["method"], job["job_file"]]


def time_oneshot(job: dict, stem: Path, timeout: float, env: dict) -> tuple[float, int, str]:
    """Run ``job`` as a one-shot process in ``stem``'s folder: (its wall seconds, the hulls it
    wrote, ""), or (NaN, 0, a one-line error) when it fails, times out or writes no hull.
    ``job["hulls"]`` is where the process writes its hulls; the job file and the log go next to
    ``stem``."""
    job = {**job, "job_file": str(stem.with_suffix(".job.json"))}
    Path(job["job_file"]).write_text(json.dumps(job))
    argv = oneshot_command(job)
    log_file = stem.with_suffix(".log")
    t0 = time.perf_counter()
    try:
        with open(log_file, "wb") as out:
            proc = subprocess.run(argv, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                                  timeout=timeout, env=env, cwd=str(stem.parent), check=False)
    except subprocess.TimeoutExpired:
        return math.nan, 0, f"one-shot: timeout after {timeout:g} s"
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        from .launch import last_line

        tail = last_line(log_file)
        return math.nan, 0, f"one-shot: exit status {proc.returncode}" + (f": {tail}" if tail else "")
    hulls = count_objects(job["hulls"])
    if hulls == 0:
        return math.nan, 0, "one-shot: no hull written"
    return seconds, hulls, ""


def count_objects(path: str | os.PathLike) -> int:
    """How many ``o`` objects (hulls) an OBJ file holds; 0 when it is missing."""
    try:
        with open(path, errors="replace") as f:
            return sum(1 for line in f if line.startswith("o "))
    except OSError:
        return 0


# ------------------------------------------------------------------- the one-shot process
def _read_mesh(path: str):
    """(vertices, faces) of the OBJ at ``path``, as a user reads it (trimesh, unprocessed: the
    same arrays the warm run gets)."""
    import numpy as np
    import trimesh

    mesh = trimesh.load(path, force="mesh", process=False)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def write_hulls(path: str | os.PathLike, hulls) -> int:
    """Write (vertices, faces) pairs as an OBJ with one ``o hull_NNN`` object per hull (faces
    0-based in, 1-based out); how many were written."""
    lines, base, count = [], 1, 0
    for vertices, faces in hulls:
        if not len(vertices) or not len(faces):
            continue
        lines.append(f"o hull_{count:03d}")
        lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertices]
        lines += [f"f {a + base} {b + base} {c + base}" for a, b, c in faces]
        base += len(vertices)
        count += 1
    Path(path).write_text("\n".join(lines) + "\n")
    return count


def _coacd(job: dict) -> int:
    import coacd

    coacd.set_log_level("error")
    vertices, faces = _read_mesh(job["input"])
    parts = coacd.run_coacd(coacd.Mesh(vertices, faces.astype("int32")), **job["params"])
    return write_hulls(job["hulls"], parts)


def _vhacd(job: dict) -> int:
    import pybullet

    pybullet.vhacd(job["input"], job["hulls"], str(Path(job["hulls"]).with_suffix(".vhacd.log")),
                   **job["params"])
    return count_objects(job["hulls"])


def _vhacdx(job: dict) -> int:
    import vhacdx

    vertices, faces = _read_mesh(job["input"])
    parts = vhacdx.compute_vhacd(vertices, faces.astype("uint32"), **job["params"])
    return write_hulls(job["hulls"], parts)


WRAPPERS = {"coacd": _coacd, "vhacd": _vhacd, "vhacdx": _vhacdx}
"""The thin wrapper of each baseline: job -> hulls written."""


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2 or args[0] not in WRAPPERS:
        print(f"usage: python -m {MODULE} {{{','.join(WRAPPERS)}}} JOB.json", file=sys.stderr)
        return 2
    job = json.loads(Path(args[1]).read_text())
    return 0 if WRAPPERS[args[0]](job) > 0 else 1


if __name__ == "__main__":
    sys.exit(main())
