"""Options declared once: the API, ``decompose``, ``batch``, ``bench`` and ``info`` take the same
names with the same checks; bad values are InputError in the API and exit status 2 on the CLI."""

from __future__ import annotations

import argparse
import inspect
from dataclasses import fields

import numpy as np
import pytest

import pointcvx
from conftest import ROOT
from pointcvx.cli import build_parser, main
from pointcvx.errors import EXIT_USAGE, InputError
from pointcvx.options import (
    DECOMPOSE_POINTS,
    ENGINE_TARGETS,
    DecomposeOptions,
    LoadOptions,
    spec_of,
    split_kwargs,
)

MUG = str(ROOT / "io" / "mug.obj")


def _subparser(command: str) -> argparse.ArgumentParser:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices[command]


def _flags(command: str) -> dict[str, argparse.Action]:
    return {a.dest: a for a in _subparser(command)._actions}


@pytest.mark.parametrize("command", ["decompose", "batch", "bench"])
def test_every_decomposition_and_loading_option_is_a_flag_of_each_command(command):
    actions = _flags(command)
    for options in (DecomposeOptions, LoadOptions):
        for f in fields(options):
            spec = spec_of(f)
            if spec.flag is None:
                continue
            if f.name == "timeout" and command in ("batch", "bench"):
                # their own --timeout bounds each asset's or run's whole process
                assert actions["timeout"].default == 600.0
                continue
            assert f.name in actions, f"{command} lacks the flag of {f.name}"
            action = actions[f.name]
            want = DECOMPOSE_POINTS if f.name == "n_points" else f.default
            assert action.default == want, (command, f.name)
            long = spec.flag if spec.kind is not bool or not f.default else f"--no-{spec.flag[2:]}"
            assert long in action.option_strings


def test_info_takes_the_loading_options_with_their_declared_defaults():
    actions = _flags("info")
    for f in fields(LoadOptions):
        if spec_of(f).flag is not None:
            assert actions[f.name].default == f.default


def test_decompose_signature_lists_every_option():
    sig = inspect.signature(pointcvx.decompose)
    names = set(sig.parameters) - {"x", "progress"}
    assert names == set(DecomposeOptions.names()) | set(LoadOptions.names())
    assert sig.parameters["n_points"].default == DECOMPOSE_POINTS
    assert sig.parameters["threshold"].default == DecomposeOptions().threshold


# (option, bad value given to the API, the same value as command-line text, message fragment)
BAD = [
    ("threshold", 0.0, "0", "threshold must be positive, got 0.0"),
    ("threshold", float("nan"), "nan", "threshold must be finite"),
    ("max_hulls", 0, "0", "max_hulls must be at least 1, got 0"),
    ("views", -2, "-2", "views must be at least 1"),
    ("features", "best", "best", "unknown features 'best'"),
    ("split", "random", "random", "unknown split 'random'"),
    ("target", "havok", "havok", "unknown target 'havok'"),
    ("max_hull_vertices", 3, "3", "max_hull_vertices must be at least 4"),
    ("subsurface", -0.1, "-0.1", "subsurface must be positive"),
    ("blend", -1.0, "-1", "blend must be at least 0"),
    ("seed", -1, "-1", "seed must be in [0, 4.29497e+09], got -1"),
    ("n_points", 3, "3", "n_points must be at least 4"),
    ("min_opacity", 1.0, "1", "min_opacity must be in [0, 1)"),
    ("outlier_std", -3.0, "-3", "outlier_std must be positive"),
    ("outlier_std", float("nan"), "nan", "outlier_std must be finite"),
    ("voxel_size", 0.0, "0", "voxel_size must be positive"),
    ("cad_mesh_size", 2.0, "2", "cad_mesh_size must be in (0, 1]"),
]


def _flag(name: str) -> str:
    for options in (DecomposeOptions, LoadOptions):
        for f in fields(options):
            if f.name == name:
                return spec_of(f).flag
    raise KeyError(name)


@pytest.mark.parametrize("name, value, text, message", BAD)
def test_bad_values_are_the_same_error_in_the_api_and_usage_errors_on_every_command(
        name, value, text, message, tmp_path, capsys):
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")
                       .replace("[", r"\[").replace("]", r"\]").replace("+", r"\+")):
        pointcvx.decompose(MUG, **{name: value})
    for argv in (["decompose", MUG], ["batch", MUG, "-o", str(tmp_path / "b")],
                 ["bench", MUG, "-o", str(tmp_path / "c")]):
        with pytest.raises(SystemExit) as info:
            main([*argv, _flag(name), text])
        assert info.value.code == EXIT_USAGE
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and message in err, (argv[0], err)
    assert not (tmp_path / "b").exists() and not (tmp_path / "c").exists()


