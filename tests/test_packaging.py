"""Packaging: README's two commands, CI wiring, and a real install of the package into a fresh
virtual environment (dependencies borrowed from the running environment, so no network)."""

from __future__ import annotations

import json
import re
import site
import subprocess
import sys
import venv
from pathlib import Path

from conftest import ROOT


def _readme_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"<!-- (\w[\w-]*) -->\s*```(?:bash|sh)?\n(.*?)```", text, re.S)
    return {name: body.strip() for name, body in blocks}


def test_readme_gives_exactly_two_setup_commands():
    cmds = _readme_commands()
    assert set(cmds) == {"main-command", "test-command"}
    for body in cmds.values():
        assert len(body.splitlines()) == 1
        assert "pip install torch==2.13.0" in body
    assert "pointcvx " in cmds["main-command"] and "io/" in cmds["main-command"]
    assert "pytest" in cmds["test-command"]


def test_ci_runs_the_readme_commands_the_main_one_before_any_system_package():
    ci = (ROOT / ".ci" / "run").read_text()
    assert "readme_block main-command" in ci and "readme_block test-command" in ci
    main_run, apt = ci.index('bash -euo pipefail -c "$main_cmd"'), ci.index("apt-get install")
    assert main_run < apt and ci.index('bash -euo pipefail -c "$test_cmd"') > apt
    assert "libusb" not in ci[apt:ci.index("\n", apt)]  # the tests, too, run on the bundled copy
    assert "ruff check" in ci


def test_fresh_venv_install_runs_the_cli(tmp_path):
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    py = env_dir / "bin" / "python"
    child_site = subprocess.run([py, "-c", "import site; print(site.getsitepackages()[0])"],
                                capture_output=True, text=True, check=True).stdout.strip()
    # Dependencies come from this environment; pointcvx itself is installed for real.
    parents = [p for p in site.getsitepackages() if p != child_site]
    with open(f"{child_site}/zz_parent_deps.pth", "w") as f:
        f.write("\n".join(parents) + "\n")
    res = subprocess.run(
        # Build isolation fetches the build backend (setuptools) from the package index.
        [py, "-m", "pip", "install", "--no-deps", "-q", str(ROOT)],
        capture_output=True, text=True, timeout=600,
    )
    assert res.returncode == 0, res.stderr[-2000:]
    exe = env_dir / "bin" / "pointcvx"
    where = subprocess.run([py, "-c", "import pointcvx; print(pointcvx.__file__)"], cwd=tmp_path,
                           capture_output=True, text=True, check=True).stdout
    assert str(env_dir) in where  # the installed copy, not the source tree
    res = subprocess.run([exe, "info", str(ROOT / "io" / "mug.obj"), "--json", "-n", "1000"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["points"] == 1000
    assert sys.executable != str(py)
    # the trained model ships inside the installed package and is used offline
    shipped = Path(where.strip()).parent / "data" / "model_small.pt"
    assert shipped.is_file() and shipped.stat().st_size <= 25e6
    res = subprocess.run([exe, "decompose", str(ROOT / "io" / "mug.obj"), "--features", "model",
                          "-n", "3000", "-t", "0.2", "-k", "8", "--json", "-o", str(tmp_path / "h.obj")],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert 1 <= json.loads(res.stdout)["hulls"] <= 8 and (tmp_path / "h.obj").is_file()
