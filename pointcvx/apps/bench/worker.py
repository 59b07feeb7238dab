"""One benchmark run in its own process: ``python -m pointcvx.apps.bench.worker JOB.json``.

``pointcvx bench`` (:func:`pointcvx.apps.bench.launch.launch`) starts this module once per
(method, shape, setting) so that every run has a fresh interpreter, its own wall-clock timeout
and its own peak memory. The job file is JSON with:

``method``
    ``pointcvx``, ``coacd``, ``vhacd`` (V-HACD 2.x through ``pybullet.vhacd``) or ``vhacdx``.
``input``
    The file the method reads: the normalised mesh as OBJ (every method) or, for pointcvx on a
    splat or a scan, the original file.
``arrays``
    ``.npz`` with ``vertices`` (n, 3) float and ``faces`` (m, 3) int of that OBJ (read by the
    in-memory baselines, so that parsing the OBJ is not timed), or null.
``params``
    Keyword arguments of the method (see ``_RUNNERS``).
``hulls``
    Where to write the hulls: an OBJ with one ``o hull_NNN`` object per hull.
``points``
    For pointcvx only, optional: where to save the decomposed cloud in input units, (n, 3)
    float as ``.npy`` (the reference of the point-based metrics for splats and scans).
``result``
    Where to write the result JSON: ``ok``, ``hulls`` (count), ``seconds`` (the method's call
    only: no interpreter start, no imports, no file writing), ``peak_kb`` (peak resident memory
    of this process in KiB, see :func:`~pointcvx.apps.common.peak_kb`) and ``error`` (one line,
    when ``ok`` is false).

The method's own output on stdout and stderr (V-HACD and CoACD are chatty) goes wherever the
parent sent it; the result travels only through the result file.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from ...errors import first_line
from ..common import limit_threads, peak_kb


def _load_arrays(job: dict) -> tuple[np.ndarray, np.ndarray]:
    with np.load(job["arrays"]) as data:
        return np.asarray(data["vertices"], dtype=np.float64), np.asarray(data["faces"], dtype=np.int64)


def write_obj(path: str | os.PathLike, hulls: list[tuple[np.ndarray, np.ndarray]]) -> int:
    """Write ``hulls`` ((k, 3) float vertices, (f, 3) int faces) as an OBJ with one ``o hull_NNN``
    object per hull (:func:`pointcvx.export.obj_text`), skipping hulls without a face; return how
    many were written."""
    from ...export import obj_text

    pairs = [(np.asarray(v, dtype=np.float64).reshape(-1, 3), np.asarray(f, dtype=np.int64).reshape(-1, 3))
             for v, f in hulls]
    kept = [(v, f) for v, f in pairs if len(v) and len(f)]
    Path(path).write_text(obj_text(kept))
    return len(kept)


def read_obj_objects(path: str | os.PathLike) -> list[tuple[np.ndarray, np.ndarray]]:
    """Read an OBJ whose ``o`` objects are hulls (V-HACD's output): a list of (k, 3) float
    vertices and (f, 3) int faces (0-based, local to each object; polygons are fanned)."""
    verts: list[list[float]] = []
    objects: list[list[list[int]]] = [[]]
    with open(path, errors="replace") as f:
        for line in f:
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "v":
                verts.append([float(x) for x in parts[1:4]])
            elif parts[0] == "o":
                objects.append([])
            elif parts[0] == "f":
                idx = [int(p.split("/")[0]) for p in parts[1:]]
                idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                objects[-1].extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
    vertices = np.asarray(verts, dtype=np.float64).reshape(-1, 3)
    out = []
    for faces in objects:
        if not faces:
            continue
        f = np.asarray(faces, dtype=np.int64)
        used, local = np.unique(f, return_inverse=True)
        out.append((vertices[used], local.reshape(-1, 3)))
    return out


# ------------------------------------------------------------------------------------ methods
def warm_pointcvx(params: dict) -> None:
    """Bring the process to the state of a long-running one (``pointcvx batch``, a scan pipeline)
    before its next shape: :func:`pointcvx.pipeline.preload` (lazy imports, model weights), then
    one small decomposition. The timed call then pays none of these one-time costs, as the
    baselines' timed calls do not pay their imports."""
    import trimesh

    from ...pipeline import decompose, preload

    preload(params.get("features", "auto"), params.get("model"))
    # One small decomposition of a ring: the first call of a process also pays one-time set-up
    # inside torch, scikit-learn and Qhull, which a batch pays once.
    ring = trimesh.creation.annulus(r_min=0.5, r_max=1.0, height=0.4)
    decompose(ring, **{**params, "max_hulls": 4, "threshold": 0.2})


def _run_pointcvx(job: dict, params: dict) -> tuple[list, float]:
    from ...pipeline import decompose

    warm_pointcvx(params)
    t0 = time.perf_counter()
    result = decompose(job["input"], **params)
    seconds = time.perf_counter() - t0
    if job.get("points"):
        np.save(job["points"], result.cloud.in_input_units().points)
    return [(h.vertices, h.faces) for h in result.hulls], seconds


def _run_coacd(job: dict, params: dict) -> tuple[list, float]:
    import coacd

    coacd.set_log_level("error")
    vertices, faces = _load_arrays(job)
    t0 = time.perf_counter()
    parts = coacd.run_coacd(coacd.Mesh(vertices, faces.astype(np.int32)), **params)
    seconds = time.perf_counter() - t0
    return [(v, f) for v, f in parts], seconds


def _run_vhacd(job: dict, params: dict) -> tuple[list, float]:
    import pybullet

    out = str(Path(job["hulls"]).with_suffix(".vhacd.obj"))
    log_txt = str(Path(job["hulls"]).with_suffix(".vhacd.log"))
    t0 = time.perf_counter()
    pybullet.vhacd(job["input"], out, log_txt, **params)
    seconds = time.perf_counter() - t0
    if not Path(out).is_file():
        raise RuntimeError("pybullet.vhacd wrote no output")
    hulls = read_obj_objects(out)
    for p in (out, log_txt):
        Path(p).unlink(missing_ok=True)
    return hulls, seconds


def _run_vhacdx(job: dict, params: dict) -> tuple[list, float]:
    import vhacdx

    vertices, faces = _load_arrays(job)
    t0 = time.perf_counter()
    parts = vhacdx.compute_vhacd(vertices, faces.astype(np.uint32), **params)
    seconds = time.perf_counter() - t0
    return [(v, f) for v, f in parts], seconds


_RUNNERS = {"pointcvx": _run_pointcvx, "coacd": _run_coacd, "vhacd": _run_vhacd, "vhacdx": _run_vhacdx}


def run_job(job: dict) -> dict:
    """Run ``job`` (see the module docstring) and return its result dict (also written to
    ``job["result"]``)."""
    result: dict = {"ok": False, "method": job.get("method")}
    try:
        runner = _RUNNERS[job["method"]]
        if job["method"] == "pointcvx":
            limit_threads(job.get("threads"))
        hulls, seconds = runner(job, dict(job.get("params") or {}))
        result["seconds"] = seconds
        result["peak_kb"] = peak_kb()
        count = write_obj(job["hulls"], hulls)
        if count == 0:
            raise RuntimeError(f"{job['method']} returned no hull")
        result.update(ok=True, hulls=count)
    # A decomposition library can fail in any way on a hard shape; the benchmark records the
    # failure as an error row and goes on with the next run.
    except Exception as exc:  # noqa: BLE001
        result["error"] = first_line(exc, typed=True)
    result.setdefault("peak_kb", peak_kb())
    tmp = Path(job["result"]).with_suffix(".part")
    tmp.write_text(json.dumps(result))
    os.replace(tmp, job["result"])
    return result


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m pointcvx.apps.bench.worker JOB.json", file=sys.stderr)
        return 2
    job = json.loads(Path(args[0]).read_text())
    return 0 if run_job(job)["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
