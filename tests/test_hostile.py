"""Hostile input: the generated corpus of ``tools/hostile_corpus.py`` through the API and the CLI.

Every fast member (over 200 files across every format) is loaded by ``pointcvx.load`` in child
processes capped at ``MEMORY_BYTES`` of address space and ``INFO_SECONDS`` per file: each must
give a cloud with finite values or a :class:`pointcvx.PointcvxError` (no other exception, no
``MemoryError``, no numpy warning), and members that name their outcome must give it. A sample
of members then goes through the real ``pointcvx`` command under the same memory bound: exit 0,
1 or 2, at most one line on stderr, no traceback. The slow members (big files) run with
``python tools/hostile_corpus.py --run --all OUT`` (docs/hostile_input.md).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import pointcvx
from conftest import load_tool
from pointcvx.errors import InputError

H = load_tool("hostile_corpus")

#: Members run through the real command (tests/test_cli.py runs a FIFO, NaN and huge counts and
#: coordinates that way too): a bomb, a huge declared count, a path trick, a load with a warning.
CLI_SAMPLE = ["spz-bomb-3gib.spz", "ply-vertex-1e12-ascii.ply", "sub/gltf-uri-dotdot.gltf",
              "splat-log-scale-80-some.ply"]
DECOMPOSE_SAMPLE = ["pcd-binary-organised-nan.pcd"]


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    out = tmp_path_factory.mktemp("hostile")
    return out, {m.name: m for m in H.build(out)}


def test_corpus_covers_every_format_many_ways(corpus):
    _, members = corpus
    assert len(members) > 200
    suffixes = {name.rsplit(".", 1)[-1] for name in members}
    assert {"obj", "ply", "stl", "off", "glb", "gltf", "pcd", "xyz", "pts", "las", "laz", "spz", "splat",
            "step", "bin"} <= suffixes
    for kind in ("-cut-", "-random-body", "-nan", "-1e154", "1e12", "bomb", "uri-dotdot", "fifo"):
        assert any(kind in name for name in members), kind


def test_every_member_loads_or_fails_cleanly(corpus):
    out, members = corpus
    rows = H.run_api([out / name for name in members])
    found = {name: H.problems(m, api=rows[str(out / name)]) for name, m in members.items()}
    bad = {name: p for name, p in found.items() if p}
    assert not bad, json.dumps(bad, indent=1)[:4000]
    # the valid files load, the bombs are refused without inflating
    assert rows[str(out / "ok.laz")]["outcome"] == "ok" and rows[str(out / "ok-v4.spz")]["outcome"] == "ok"
    bomb = rows[str(out / "spz-bomb-3gib.spz")]
    assert bomb["peak_mb"] < 1500 and bomb["seconds"] < 10


def test_the_command_on_hostile_files_exits_cleanly(corpus):
    out, members = corpus
    bad = {}
    for name in CLI_SAMPLE:
        res = H.run_cli(["info", str(out / name)], H.INFO_SECONDS)
        found = H.problems(members[name], cli=res)
        if members[name].expect is not None and res["rc"] != (0 if members[name].expect == "ok" else 1):
            found.append(f"exit {res['rc']} for a member expected to give {members[name].expect}")
        if found:
            bad[name] = found
    for name in DECOMPOSE_SAMPLE:
        res = H.run_cli(["decompose", str(out / name), *H.DECOMPOSE_ARGS, "-o", str(out / "hulls.obj")],
                        H.DECOMPOSE_SECONDS)
        if H.problems(members[name], cli=res) or res["rc"] != 0:
            bad[name] = [*H.problems(members[name], cli=res), f"exit {res['rc']}"]
    assert not bad, bad


# ------------------------------------------------------------------- the API's own inputs
@pytest.mark.parametrize("array", [
    np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=object),
    np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=complex),
    np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=bool),
    np.array([["0", "0", "0"]] * 4),
    [[0, 0, 0], [1, 0], [0, 1, 0], [0, 0, 1]],
    np.full((50, 3), 1e154) * np.arange(50)[:, None],
], ids=["object", "complex", "bool", "string", "ragged", "1e154"])
def test_arrays_that_are_not_real_coordinates_are_input_errors(array):
    with pytest.raises(InputError, match="real numbers|array of numbers|beyond"):
        pointcvx.decompose(array, features="model", n_points=500)


def test_deeply_nested_json_manifest_is_an_input_error(tmp_path):
    from pointcvx.apps.batch.assets import read_manifest_file

    manifest = tmp_path / "list.json"
    manifest.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(InputError, match="nested too deeply"):
        read_manifest_file(manifest)
