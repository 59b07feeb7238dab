"""The notebooks in notebooks/ run top to bottom on the bundled samples (each code cell executed in
order, in one namespace, from the notebooks folder, as Jupyter would), and are stored clean."""

from __future__ import annotations

import json

import pytest

from conftest import ROOT

NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


def test_the_promised_notebooks_exist():
    assert {p.stem for p in NOTEBOOKS} >= {"quickstart_splat", "feature_fields", "scan_pipeline"}


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs_top_to_bottom(path, monkeypatch, tmp_path):
    book = json.loads(path.read_text())
    cells = [c for c in book["cells"] if c["cell_type"] == "code"]
    assert cells
    # Stored without outputs, so diffs stay readable and nothing stale is shown.
    assert all(not c.get("outputs") and c.get("execution_count") is None for c in cells)
    monkeypatch.chdir(path.parent)
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    namespace: dict = {"__name__": "__main__"}
    for i, cell in enumerate(cells):
        source = "".join(cell["source"])
        exec(compile(source, f"{path.name}[cell {i}]", "exec"), namespace)  # noqa: S102
