"""Small bad inputs written on demand (one per way a file can be unusable), shared by the CLI and
API tests: name -> (path, a fragment of the expected one-line error)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from conftest import DATA, ROOT


def bad_inputs(tmp: str) -> dict[str, tuple[str, str]]:
    """name -> (path, expected message fragment), written into ``tmp``."""
    tmp = Path(tmp)
    cases = {}
    cases["missing"] = (str(tmp / "nope.ply"), "no such file")
    (tmp / "empty.obj").write_bytes(b"")
    cases["empty"] = (str(tmp / "empty.obj"), "empty")
    data = (ROOT / "io" / "mug_splat.ply").read_bytes()
    (tmp / "truncated.ply").write_bytes(data[: len(data) // 2])
    cases["truncated ply"] = (str(tmp / "truncated.ply"), "truncated or corrupted PLY")
    mesh_ply = (DATA / "dev/objects/ant.ply").read_bytes()
    (tmp / "truncated_mesh.ply").write_bytes(mesh_ply[: len(mesh_ply) * 2 // 3])
    cases["truncated mesh ply"] = (str(tmp / "truncated_mesh.ply"), "PLY")
    (tmp / "corrupt.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 10\n")
    cases["corrupted ply"] = (str(tmp / "corrupt.ply"), "header never ends")
    (tmp / "novert.ply").write_bytes(
        b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
        b"property float z\nend_header\n")
    cases["no vertices"] = (str(tmp / "novert.ply"), "no vertices")
    # NaN rows of a scan are dropped ("no measurement"): an error only with fewer than 4 finite left
    (tmp / "nan.xyz").write_text("0 0 0\n1 0 0\n0 1 0\nnan 0 1\n0 0 nan\n")
    cases["nan"] = (str(tmp / "nan.xyz"), "only 3 of 5 points are usable (2 NaN or infinite)")
    (tmp / "inf.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 inf 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\n")
    cases["inf"] = (str(tmp / "inf.obj"), "infinite")
    (tmp / "same.xyz").write_text("1 2 3\n" * 20)
    cases["identical"] = (str(tmp / "same.xyz"), "identical")
    (tmp / "line.xyz").write_text("".join(f"{t} {2 * t} {3 * t}\n" for t in range(20)))
    cases["collinear"] = (str(tmp / "line.xyz"), "collinear")
    (tmp / "noise.bin").write_bytes(np.random.default_rng(0).bytes(5000))
    cases["unknown"] = (str(tmp / "noise.bin"), "unknown format")
    (tmp / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nf 1 2 3\nf 2 3 4\n")
    cases["degenerate faces"] = (str(tmp / "flat.obj"), "degenerate")
    os.mkfifo(tmp / "pipe.ply")
    cases["fifo"] = (str(tmp / "pipe.ply"), "not a regular file but a FIFO")
    (tmp / "many.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000\n"
                                   b"property float x\nproperty float y\nproperty float z\nend_header\n"
                                   + bytes(36))
    cases["huge count"] = (str(tmp / "many.ply"), "declares 1000000000000 vertices")
    (tmp / "count.stl").write_bytes(bytes(80) + (7).to_bytes(4, "little") + bytes(50 * 5))
    cases["stl count"] = (str(tmp / "count.stl"), "truncated or corrupted binary STL")
    (tmp / "far.obj").write_text("v 0 0 0\nv 1e154 0 0\nv 0 1e154 0\nv 0 0 1e154\nf 1 2 3\nf 1 3 4\n")
    cases["huge coordinates"] = (str(tmp / "far.obj"), "beyond 1e+10")
    (tmp / "zero.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 0 3 4\n")
    cases["obj index 0"] = (str(tmp / "zero.obj"), "line 6 has a face with vertex index 0")
    return cases


CASES = ["missing", "empty", "truncated ply", "truncated mesh ply", "corrupted ply", "no vertices",
         "nan", "inf", "identical", "collinear", "unknown", "degenerate faces", "fifo", "huge count",
         "stl count", "huge coordinates", "obj index 0"]
