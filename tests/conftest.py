"""Shared fixtures: the read-only shape data beside the checkout, and the bundled samples."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = (ROOT / ".." / "shared" / "data").resolve()
SAMPLES = ROOT / "io"


def dev_files(category: str | None = None) -> list[Path]:
    """Every file of ``shared/data/dev`` (or one category of it), sorted."""
    base = DATA / "dev"
    folders = [base / category] if category else sorted(p for p in base.iterdir() if p.is_dir())
    return sorted(f for d in folders for f in d.iterdir() if f.is_file())


@pytest.fixture(scope="session")
def data_dir() -> Path:
    if not DATA.is_dir():
        raise FileNotFoundError(f"shared data not found at {DATA}")
    return DATA
