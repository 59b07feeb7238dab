"""The results file: ``results.csv``'s columns, reading and writing its rows (atomically), and
:class:`BenchReport`, what a benchmark leaves behind."""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...errors import InputError
from ...io.files import atomic_path

COLUMNS = (
    "dataset", "category", "shape", "method", "setting", "param", "hulls", "concavity",
    "reconstruction", "iou", "coverage", "seconds", "oneshot_seconds", "peak_mb", "error",
    "param_name", "threshold", "target_hulls", "search_runs", "search_seconds", "modality",
    "hull_file", "oneshot_error",
)
"""Columns of ``results.csv``. ``threshold`` is the pointcvx threshold the row belongs to (empty
for fixed-setting baselines); ``target_hulls`` the hull count a matched row aimed at;
``search_runs`` the parameter values tried (the reused fixed-setting run included);
``search_seconds`` the method time of all of them; ``hull_file`` is relative to OUTDIR.
``seconds`` is the warm time of the method's call; ``oneshot_seconds`` the same run as a whole
process, start-up included (:mod:`.oneshot`; fixed-setting rows only), ``oneshot_error`` why a
one-shot run gave no time. Files written before a column existed read it as empty."""
METRICS = ("hulls", "concavity", "reconstruction", "iou", "coverage")
"""The columns :func:`pointcvx.evaluate.evaluate` fills."""


@dataclass
class BenchReport:
    """What :func:`~.driver.run_bench` did: every row of ``results.csv`` and the files written."""

    rows: list[dict]
    new_rows: int
    outdir: Path
    files: list[Path] = field(default_factory=list)


def key_of(dataset: str, shape: str, method: str, setting: str, threshold: str) -> str:
    """The identity of a row: a benchmark has at most one row per key."""
    return "\t".join((dataset, shape, method, setting, threshold))


def row_key(row: dict) -> str:
    """:func:`key_of` of ``row``."""
    return key_of(row["dataset"], row["shape"], row["method"], row["setting"], row.get("threshold", ""))


def num(value) -> float:
    """A cell as a float; NaN when empty or not a number."""
    if value is None or value == "":
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def _cell(value) -> str:
    """A value as a CSV cell: integers plain, floats to 6 significant digits, NaN and None empty."""
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return "" if not math.isfinite(value) else f"{float(value):.6g}"
    return str(value)


def read_results(path: str | os.PathLike) -> list[dict]:
    """The rows of a ``results.csv`` (every value a string); [] when the file does not exist."""
    p = Path(path)
    if not p.is_file():
        return []
    with open(p, newline="") as f:
        reader = csv.DictReader(f)
        missing = [c for c in ("dataset", "shape", "method", "setting") if c not in (reader.fieldnames or [])]
        if missing:
            raise InputError(f"{p}: not a pointcvx bench results file (no {missing[0]!r} column); "
                             "pass --overwrite to start over")
        return [{c: (r.get(c) or "") for c in COLUMNS} for r in reader]


def write_atomic(path: Path, data: str | bytes) -> None:
    """Write ``data`` (text or bytes) to ``path`` through a temporary file renamed into place."""
    with atomic_path(path, overwrite=True) as tmp:
        if isinstance(data, bytes):
            tmp.write_bytes(data)
        else:
            tmp.write_text(data)


def write_results(path: str | os.PathLike, rows: Sequence[dict]) -> None:
    """Write ``rows`` as CSV with :data:`COLUMNS` (atomically)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for r in rows:
        w.writerow([_cell(r.get(c)) for c in COLUMNS])
    write_atomic(Path(path), buf.getvalue())
