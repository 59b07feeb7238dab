"""Shared fixtures: the read-only shape data beside the checkout, and the bundled samples."""

from __future__ import annotations

from pathlib import Path

import pytest

import pointcvx  # noqa: F401 - first: makes open3d's libusb loadable for tests that import open3d

ROOT = Path(__file__).resolve().parents[1]
DATA = (ROOT / ".." / "shared" / "data").resolve()
SAMPLES = ROOT / "io"


def load_tool(name: str):
    """The module ``tools/NAME.py`` (tools are scripts, not a package), loaded once per session."""
    import importlib.util
    import sys

    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, ROOT / "tools" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


def dev_files(category: str | None = None) -> list[Path]:
    """Every file of ``shared/data/dev`` (or one category of it), sorted."""
    base = DATA / "dev"
    folders = [base / category] if category else sorted(p for p in base.iterdir() if p.is_dir())
    return sorted(f for d in folders for f in d.iterdir() if f.is_file())


def collision_vertices(model, data, body: int | None = None):
    """(n, 3) float: every vertex of every collision geom (group 3) of a MuJoCo model, or of one
    ``body`` (its id), in world coordinates, in a fixed order: where the objects' surfaces are,
    whatever frame their bodies have."""
    import numpy as np

    out = []
    for g in np.flatnonzero(model.geom_group == 3):
        if body is not None and model.geom_bodyid[g] != body:
            continue
        mesh = model.geom_dataid[g]
        start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        local = model.mesh_vert[start:start + count]
        out.append(local @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g])
    return np.concatenate(out)


def largest_move(model, data, start, body: int | None = None) -> float:
    """How far the collision vertex that moved most (of all, or of ``body``) is from where it was
    in ``start`` (:func:`collision_vertices` then), in model units."""
    import numpy as np

    return float(np.linalg.norm(collision_vertices(model, data, body) - start, axis=1).max())


@pytest.fixture(scope="session")
def data_dir() -> Path:
    if not DATA.is_dir():
        raise FileNotFoundError(f"shared data not found at {DATA}")
    return DATA


@pytest.fixture(scope="session")
def source(tmp_path_factory) -> Path:
    """A torus written as OBJ (the export tests' input)."""
    from shapes import torus

    path = tmp_path_factory.mktemp("input") / "torus.obj"
    torus().export(path)
    return path


@pytest.fixture(scope="session")
def result(source):
    """The torus decomposed with the bundled model (3,000 points, seed 0): hulls of about 200
    vertices each."""

    return pointcvx.decompose(source, features="model", n_points=3000, seed=0)
