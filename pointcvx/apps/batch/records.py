"""What the driver writes in the output folder: the hull files' names, the manifest of finished
assets, and the reports (one row per asset, a summary)."""

from __future__ import annotations

import csv
import io
import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

from .assets import Asset
from .options import BatchOptions

log = logging.getLogger(__name__)

MANIFEST = "batch_manifest.jsonl"
"""The manifest: one JSON line per finished asset (:class:`Manifest`)."""
REPORT_CSV = "batch_report.csv"
REPORT_JSON = "batch_report.json"
"""The reports: one row per asset (:data:`COLUMNS`); the JSON adds the summary."""
HULLS = "hulls"
"""The folder of the hull files, one per asset (:func:`output_path`)."""
COLUMNS = ("id", "status", "error", "hulls", "max_concavity", "mean_concavity", "points", "seconds",
           "cpu_seconds", "peak_mb", "seed", "worker", "output", "path", "finished")
"""Columns of ``batch_report.csv`` (``status``: done, failed or pending)."""


def output_path(outdir: str | os.PathLike, asset_id: str, format: str) -> Path:
    """Where asset ``asset_id``'s hulls go: ``OUTDIR/hulls/<id><ext>`` (folder formats: the folder
    ``OUTDIR/hulls/<id>_<format>/``, written whole, see :mod:`pointcvx.export`)."""
    from ...export import EXTENSIONS

    return Path(outdir) / HULLS / f"{asset_id}{EXTENSIONS[format]}"


class Manifest:
    """``OUTDIR/batch_manifest.jsonl``: one JSON record per line, appended and fsynced; the last
    record of an asset wins; a line cut short (a crash while writing) is ignored and the next
    record starts on a fresh line."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._file = None

    def read(self) -> dict[str, dict]:
        """asset id -> its latest record ({} when there is no manifest)."""
        if not self.path.is_file():
            return {}
        latest: dict[str, dict] = {}
        bad = 0
        with open(self.path, encoding="utf-8", errors="replace") as f:
            for line in f:
                line = line.strip()
                if not line:
                    continue
                try:
                    rec = json.loads(line)
                except json.JSONDecodeError:
                    bad += 1
                    continue
                if isinstance(rec, dict) and isinstance(rec.get("id"), str):
                    latest[rec["id"]] = rec
                else:
                    bad += 1
        if bad:
            log.warning("%s: %d unreadable line(s) ignored", self.path, bad)
        return latest

    def open(self, truncate: bool = False) -> None:
        new = truncate or not self.path.is_file() or self.path.stat().st_size == 0
        self._file = open(self.path, "w" if truncate else "a", encoding="utf-8")
        if not new:
            with open(self.path, "rb") as f:
                f.seek(-1, os.SEEK_END)
                if f.read(1) != b"\n":
                    self._file.write("\n")

    def append(self, record: dict) -> None:
        assert self._file is not None
        self._file.write(json.dumps(record, default=_json_default) + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def _json_default(x):
    try:
        return x.item()  # numpy scalars
    except AttributeError:
        return str(x)


@dataclass
class BatchReport:
    """What :func:`~pointcvx.apps.batch.driver.run_batch` did: one row per asset (:data:`COLUMNS`),
    the summary and the report files."""

    rows: list[dict]
    summary: dict
    outdir: Path
    files: list[Path] = field(default_factory=list)

    @property
    def failed(self) -> list[dict]:
        return [r for r in self.rows if r["status"] == "failed"]


def is_done(rec: dict | None, config: str, outdir: Path) -> bool:
    """Whether manifest record ``rec`` says its asset is done with settings ``config`` (a
    fingerprint) and its files are still under ``outdir`` (a folder output appears whole or not
    at all, so its files there are all of it)."""
    return (rec is not None and rec.get("status") == "done" and rec.get("config") == config
            and all((outdir / f).is_file() for f in rec.get("files") or ()))


def report_row(asset: Asset, rec: dict | None, outdir: Path) -> dict:
    """The report row (:data:`COLUMNS`) of ``asset``, whose latest record is ``rec`` (None:
    pending)."""
    row = {c: "" for c in COLUMNS}
    row.update(id=asset.id, path=asset.path, status="pending")
    if rec is not None:
        for c in COLUMNS:
            if c in rec and rec[c] is not None:
                row[c] = rec[c]
    return row


def _mean(values: list[float]) -> float | None:
    vals = [float(v) for v in values if v not in ("", None)]
    return round(sum(vals) / len(vals), 5) if vals else None


def report_summary(rows: list[dict], finished: int, skipped: int, wall: float, startup: float | None,
                   engine: str, jobs: int | None, opts: BatchOptions, config: str, out: Path) -> dict:
    """The summary of a batch's report: counts of ``rows`` by status, this run's wall time and
    rate, means over the done assets, and the run's settings."""
    done = [r for r in rows if r["status"] == "done"]
    return {
        "assets": len(rows),
        "done": len(done),
        "failed": sum(r["status"] == "failed" for r in rows),
        "pending": sum(r["status"] == "pending" for r in rows),
        "skipped": skipped,
        "run": finished,
        "wall_seconds": round(wall, 3),
        "assets_per_minute": round(60.0 * finished / wall, 3) if finished and wall > 0 else None,
        "startup_seconds": round(startup, 3) if startup is not None else None,
        "mean_hulls": _mean([r["hulls"] for r in done]),
        "mean_max_concavity": _mean([r["max_concavity"] for r in done]),
        "mean_seconds": _mean([r["seconds"] for r in done]),
        "mean_cpu_seconds": _mean([r["cpu_seconds"] for r in done]),
        "max_peak_mb": max((float(r["peak_mb"]) for r in done if r["peak_mb"] not in ("", None)),
                           default=None),
        "engine": engine,
        "jobs": jobs,
        "threads": opts.threads,
        "config": config,
        "outdir": str(out),
    }


def write_reports(outdir: Path, rows: list[dict], summary: dict) -> list[Path]:
    """Write (atomically) :data:`REPORT_CSV` and :data:`REPORT_JSON` under ``outdir``; returns
    their paths."""
    from ...io.files import atomic_path

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for r in rows:
        w.writerow(["" if r.get(c) is None else r.get(c) for c in COLUMNS])
    out = []
    for name, text in ((REPORT_CSV, buf.getvalue()),
                       (REPORT_JSON, json.dumps({"summary": summary, "assets": rows}, indent=1,
                                                default=_json_default) + "\n")):
        with atomic_path(outdir / name) as tmp:
            tmp.write_text(text)
        out.append(outdir / name)
    return out
