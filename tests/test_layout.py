"""The house: the package tree reads as the pipeline. No import circles, no stage importing a later
one, no private name imported across modules, small modules that say what they hold."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from conftest import ROOT

PACKAGE = ROOT / "pointcvx"
MAX_LINES = 700

#: Stages, lowest first: a module may import its own stage and the ones below, never above.
STAGES = [
    ("errors", "version", "options", "flags", "syslibs", "progress", "embree", "deadline", "workers"),
    ("cloud",),
    ("scene",),
    ("io",),
    ("solid",),
    ("features", "training", "model"),
    ("decomposition",),
    ("result", "export"),
    ("pipeline", "evaluate", "view"),
    ("apps",),
    ("cli", "__main__", "__init__"),
]
RANK = {name: i for i, names in enumerate(STAGES) for name in names}


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(ROOT).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _resolve(module: str, path: Path, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(module: str) -> list[tuple[str, str]]:
    """(imported module, imported name or '') of every import of ``module``, functions included."""
    path = MODULES[module]
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [(a.name, "") for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(module, path, node)
            for a in node.names:
                sub = f"{target}.{a.name}"
                out.append((sub, "") if sub in MODULES else (target, a.name))
    return [(m, n) for m, n in out if m == "pointcvx" or m.startswith("pointcvx.")]


def _stage(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_no_import_circles():
    graph = {m: {t for t, _ in _imports(m) if t in MODULES and t != m} for m in MODULES}
    # a package's __init__ re-exporting its own modules is not a circle with them
    graph = {m: {t for t in ts if not m.startswith(t + ".")} for m, ts in graph.items()}
    state: dict[str, int] = {}

    def visit(m: str, trail: list[str]) -> None:
        state[m] = 1
        for t in sorted(graph[m]):
            if state.get(t) == 1:
                raise AssertionError("import circle: " + " -> ".join(trail[trail.index(t):] + [t]))
            if t not in state:
                visit(t, trail + [t])
        state[m] = 2

    for m in sorted(MODULES):
        if m not in state:
            visit(m, [m])


def test_no_stage_imports_a_later_one():
    bad = []
    for m in MODULES:
        mine = RANK[_stage(m)]
        for target, _ in _imports(m):
            if target == "pointcvx":
                if _stage(m) not in ("cli", "__main__", "__init__"):
                    bad.append(f"{m} imports the package face")
                continue
            if RANK[_stage(target)] > mine:
                bad.append(f"{m} -> {target}")
    assert not bad, bad


def test_no_private_name_is_imported_from_another_module():
    bad = [f"{m}: {t}.{n}" for m in MODULES for t, n in _imports(m)
           if n.startswith("_") and not n.endswith("__")]
    bad += [f"{m}: {t}" for m in MODULES for t, _ in _imports(m) if t.split(".")[-1].startswith("_")
            and not t.endswith("__init__") and t.split(".")[-1] != "__main__"]
    assert not bad, bad


@pytest.mark.parametrize("module", sorted(MODULES))
def test_modules_are_small_and_say_what_they_hold(module):
    path = MODULES[module]
    text = path.read_text()
    assert len(text.splitlines()) <= MAX_LINES, f"{module}: {len(text.splitlines())} lines"
    doc = ast.get_docstring(ast.parse(text))
    if path.name == "__main__.py" or (path.name == "__init__.py" and not text.strip()):
        return
    assert doc and doc.splitlines()[0].strip(), f"{module} has no docstring naming what it holds"


def test_tests_do_not_import_other_test_modules_private_helpers():
    bad = []
    for path in sorted((ROOT / "tests").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("test_"):
                bad.append(f"{path.name} imports from {node.module}")
    assert not bad, bad
