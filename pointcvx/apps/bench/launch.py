"""Launching one worker run: ``python -m pointcvx.apps.bench.worker JOB.json`` in a fresh process
with a wall-clock timeout, and what it reports (:class:`Run`)."""

from __future__ import annotations

import json
import logging
import math
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)

WORKER = "pointcvx.apps.bench.worker"
"""The module each run executes (``python -m``)."""
PACKAGE_ROOT = Path(__file__).resolve().parents[3]
"""The folder holding the ``pointcvx`` package, put first on the worker's ``PYTHONPATH``."""


@dataclass
class Run:
    """One finished (or failed) worker run."""

    method: str
    param: float
    ok: bool
    hulls: int | None = None
    seconds: float = math.nan
    peak_mb: float = math.nan
    error: str = ""
    hull_file: Path | None = None
    metrics: dict | None = None
    reused: bool = False


def worker_env(threads: int | None = None) -> dict:
    """The environment of a run's process: this one's, with the package first on
    ``PYTHONPATH`` and, when ``threads`` is set, the thread variables of OpenMP and the BLAS
    libraries (which torch and NumPy read at start) at ``threads``."""
    env = dict(os.environ)
    root = str(PACKAGE_ROOT)
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    if threads:
        for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
            env[name] = str(int(threads))
    return env


def launch(job: dict, stem: Path, timeout: float, param: float, shape: str = "") -> Run:
    """Run ``job`` (see :mod:`.worker`) in a fresh worker process in ``stem``'s folder, killed
    after ``timeout`` seconds. The job file and the worker's log go next to ``stem``; a timeout
    or a crash becomes a failed run."""
    method = job["method"]
    job_file = stem.with_suffix(".job.json")
    job_file.write_text(json.dumps(job))
    env = worker_env()
    t0 = time.perf_counter()
    log_file = stem.with_suffix(".log")
    try:
        with open(log_file, "wb") as out:
            proc = subprocess.run(
                [sys.executable, "-m", WORKER, str(job_file)],
                stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                timeout=timeout, env=env, cwd=str(stem.parent), check=False,
            )
    except subprocess.TimeoutExpired:
        wall = time.perf_counter() - t0
        log.info("%s: %s timed out after %.1f s", shape, method, wall)
        return Run(method, param, False, seconds=wall, error=f"timeout after {timeout:g} s")
    result_file = Path(job["result"])
    if not result_file.is_file():
        tail = last_line(log_file)
        how = f"signal {-proc.returncode}" if proc.returncode < 0 else f"exit status {proc.returncode}"
        return Run(method, param, False, seconds=time.perf_counter() - t0,
                   error=f"worker crashed ({how})" + (f": {tail}" if tail else ""))
    res = json.loads(result_file.read_text())
    peak = res.get("peak_kb")
    run = Run(method, param, bool(res.get("ok")), hulls=res.get("hulls"),
              seconds=float(res.get("seconds", math.nan)),
              peak_mb=peak / 1024.0 if peak is not None else math.nan,
              error=res.get("error", "") if not res.get("ok") else "",
              hull_file=Path(job["hulls"]) if res.get("ok") else None)
    log.debug("%s: %s %s -> %s hulls, %.2f s, %.0f MB %s", shape, method, job["params"],
              run.hulls, run.seconds, run.peak_mb, run.error)
    return run


def last_line(path: Path) -> str:
    """The last non-blank line of a text file (at most 200 characters); "" when unreadable."""
    try:
        lines = [ln.strip() for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    return lines[-1][:200] if lines else ""