@pytest.mark.parametrize("kwargs, fragment", [
    ({"seed": "1"}, "seed must be an integer"),
    ({"seed": b"1"}, "seed must be an integer"),
    ({"seed": 1.5}, "seed must be an integer"),
    ({"max_hulls": True}, "max_hulls must be an integer"),
    ({"threshold": "0.1"}, "threshold must be a number"),
    ({"threshold": 1 + 2j}, "threshold must be a number"),
    ({"merge": 1}, "merge must be True or False"),
    ({"features": 3}, "features must be a string"),
    ({"model": 3}, "model must be a path"),
    ({"progress": False}, "progress must be a callable"),
])
def test_wrong_types_are_input_errors(kwargs, fragment):
    with pytest.raises(InputError, match=fragment):
        pointcvx.decompose(MUG, **kwargs)


def test_numpy_scalars_and_paths_are_taken():
    opts = DecomposeOptions(threshold=np.float32(0.2), max_hulls=np.int64(3), model=ROOT / "x.pt")
    assert opts.threshold == pytest.approx(0.2) and type(opts.threshold) is float
    assert opts.max_hulls == 3 and type(opts.max_hulls) is int
    assert opts.model == str(ROOT / "x.pt")
    assert LoadOptions(seed=np.uint32(7), normalize=np.bool_(False)).seed == 7


def test_unknown_names_are_type_errors():
    with pytest.raises(TypeError, match="unknown option"):
        pointcvx.decompose(MUG, treshold=0.1)
    with pytest.raises(TypeError, match="unknown load option"):
        pointcvx.load(MUG, treshold=0.1)
    assert split_kwargs({"threshold": 0.2, "seed": 1}) == ({"threshold": 0.2}, {"seed": 1})


def test_changed_lists_only_what_differs():
    assert DecomposeOptions().changed() == {}
    assert DecomposeOptions(max_hulls=8, threshold=0.1).changed() == {"max_hulls": 8}


def test_engine_targets_name_the_caps_table():
    from pointcvx.decomposition.limits import TARGETS

    assert tuple(TARGETS) == ENGINE_TARGETS


def test_batch_and_bench_options_are_made_from_the_same_declarations():
    from pointcvx.apps.batch import BatchOptions
    from pointcvx.apps.bench import BenchOptions

    b = BatchOptions.create(features="model", n_points=3000, max_hulls=8, timeout=30)
    assert b.decompose == DecomposeOptions(features="model", max_hulls=8)
    assert b.load == LoadOptions(n_points=3000) and b.timeout == 30
    assert BatchOptions.from_dict(b.to_dict()) == b
    c = BenchOptions.create(methods=("pointcvx",), seed=4, split="ward")
    assert c.decompose.split == "ward" and c.seed == 4 and c.load.n_points == DECOMPOSE_POINTS
    assert BenchOptions.from_dict(c.to_dict()) == c
    with pytest.raises(InputError, match="max_hulls must be at least 1"):
        BatchOptions.create(max_hulls=0)
    with pytest.raises(TypeError):
        BenchOptions.create(treshold=0.1)


def test_a_threshold_can_be_a_length_in_the_inputs_units():
    """5 mm on a mesh in metres whose longest half-side is s: 0.005 / s in the normalised frame;
    with the coordinates read as centimetres the mug is a hundredth the size, so the same 5 mm is
    a hundred times coarser."""
    from pointcvx.options import parse_length

    assert parse_length("5mm") == pytest.approx(0.005) and parse_length("0.5 in") == pytest.approx(0.0127)
    fine = pointcvx.decompose(MUG, threshold="5mm", features="model", n_points=2000, max_hulls=4)
    scale = fine.cloud.normalization.scale
    assert fine.params["threshold"] == pytest.approx(0.005 / scale)
    assert fine.params["threshold_given"] == "5mm" and fine.params["units"] == "m"
    coarse = pointcvx.decompose(MUG, threshold="5mm", units="cm", features="model", n_points=2000,
                                max_hulls=4)
    assert coarse.params["threshold"] == pytest.approx(0.5 / scale) and coarse.params["units"] == "cm"
    with pytest.raises(InputError, match="length with a unit"):
        pointcvx.decompose(MUG, threshold="5 parsecs")
    with pytest.raises(InputError, match="threshold must be positive"):
        pointcvx.decompose(MUG, threshold="-1mm")


def test_length_thresholds_on_the_command_line(tmp_path, capsys):
    args = _subparser("decompose").parse_args([MUG, "-t", "2.5cm", "--units", "mm"])
    assert args.threshold == "2.5cm" and args.units == "mm"
    assert _subparser("decompose").parse_args([MUG, "-t", "0.2"]).threshold == 0.2
    with pytest.raises(SystemExit) as info:
        main(["decompose", MUG, "-t", "2furlongs"])
    assert info.value.code == EXIT_USAGE and "length with a unit" in capsys.readouterr().err
    assert main(["bench", MUG, "-o", str(tmp_path / "b"), "-t", "5mm"]) == 1
    assert "normalised" in capsys.readouterr().err and not (tmp_path / "b").exists()
