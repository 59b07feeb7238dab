"""A generated corpus of hostile inputs for the loaders, and a runner that feeds it to pointcvx.

Every format pointcvx reads, broken every way a careless tool or an adversary would break it:
empty, truncated at several offsets, valid headers over random bodies, NaN/inf in every field,
huge and tiny coordinates, declared counts far above what the file holds, decompression bombs,
glTF URIs pointing outside, a FIFO, a directory, a file named like another format. Valid files
of every format are in it too (they must keep loading).

    python tools/hostile_corpus.py OUT                  # write the fast members into OUT
    python tools/hostile_corpus.py --all OUT            # ... and the slow ones (big files)
    python tools/hostile_corpus.py --run [--all] OUT    # write, then run every member through
                                                        # `pointcvx info` and `pointcvx decompose`
    python tools/hostile_corpus.py --run --api-only OUT  # only `pointcvx.load`, many files a process
    python tools/hostile_corpus.py --run --all --slow-only OUT   # only the slow members

The rule every member is held to (:func:`problems`): the command exits 0, 1 or 2 within its time
bound (:data:`INFO_SECONDS`, :data:`DECOMPOSE_SECONDS`) under an address-space limit
(:data:`MEMORY_BYTES`), prints at most one line on stderr and never a traceback; with the API,
``pointcvx.load`` returns a cloud or raises a :class:`pointcvx.PointcvxError` (never another
exception, never ``MemoryError``). Members may also name what they must give (``expect``: ``ok``,
``error`` and an optional message fragment). ``tests/test_hostile.py`` runs the fast members.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import gzip
import json
import os
import queue
import resource
import shutil
import struct
import subprocess
import sys
import tempfile
import threading
import time
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: Address-space limit of every process the runner starts (the libraries alone map about 2 GiB).
MEMORY_BYTES = 6 << 30
#: Wall-clock bound of one `pointcvx info` run, and of one file loaded by the API runner.
INFO_SECONDS = 60
#: Wall-clock bound of one `pointcvx decompose` run (small settings, :data:`DECOMPOSE_ARGS`).
DECOMPOSE_SECONDS = 180
DECOMPOSE_ARGS = ("-n", "2000", "-k", "4", "--features", "model", "-q")
GiB = 1 << 30


@dataclass(frozen=True)
class Member:
    """One file of the corpus: its name (also its file name), what it must give, whether it is slow."""

    name: str
    expect: str | None = None  # "ok", "error" or None (either, as long as it is clean)
    fragment: str | None = None  # with "error": a piece of the message (case-insensitive)
    slow: bool = False


# ------------------------------------------------------------------------------------ base shapes
def sphere(n: int = 600, seed: int = 0) -> np.ndarray:
    """(n, 3) float points on a slightly noisy unit sphere."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    return p * (1.0 + 0.01 * rng.normal(size=(n, 1)))


def mesh():
    import trimesh

    return trimesh.creation.icosphere(subdivisions=2)


def gaussians(n: int = 600, seed: int = 0) -> dict[str, np.ndarray]:
    """Flat Gaussians on a unit sphere: centres, linear scales, (w, x, y, z) rotations, opacity, colours."""
    rng = np.random.default_rng(seed)
    c = sphere(n, seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    s = np.stack([rng.uniform(0.03, 0.05, n), rng.uniform(0.03, 0.05, n), np.full(n, 0.003)], axis=1)
    return {
        "centers": c,
        "scales": s,
        "rotations": q,
        "opacity": rng.uniform(0.6, 0.95, n),
        "colors": rng.uniform(0, 1, (n, 3)),
    }


def ply_bytes(
    columns: dict[str, np.ndarray],
    fmt: str = "binary_little_endian",
    dtype: str = "f4",
    count: int | None = None,
    extra_elements: str = "",
    faces: np.ndarray | None = None,
) -> bytes:
    """A PLY with one vertex element of float columns (``count`` overrides the declared count)."""
    n = len(next(iter(columns.values())))
    kind = {"f4": "float", "f8": "double"}[dtype]
    head = ["ply", f"format {fmt} 1.0", f"element vertex {n if count is None else count}"]
    head += [f"property {kind} {name}" for name in columns]
    if faces is not None:
        head += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    head += [extra_elements.rstrip("\n")] if extra_elements else []
    head += ["end_header"]
    header = ("\n".join(head) + "\n").encode()
    table = np.stack([np.asarray(v, dtype=np.float64) for v in columns.values()], axis=1)
    if fmt == "ascii":
        body = "".join(" ".join(repr(float(x)) for x in row) + "\n" for row in table)
        if faces is not None:
            body += "".join(f"3 {a} {b} {c}\n" for a, b, c in faces)
        return header + body.encode()
    body = table.astype("<" + dtype).tobytes()
    if faces is not None:
        rec = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
        rec["n"], rec["v"] = 3, faces
        body += rec.tobytes()
    return header + body


def inria_columns(g: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The INRIA 3DGS property columns of Gaussians ``g`` (log scales, logit opacity, f_dc)."""
    cols = {"x": g["centers"][:, 0], "y": g["centers"][:, 1], "z": g["centers"][:, 2]}
    f_dc = (g["colors"] - 0.5) / 0.28209479177387814
    cols.update({f"f_dc_{i}": f_dc[:, i] for i in range(3)})
    cols["opacity"] = np.log(g["opacity"] / (1 - g["opacity"]))
    cols.update({f"scale_{i}": np.log(g["scales"][:, i]) for i in range(3)})
    cols.update({f"rot_{i}": g["rotations"][:, i] for i in range(4)})
    return cols


def compressed_ply(g: dict[str, np.ndarray], chunk_override: dict[str, float] | None = None) -> bytes:
    """A PlayCanvas compressed PLY of Gaussians ``g`` (positions, scales, colour quantised per chunk)."""
    n = len(g["centers"])
    chunks = -(-n // 256)
    names = [
        "min_x",
        "min_y",
        "min_z",
        "max_x",
        "max_y",
        "max_z",
        "min_scale_x",
        "min_scale_y",
        "min_scale_z",
        "max_scale_x",
        "max_scale_y",
        "max_scale_z",
    ]
    chunk = np.zeros((chunks, 12), dtype="<f4")
    packed = np.zeros((n, 4), dtype="<u4")
    logs = np.log(g["scales"])
    for c in range(chunks):
        sl = slice(256 * c, 256 * (c + 1))
        lo, hi = g["centers"][sl].min(0), g["centers"][sl].max(0) + 1e-6
        slo, shi = logs[sl].min(0), logs[sl].max(0) + 1e-6
        chunk[c] = np.r_[lo, hi, slo, shi]
        for col, values, vlo, vhi in ((0, g["centers"][sl], lo, hi), (2, logs[sl], slo, shi)):
            t = (values - vlo) / (vhi - vlo)
            bits = np.round(t * [2047, 1023, 2047]).astype(np.uint32)
            packed[sl, col] = (bits[:, 0] << 21) | (bits[:, 1] << 11) | bits[:, 2]
    packed[:, 1] = 0x40000000 | (511 << 20) | (511 << 10) | 511  # near-identity rotations
    rgba = np.round(np.c_[g["colors"], g["opacity"]] * 255).astype(np.uint32)
    packed[:, 3] = (rgba[:, 0] << 24) | (rgba[:, 1] << 16) | (rgba[:, 2] << 8) | rgba[:, 3]
    if chunk_override:
        for name, value in chunk_override.items():
            chunk[:, names.index(name)] = value
    head = ["ply", "format binary_little_endian 1.0", f"element chunk {chunks}"]
    head += [f"property float {nm}" for nm in names]
    head += [f"element vertex {n}"] + [
        f"property uint {nm}" for nm in ("packed_position", "packed_rotation", "packed_scale", "packed_color")
    ]
    head += ["end_header"]
    return ("\n".join(head) + "\n").encode() + chunk.tobytes() + packed.tobytes()


def spz_legacy(
    g: dict[str, np.ndarray], version: int = 3, count: int | None = None, degree: int = 0
) -> bytes:
    """An uncompressed SPZ v2/v3 payload (header + arrays) of Gaussians ``g``."""
    n = len(g["centers"])
    fixed = np.round(g["centers"] * 4096).astype(np.int64).reshape(-1)
    pos = np.stack([fixed & 255, (fixed >> 8) & 255, (fixed >> 16) & 255], axis=1).astype(np.uint8)
    alpha = np.round(g["opacity"] * 255).astype(np.uint8)
    color = np.clip(np.round(((g["colors"] - 0.5) / 0.2820948 * 0.15 * 255) + 127.5), 0, 255).astype(np.uint8)
    scale = np.clip(np.round((np.log(g["scales"]) + 10) * 16), 0, 255).astype(np.uint8)
    rot = np.full((n, 4 if version >= 3 else 3), 0, dtype=np.uint8)
    if version < 3:
        rot[:] = 128
    header = struct.pack("<4sIIBBBB", b"NGSP", version, n if count is None else count, degree, 12, 0, 0)
    return header + pos.tobytes() + alpha.tobytes() + color.tobytes() + scale.tobytes() + rot.tobytes()


def spz_v4(g: dict[str, np.ndarray], count: int | None = None, toc: int = 32) -> bytes:
    """An SPZ v4 file (32-byte header, stream table, zstd streams) of Gaussians ``g``."""
    import zstandard

    legacy = spz_legacy(g, version=3)
    n = len(g["centers"])
    sizes = [9 * n, n, 3 * n, 3 * n, 4 * n]
    streams, offset = [], 16
    for size in sizes:
        streams.append(legacy[offset : offset + size])
        offset += size
    packed = [zstandard.ZstdCompressor().compress(s) for s in streams]
    header = struct.pack(
        "<4sIIBBBBI", b"NGSP", 4, n if count is None else count, 0, 12, 0, len(sizes), toc
    ) + bytes(12)
    table = b"".join(struct.pack("<QQ", len(p), s) for p, s in zip(packed, sizes, strict=True))
    return header + bytes(max(0, toc - 32)) + table + b"".join(packed)


def _gf2_times(matrix: list[int], vector: int) -> int:
    out, i = 0, 0
    while vector:
        if vector & 1:
            out ^= matrix[i]
        vector >>= 1
        i += 1
    return out


def crc32_zeros(crc: int, length: int) -> int:
    """``zlib.crc32(bytes(length), crc)`` in O(log length) (zlib's crc32_combine, in Python)."""
    odd = [0xEDB88320] + [1 << i for i in range(31)]  # one zero bit
    even = [_gf2_times(odd, odd[i]) for i in range(32)]  # two zero bits
    odd = [_gf2_times(even, even[i]) for i in range(32)]  # four zero bits
    crc ^= 0xFFFFFFFF
    while length:
        even = [_gf2_times(odd, odd[i]) for i in range(32)]  # doubles the zeros applied per step
        if length & 1:
            crc = _gf2_times(even, crc)
        length >>= 1
        if not length:
            break
        odd = [_gf2_times(even, even[i]) for i in range(32)]
        if length & 1:
            crc = _gf2_times(odd, crc)
        length >>= 1
    return crc ^ 0xFFFFFFFF


def gzip_of_zeros(prefix: bytes, total: int) -> bytes:
    """A valid gzip stream of ``prefix`` followed by zeros up to ``total`` bytes (a few MB per GiB),
    made by repeating one fully flushed deflate segment of 64 MiB of zeros."""
    seg_len = 64 << 20
    c = zlib.compressobj(9, zlib.DEFLATED, -15)
    head = c.compress(prefix) + c.flush(zlib.Z_FULL_FLUSH)
    c2 = zlib.compressobj(9, zlib.DEFLATED, -15)
    seg = c2.compress(bytes(seg_len)) + c2.flush(zlib.Z_FULL_FLUSH)
    reps, rest = divmod(total - len(prefix), seg_len)
    c3 = zlib.compressobj(9, zlib.DEFLATED, -15)
    tail = c3.compress(bytes(rest)) + c3.flush(zlib.Z_FINISH)
    crc = crc32_zeros(zlib.crc32(prefix), total - len(prefix))
    gz_head = b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x02\xff"
    return gz_head + head + seg * reps + tail + struct.pack("<II", crc & 0xFFFFFFFF, total & 0xFFFFFFFF)


def las_bytes(points: np.ndarray, compressed: bool = False) -> bytes:
    import laspy

    header = laspy.LasHeader(point_format=2, version="1.2")
    header.scales = [0.001] * 3
    header.offsets = points.min(axis=0)
    las = laspy.LasData(header)
    las.x, las.y, las.z = points.T
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / ("x.laz" if compressed else "x.las")
        las.write(str(path))
        return path.read_bytes()


def pcd_bytes(
    points: np.ndarray,
    mode: str,
    width: int | None = None,
    height: int = 1,
    count: int | None = None,
    viewpoint: str = "0 0 0 1 0 0 0",
) -> bytes:
    """A PCD v0.7 with float x y z (``width`` x ``height`` organised when given)."""
    n = len(points)
    width = n // height if width is None else width
    head = (
        f"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        f"WIDTH {width}\nHEIGHT {height}\nVIEWPOINT {viewpoint}\nPOINTS {n if count is None else count}\n"
        f"DATA {mode}\n"
    ).encode()
    p = np.asarray(points, dtype="<f4")
    if mode == "ascii":
        return head + "".join(f"{a!r} {b!r} {c!r}\n" for a, b, c in p.tolist()).encode()
    if mode == "binary":
        return head + p.tobytes()
    raw = np.ascontiguousarray(p.T).tobytes()  # field-major, as PCL writes it
    packed = lzf_literals(raw)
    return head + struct.pack("<II", len(packed), len(raw)) + packed


def lzf_literals(raw: bytes) -> bytes:
    """LZF 'compression' with literal runs only (valid for every LZF decoder)."""
    out = bytearray()
    for i in range(0, len(raw), 32):
        chunk = raw[i : i + 32]
        out.append(len(chunk) - 1)
        out += chunk
    return bytes(out)


def glb(gltf: dict, binary: bytes, json_length: int | None = None) -> bytes:
    """A GLB container of the glTF JSON ``gltf`` and one BIN chunk."""
    js = json.dumps(gltf).encode()
    js += b" " * (-len(js) % 4)
    binary += bytes(-len(binary) % 4)
    chunks = struct.pack("<II", len(js) if json_length is None else json_length, 0x4E4F534A) + js
    chunks += struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def gltf_triangle(
    uri: str | None = None,
    count: int = 3,
    offset: int = 0,
    length: int | None = None,
    buffer_length: int | None = None,
) -> tuple[dict, bytes]:
    """A one-triangle glTF (positions and indices in buffer 0) with the given hostile fields."""
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype="<f4").tobytes()
    idx = np.array([0, 1, 2], dtype="<u2").tobytes() + bytes(2)
    data = pos + idx
    buffer = {"byteLength": len(data) if buffer_length is None else buffer_length}
    if uri is not None:
        buffer["uri"] = uri
    gltf = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [buffer],
        "bufferViews": [
            {"buffer": 0, "byteOffset": offset, "byteLength": len(pos) if length is None else length},
            {"buffer": 0, "byteOffset": len(pos), "byteLength": 6},
        ],
        "accessors": [
            {
                "bufferView": 0,
                "componentType": 5126,
                "count": count,
                "type": "VEC3",
                "min": [0, 0, 0],
                "max": [1, 1, 0],
            },
            {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"},
        ],
    }
    return gltf, data


# ------------------------------------------------------------------------------------ the corpus
class Corpus:
    """Collects members while writing their files into ``out``."""

    def __init__(self, out: Path, slow: bool):
        self.out, self.slow = out, slow
        self.members: list[Member] = []
        self.rng = np.random.default_rng(20261201)

    def add(
        self, name: str, data, expect: str | None = None, fragment: str | None = None, slow: bool = False
    ) -> Path:
        """Write member ``name``: ``data`` is bytes, a function making them (slow members: only
        called when they are built), or None for a member made by the caller."""
        path = self.out / name
        if slow and not self.slow:
            return path
        if callable(data):
            data = data()
        if data is not None:
            path.write_bytes(data)
        self.members.append(Member(name, expect, fragment, slow))
        return path

    def cuts(self, stem: str, ext: str, data: bytes, header: int, slow_all: bool = False) -> None:
        """``data`` truncated at several offsets (just inside and past the header, a third, half,
        one byte short) and its header over a random body; more offsets in the slow set."""
        fast = {"h": header, "half": len(data) // 2, "last": len(data) - 1}
        slow = {"1": 1, "4": 4, "hhalf": max(1, header // 2), "h1": header + 1, "third": len(data) // 3}
        for tag, at in fast.items():
            self.add(f"{stem}-cut-{tag}{ext}", data[:at], slow=slow_all)
        for tag, at in slow.items():
            self.add(f"{stem}-cut-{tag}{ext}", data[:at], slow=True)
        body = self.rng.bytes(len(data) - header)
        self.add(f"{stem}-random-body{ext}", data[:header] + body, slow=slow_all)
        for k in range(4):  # bytes flipped past the header, four ways
            flipped = bytearray(data)
            for i in np.random.default_rng([len(data), k]).integers(header, len(data), 4 << k):
                flipped[i] ^= 0xFF
            self.add(f"{stem}-flipped{k}{ext}", bytes(flipped), slow=True)


def build(out: str | os.PathLike, slow: bool = False) -> list[Member]:
    """Write the corpus into ``out`` (created, emptied first) and return its members, fast ones
    first (``slow`` adds the slow members)."""
    out = Path(out)
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    c = Corpus(out, slow)
    _meshes(c)
    _gltf(c)
    _points(c)
    _splats(c)
    _cad(c)
    _filesystem(c)
    return c.members


def _meshes(c: Corpus) -> None:
    m = mesh()
    v, f = np.asarray(m.vertices), np.asarray(m.faces)
    obj = "".join(f"v {a} {b} {d}\n" for a, b, d in v) + "".join(
        f"f {a + 1} {b + 1} {d + 1}\n" for a, b, d in f
    )
    c.add("ok.obj", obj.encode(), "ok")
    c.cuts("obj", ".obj", obj.encode(), 40)
    c.add("obj-face-index-0.obj", (obj + "f 0 1 2\n").encode(), "error", "index 0")
    c.add("obj-face-index-huge.obj", (obj + "f 1 2 99999999999\n").encode(), "error")
    c.add("obj-face-negative-beyond.obj", (obj + "f -1 -2 -99999\n").encode(), "error")
    c.add("obj-nan-vertex.obj", obj.replace("v ", "v nan ", 1).encode(), "error")
    c.add("obj-inf-vertex.obj", obj.replace("v ", "v inf ", 1).encode(), "error")
    big = "".join(f"v {a * 1e154} {b * 1e154} {d * 1e154}\n" for a, b, d in v) + obj.split("f ", 1)[0][:0]
    faces = "".join(f"f {a + 1} {b + 1} {d + 1}\n" for a, b, d in f)
    c.add("obj-1e154.obj", (big + faces).encode())
    c.add(
        "obj-1e300.obj",
        ("".join(f"v {a * 1e300} {b * 1e300} {d * 1e300}\n" for a, b, d in v) + faces).encode(),
    )
    c.add(
        "obj-1e-300.obj",
        ("".join(f"v {a * 1e-300} {b * 1e-300} {d * 1e-300}\n" for a, b, d in v) + faces).encode(),
    )
    c.add("obj-mixed-scale.obj", (obj + "v 1e200 0 0\nf 1 2 163\n").encode())
    c.add("obj-mtllib-outside.obj", ("mtllib ../../../../etc/passwd\nmtllib /etc/shadow\n" + obj).encode())
    c.add(
        "obj-points-nan.obj",
        "".join(f"v {a} {b} {d}\n" for a, b, d in sphere(300)).replace("v ", "v nan ", 5).encode(),
        "ok",
    )

    ply_mesh = ply_bytes({"x": v[:, 0], "y": v[:, 1], "z": v[:, 2]}, faces=f)
    c.add("ok-mesh.ply", ply_mesh, "ok")
    hdr = ply_mesh.index(b"end_header") + 11
    c.cuts("ply-mesh", ".ply", ply_mesh, hdr)
    c.add(
        "ok-mesh-ascii.ply", ply_bytes({"x": v[:, 0], "y": v[:, 1], "z": v[:, 2]}, fmt="ascii", faces=f), "ok"
    )
    c.add(
        "ply-mesh-faces-1e12.ply",
        ply_mesh.replace(b"element face 320", b"element face 1000000000000"),
        "error",
        "declares",
    )
    c.add(
        "ply-mesh-face-out-of-range.ply",
        ply_bytes({"x": v[:, 0], "y": v[:, 1], "z": v[:, 2]}, fmt="ascii", faces=np.r_[f, [[0, 1, 10**6]]]),
        "error",
    )
    c.add(
        "ply-mesh-face-negative.ply",
        ply_bytes({"x": v[:, 0], "y": v[:, 1], "z": v[:, 2]}, fmt="ascii", faces=np.r_[f, [[0, -1, 2]]]),
        "error",
    )
    c.add(
        "ply-mesh-nan.ply",
        ply_bytes({"x": np.r_[np.nan, v[1:, 0]], "y": v[:, 1], "z": v[:, 2]}, faces=f),
        "error",
    )

    stl = m.export(file_type="stl")
    c.add("ok.stl", stl, "ok")
    c.cuts("stl", ".stl", stl, 84)
    c.add("stl-count-high.stl", stl[:80] + struct.pack("<I", 10**6) + stl[84:], "error", "binary STL")
    c.add("stl-count-low.stl", stl[:80] + struct.pack("<I", 5) + stl[84:], "error", "binary STL")
    c.add("stl-count-max.stl", stl[:80] + struct.pack("<I", 2**32 - 1) + stl[84:], "error", "binary STL")
    c.add("stl-count-zero.stl", stl[:80] + struct.pack("<I", 0) + stl[84:], "error", "binary STL")
    tri = np.frombuffer(stl[84:], dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]).copy()
    for tag, value in (("nan", np.nan), ("inf", np.inf), ("3e38", 3e38)):
        bad = tri.copy()
        bad["v"][:7] = value
        c.add(f"stl-{tag}.stl", stl[:84] + bad.tobytes())
    huge = tri.copy()
    huge["v"] *= np.float32(1e37)
    c.add("stl-1e37.stl", stl[:84] + huge.tobytes())
    c.add("stl-solid-header-binary.stl", b"solid binary" + stl[12:], "ok")
    ascii_stl = (
        m.export(file_type="stl_ascii").encode()
        if isinstance(m.export(file_type="stl_ascii"), str)
        else m.export(file_type="stl_ascii")
    )
    c.add("ok-ascii.stl", ascii_stl, "ok")
    c.cuts("stl-ascii", ".stl", ascii_stl, 60)
    c.add(
        "stl-ascii-garbage.stl",
        b"solid x\nfacet normal 0 0 1\nouter loop\nvertex a b c\nendloop\nendfacet\nendsolid\n",
        "error",
    )
    c.add("stl-ascii-nan.stl", ascii_stl.replace(b"vertex ", b"vertex nan ", 3))

    off = (
        f"OFF\n{len(v)} {len(f)} 0\n"
        + "".join(f"{a} {b} {d}\n" for a, b, d in v)
        + "".join(f"3 {a} {b} {d}\n" for a, b, d in f)
    )
    c.add("ok.off", off.encode(), "ok")
    c.cuts("off", ".off", off.encode(), 12)
    c.add(
        "off-counts-1e12.off",
        off.replace(f"{len(v)} {len(f)} 0", "1000000000000 1000000000000 0", 1).encode(),
        "error",
    )
    c.add(
        "off-face-out-of-range.off",
        (off + "3 0 1 99999\n").replace(f"{len(f)} 0", f"{len(f) + 1} 0", 1).encode(),
        "error",
    )
    c.add("off-nan.off", off.replace("\n", "\nnan nan nan\n", 2).encode())
    c.add("off-polygon-huge.off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n1000000000 0 1 2\n")


def _gltf(c: Corpus) -> None:
    gltf, data = gltf_triangle()
    good = glb(gltf, data)
    c.add("ok.glb", good, "ok")  # one triangle: a flat sheet, which is a valid (thin) shape
    m = mesh()
    c.add("ok-sphere.glb", m.export(file_type="glb"), "ok")
    c.cuts("glb", ".glb", m.export(file_type="glb"), 20)
    c.add("glb-short-buffer.glb", glb(*gltf_triangle(buffer_length=4000))[:-8], "error")
    c.add("glb-short-bin-chunk.glb", glb(gltf, data[:10]), "error")
    c.add("glb-offset-huge.glb", glb(*gltf_triangle(offset=2**40)), "error")
    c.add("glb-length-huge.glb", glb(*gltf_triangle(length=2**40)), "error")
    c.add("glb-count-huge.glb", glb(*gltf_triangle(count=10**12)), "error")
    c.add("glb-json-length-huge.glb", glb(gltf, data, json_length=2**31), "error")
    bad_type = json.loads(json.dumps(gltf))
    bad_type["accessors"][0]["componentType"] = 9999
    c.add("glb-component-type.glb", glb(bad_type, data), "error")
    bad_index = json.loads(json.dumps(gltf))
    bad_index["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = 77
    c.add("glb-accessor-missing.glb", glb(bad_index, data), "error")
    c.add("glb-json-garbage.glb", glb({"asset": {}}, b"")[:20] + b"{{{{not json" + bytes(20), "error")
    nested = b'{"asset": {"version": "2.0"}, "x": ' + b"[" * 100000 + b"]" * 100000 + b"}"
    c.add("gltf-nested.gltf", nested, "error")
    c.add(
        "glb-nested.glb",
        struct.pack("<4sII", b"glTF", 2, 20 + len(nested))
        + struct.pack("<II", len(nested), 0x4E4F534A)
        + nested,
        "error",
    )
    (c.out / "outside.bin").write_bytes(data)
    os.makedirs(c.out / "sub", exist_ok=True)
    for tag, uri in (
        ("dotdot", "../outside.bin"),
        ("dotdot-deep", "../../../../../../etc/passwd"),
        ("absolute", str(c.out / "outside.bin")),
        ("file-url", f"file://{c.out / 'outside.bin'}"),
        ("http", "http://127.0.0.1:9/x.bin"),
        ("directory", "."),
        ("fifo", "fifo.bin"),
        ("missing", "nope.bin"),
        ("data-bad", "data:application/octet-stream;base64,@@@@"),
        ("dev-zero", "/dev/zero"),
    ):
        g, _ = gltf_triangle(uri=uri)
        c.add(f"sub/gltf-uri-{tag}.gltf", json.dumps(g).encode(), "error")
    fifo = c.out / "sub" / "fifo.bin"
    if not fifo.exists():
        os.mkfifo(fifo)
    g, _ = gltf_triangle(uri="data:application/octet-stream;base64," + base64.b64encode(data).decode())
    c.add("gltf-data-uri.gltf", json.dumps(g).encode(), "ok")
    g, _ = gltf_triangle(
        uri="data:application/octet-stream;base64," + base64.b64encode(data).decode(), count=10**9
    )
    c.add("gltf-data-uri-count-huge.gltf", json.dumps(g).encode(), "error")


def _points(c: Corpus) -> None:
    p = sphere(600)
    cols = {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2]}
    pts_ply = ply_bytes(cols)
    c.add("ok-points.ply", pts_ply, "ok")
    hdr = pts_ply.index(b"end_header") + 11
    c.cuts("ply-points", ".ply", pts_ply, hdr)
    c.add(
        "ply-vertex-1e12.ply",
        ply_bytes({k: v[:3] for k, v in cols.items()}, count=10**12),
        "error",
        "declares",
    )
    c.add(
        "ply-vertex-1e12-ascii.ply",
        ply_bytes({k: v[:3] for k, v in cols.items()}, fmt="ascii", count=10**12),
        "error",
        "declares",
    )
    c.add("ply-vertex-negative.ply", pts_ply.replace(b"element vertex 600", b"element vertex -5"), "error")
    c.add("ply-unknown-type.ply", pts_ply.replace(b"property float y", b"property flot y"), "error")
    c.add("ply-ascii-binary-body.ply", pts_ply.replace(b"binary_little_endian", b"ascii"), "error")
    c.add("ply-header-only.ply", b"ply\n", "error")
    for tag, value in (("nan", np.nan), ("inf", np.inf), ("neginf", -np.inf)):
        for col in "xyz":
            bad = dict(cols)
            bad[col] = np.where(np.arange(600) % 50 == 0, value, cols[col])
            c.add(f"ply-points-{tag}-{col}.ply", ply_bytes(bad), "ok", slow=col != "x")
    few = {k: np.where(np.arange(600) < 597, np.nan, v) for k, v in cols.items()}
    c.add("ply-points-3-finite.ply", ply_bytes(few), "error", "finite")
    c.add("ply-points-all-nan.ply", ply_bytes({k: np.full(600, np.nan) for k in cols}), "error", "finite")
    for tag, scale in (
        ("1e154", 1e154),
        ("1e300", 1e300),
        ("1e-300", 1e-300),
        ("1e-154", 1e-154),
        ("1e200", 1e200),
    ):
        c.add(f"ply-points-{tag}.ply", ply_bytes({k: v * scale for k, v in cols.items()}, dtype="f8"))
    c.add("ply-points-one-far.ply", ply_bytes({k: np.r_[v, 1e300] for k, v in cols.items()}, dtype="f8"))
    c.add(
        "ply-points-normals-nan.ply",
        ply_bytes({**cols, "nx": np.full(600, np.nan), "ny": p[:, 1], "nz": p[:, 2]}),
        "ok",
    )

    xyz = "".join(f"{a} {b} {d}\n" for a, b, d in p)
    c.add("ok.xyz", xyz.encode(), "ok")
    c.cuts("xyz", ".xyz", xyz.encode(), 20)
    c.add("xyz-nan-rows.xyz", xyz.replace("\n", "\nnan nan nan\n", 30).encode(), "ok")
    c.add("xyz-inf-rows.xyz", xyz.replace("\n", "\n1 inf 2\n", 30).encode(), "ok")
    c.add("xyz-3-finite.xyz", ("0 0 0\n1 0 0\n0 1 0\n" + "nan 0 0\n" * 50).encode(), "error", "finite")
    c.add("xyz-1e154.xyz", "".join(f"{a * 1e154} {b * 1e154} {d * 1e154}\n" for a, b, d in p).encode())
    c.add("xyz-1e308.xyz", "".join(f"{a * 1e308} {b * 1e308} {d * 1e308}\n" for a, b, d in p).encode())
    c.add("xyz-1e-300.xyz", "".join(f"{a * 1e-300} {b * 1e-300} {d * 1e-300}\n" for a, b, d in p).encode())
    c.add("xyz-wide-row.xyz", (xyz + " ".join(["1"] * 100000) + "\n").encode(), "error")
    c.add("xyz-overflow.xyz", (xyz + "1e999 0 0\n").encode(), "ok")
    c.add("pts-count-huge.pts", ("1000000000000\n" + xyz).encode(), "ok")
    c.add("ok.pts", (f"{len(p)}\n" + "".join(f"{a} {b} {d} 10 200 100 50\n" for a, b, d in p)).encode(), "ok")

    for mode in ("ascii", "binary", "binary_compressed"):
        data = pcd_bytes(p, mode)
        c.add(f"ok-{mode}.pcd", data, "ok")
        c.cuts(f"pcd-{mode}", ".pcd", data, data.index(b"DATA") + len(f"DATA {mode}\n"))
        c.add(f"pcd-{mode}-points-1e12.pcd", pcd_bytes(p, mode, count=10**12, width=10**12), "error")
        holes = p.copy()
        holes[::3] = np.nan
        c.add(f"pcd-{mode}-organised-nan.pcd", pcd_bytes(holes, mode, width=30, height=20), "ok")
        c.add(f"pcd-{mode}-all-nan.pcd", pcd_bytes(np.full((600, 3), np.nan), mode), "error", "finite")
        c.add(f"pcd-{mode}-viewpoint-garbage.pcd", pcd_bytes(p, mode, viewpoint="a b nan"), "ok")
        c.add(f"pcd-{mode}-1e38.pcd", pcd_bytes(p * 3e38, mode))
    comp = pcd_bytes(p, "binary_compressed")
    at = comp.index(b"DATA binary_compressed\n") + len("DATA binary_compressed\n")
    c.add(
        "pcd-compressed-size-huge.pcd",
        comp[:at] + struct.pack("<II", 2**32 - 1, 2**32 - 1) + comp[at + 8 :],
        "error",
    )
    c.add(
        "pcd-compressed-raw-short.pcd",
        comp[:at] + struct.pack("<II", len(comp) - at - 8, 100) + comp[at + 8 :],
        "error",
    )
    c.add(
        "pcd-compressed-backref.pcd",
        comp[:at] + struct.pack("<II", 4, 7200) + b"\xe0\xff\xff\xff" + bytes(8),
        "error",
    )
    c.add("pcd-size-3.pcd", pcd_bytes(p, "binary").replace(b"SIZE 4 4 4", b"SIZE 3 4 4"), "error")
    c.add("pcd-no-data.pcd", b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 3\nDATA ", "error")

    las = las_bytes(p * 10 + 100)
    c.add("ok.las", las, "ok")
    c.cuts("las", ".las", las, 227)
    c.add("las-count-1e9.las", las[:107] + struct.pack("<I", 10**9) + las[111:1024], "error", "declares")
    c.add("las-signature-random.las", b"LASF" + c.rng.bytes(4000), "error")
    c.add(
        "las-signature-random-big.las",
        lambda: b"LASF" + np.random.default_rng(8).bytes(400_000),
        "error",
        slow=True,
    )
    c.add("las-offset-beyond.las", las[:96] + struct.pack("<I", 10**9) + las[100:], "error")
    c.add("las-record-length-0.las", las[:105] + struct.pack("<H", 0) + las[107:], "error")
    c.add("las-format-99.las", las[:104] + bytes([99]) + las[105:], "error")
    c.add("las-vlr-count-huge.las", las[:100] + struct.pack("<I", 10**9) + las[104:], "error")
    c.add("las-header-size-0.las", las[:94] + struct.pack("<H", 0) + las[96:], "error")
    c.add("las-scale-0.las", las[:131] + struct.pack("<ddd", 0, 0, 0) + las[155:], "error")
    c.add("las-scale-nan.las", las[:131] + struct.pack("<ddd", np.nan, np.nan, np.nan) + las[155:], "error")
    laz = las_bytes(p * 10 + 100, compressed=True)
    c.add("ok.laz", laz, "ok")
    c.cuts("laz", ".laz", laz, 227 + 54)
    c.add("laz-count-1e9.laz", laz[:107] + struct.pack("<I", 10**9) + laz[111:], "error")


def _splats(c: Corpus) -> None:
    g = gaussians(600)
    cols = inria_columns(g)
    splat = ply_bytes(cols)
    c.add("ok-splat.ply", splat, "ok")
    c.cuts("splat", ".ply", splat, splat.index(b"end_header") + 11)
    for name in cols:
        for tag, value in (("nan", np.nan), ("inf", np.inf)):
            bad = dict(cols)
            bad[name] = np.where(np.arange(600) % 40 == 0, value, cols[name])
            c.add(
                f"splat-{tag}-{name}.ply",
                ply_bytes(bad),
                "ok",
                slow=name not in ("x", "scale_0", "rot_0", "opacity") or tag == "inf",
            )
    c.add(
        "splat-log-scale-80.ply",
        ply_bytes({**cols, "scale_0": np.full(600, 80.0)}),
        "error",
        "larger than the splat",
    )
    c.add(
        "splat-log-scale-80-some.ply",
        ply_bytes({**cols, "scale_1": np.where(np.arange(600) < 30, 80.0, cols["scale_1"])}),
        "ok",
    )
    c.add("splat-log-scale-minus-80.ply", ply_bytes({**cols, "scale_2": np.full(600, -80.0)}), "ok")
    c.add("splat-log-scale-1000.ply", ply_bytes({**cols, "scale_0": np.full(600, 1000.0)}), "error")
    c.add("splat-transparent.ply", ply_bytes({**cols, "opacity": np.full(600, -50.0)}), "error", "opacity")
    c.add(
        "splat-zero-rotations.ply", ply_bytes({**cols, **{f"rot_{i}": np.zeros(600) for i in range(4)}}), "ok"
    )
    for tag, scale in (("1e154", 1e154), ("1e300", 1e300), ("1e-300", 1e-300)):
        big = dict(cols)
        for k in "xyz":
            big[k] = cols[k] * scale
        c.add(f"splat-{tag}.ply", ply_bytes(big, dtype="f8"))
    c.add(
        "splat-vertex-1e12.ply",
        splat.replace(b"element vertex 600", b"element vertex 1000000000000"),
        "error",
        "declares",
    )

    comp = compressed_ply(g)
    c.add("ok.compressed.ply", comp, "ok")
    hdr = comp.index(b"end_header") + 11
    c.cuts("compressed", ".ply", comp, hdr)
    c.add("compressed-random-all.ply", comp[:hdr] + c.rng.bytes(len(comp) - hdr))
    c.add("compressed-random-vertices.ply", comp[: hdr + 3 * 48] + c.rng.bytes(len(comp) - hdr - 3 * 48))
    for tag, value in (("nan", np.nan), ("inf", np.inf), ("huge", 3e38)):
        c.add(f"compressed-chunk-{tag}.ply", compressed_ply(g, {"min_x": value, "max_scale_y": value}))
    c.add("compressed-scale-80.ply", compressed_ply(g, {"min_scale_x": 80.0, "max_scale_x": 80.0}), "error")
    c.add("compressed-chunks-mismatch.ply", comp.replace(b"element chunk 3", b"element chunk 2"), "error")

    legacy = spz_legacy(g)
    for version in (2, 3):
        c.add(f"ok-v{version}.spz", gzip.compress(spz_legacy(g, version=version), mtime=0), "ok")
    c.cuts("spz-gzip", ".spz", gzip.compress(legacy, mtime=0), 10)
    c.add("spz-payload-short.spz", gzip.compress(legacy[:-100], mtime=0), "error", "truncated SPZ")
    c.add("spz-payload-long.spz", gzip.compress(legacy + bytes(5000), mtime=0))
    c.add("spz-count-1e8.spz", gzip.compress(spz_legacy(g, count=10**8), mtime=0), "error")
    c.add("spz-count-max.spz", gzip.compress(spz_legacy(g, count=2**32 - 1), mtime=0), "error")
    c.add("spz-degree-7.spz", gzip.compress(spz_legacy(g, degree=7), mtime=0), "error")
    v9 = legacy[:4] + struct.pack("<I", 9) + legacy[8:]
    c.add("spz-version-9.spz", gzip.compress(v9, mtime=0), "error")
    c.add("spz-bomb-3gib.spz", gzip_of_zeros(legacy[:16], 3 * GiB), "error", "inflates")
    c.add(
        "spz-bomb-3gib-count-1e7.spz",
        gzip_of_zeros(spz_legacy(g, count=10**7)[:16], 3 * GiB),
        "error",
        "inflates",
    )
    import zstandard

    c.add("spz-zstd-legacy.spz", zstandard.ZstdCompressor().compress(legacy), "ok")
    zc = zstandard.ZstdCompressor(level=1)
    c.add("spz-zstd-bomb.spz", lambda: zc.compress(legacy[:16] + bytes(GiB)), "error", slow=True)
    v4 = spz_v4(g)
    c.add("ok-v4.spz", v4, "ok")
    c.cuts("spz-v4", ".spz", v4, 32)
    c.add("spz-v4-toc-huge.spz", v4[:16] + struct.pack("<I", 2**32 - 1) + v4[20:], "error")
    c.add("spz-v4-count-1e8.spz", spz_v4(g, count=10**8), "error")
    c.add("spz-v4-streams-255.spz", v4[:15] + bytes([255]) + v4[16:], "error")
    c.add("spz-v4-csize-huge.spz", v4[:32] + struct.pack("<Q", 2**63) + v4[40:], "error")
    c.add("spz-raw-ngsp-random.spz", legacy[:16] + c.rng.bytes(len(legacy) - 16))
    c.add("spz-random.spz", c.rng.bytes(5000), "error")

    rec = np.zeros(
        600, dtype=[("pos", "<f4", (3,)), ("scale", "<f4", (3,)), ("rgba", "u1", (4,)), ("rot", "u1", (4,))]
    )
    rec["pos"], rec["scale"] = g["centers"], g["scales"]
    rec["rgba"] = 200
    rec["rot"] = [255, 128, 128, 128]
    c.add("ok.splat", rec.tobytes(), "ok")
    c.add("dotsplat-random.splat", c.rng.bytes(32 * 600))
    c.add("dotsplat-zeros.splat", bytes(32 * 600), "error")
    c.add("dotsplat-cut.splat", rec.tobytes()[:-7], "error", "truncated")
    nan = rec.copy()
    nan["pos"][::7] = np.nan
    nan["scale"][::11] = np.inf
    c.add("dotsplat-nan.splat", nan.tobytes(), "ok")
    huge = rec.copy()
    huge["scale"] = 3e38
    c.add("dotsplat-scale-3e38.splat", huge.tobytes(), "error")


def _cad(c: Corpus) -> None:
    step = (ROOT / "io" / "bracket.step").read_bytes()
    c.add("ok.step", step, "ok", slow=True)
    c.add("step-cut-half.step", step[: len(step) // 2], "error")
    c.add("step-random-body.step", lambda: step[:400] + np.random.default_rng(9).bytes(4000), slow=True)
    c.add(
        "step-nested.step",
        b"ISO-10303-21;\nHEADER;\nENDSEC;\nDATA;\n#1=A(" + b"(" * 100000 + b");\n"
        b"ENDSEC;\nEND-ISO-10303-21;\n",
        "error",
        slow=True,
    )
    c.add(
        "step-empty-data.step",
        b"ISO-10303-21;\nHEADER;\nENDSEC;\nDATA;\nENDSEC;\nEND-ISO-10303-21;\n",
        "error",
        slow=True,
    )
    iges = (
        "".ljust(72)
        + "S      1\n"
        + "1H,,1H;,4Hpart;".ljust(72)
        + "G      1\n"
        + "garbage".ljust(72)
        + "D      1\n"
    ).encode()
    c.add("iges-garbage.igs", iges, "error", slow=True)


def _filesystem(c: Corpus) -> None:
    fifo = c.out / "fifo.ply"
    os.mkfifo(fifo)
    c.add("fifo.ply", None, "error", "not a regular file")
    (c.out / "folder.obj").mkdir()
    c.add("folder.obj", None, "error", "directory")
    (c.out / "zero.ply").symlink_to("/dev/zero")
    c.add("zero.ply", None, "error", "not a regular file")
    (c.out / "loop.ply").symlink_to(c.out / "loop.ply")
    c.add("loop.ply", None, "error")
    (c.out / "dangling.ply").symlink_to(c.out / "nowhere.ply")
    c.add("dangling.ply", None, "error", "no such file")
    obj = (c.out / "ok.obj").read_bytes()
    c.add("obj-named.ply", obj, "ok")
    c.add("ply-named.stl", (c.out / "ok-points.ply").read_bytes(), "ok")
    c.add("stl-named.obj", (c.out / "ok.stl").read_bytes(), "ok")
    c.add("splat-named.spz", (c.out / "ok.splat").read_bytes(), "error")
    c.add("random-named.splat", c.rng.bytes(5000), "error")
    c.add("random.bin", c.rng.bytes(5000), "error", "unknown format")
    c.add("nul.xyz", bytes(5000), "error")
    c.add("utf16.xyz", "1 2 3\n4 5 6\n7 8 9\n1 1 1\n".encode("utf-16"), "error")
    slow_rng = np.random.default_rng(7)
    c.add("huge-random.stl", lambda: slow_rng.bytes(84 + 50 * 1_500_000), slow=True)
    c.add("random-triangles.stl", lambda: random_triangles_stl(1_500_000), "ok", slow=True)


def random_triangles_stl(n: int, seed: int = 0) -> bytes:
    """A binary STL of ``n`` random overlapping triangles in the unit cube (75 MB for 1.5M)."""
    rng = np.random.default_rng(seed)
    rec = np.zeros(n, dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    centres = rng.random((n, 1, 3))
    rec["v"] = centres + 0.02 * rng.normal(size=(n, 3, 3))
    return bytes(80) + struct.pack("<I", n) + rec.tobytes()


# ------------------------------------------------------------------------------------ running it
def limit_memory() -> None:
    """``preexec_fn`` of every child: cap its address space at :data:`MEMORY_BYTES`."""
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_BYTES, MEMORY_BYTES))


def _peak_rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    return 0.0


def load_each(paths: list[str]) -> None:
    """Child side of :func:`run_api`: load every path with the API and print one JSON line each
    (``begin`` first, so the parent knows what a dead child was doing)."""
    import warnings

    import pointcvx

    warnings.simplefilter("error")  # a numpy RuntimeWarning is an unclean outcome too
    for path in paths:
        print(json.dumps({"begin": path}), flush=True)
        with contextlib.suppress(OSError):  # per-file peak memory: reset the high-water mark
            Path("/proc/self/clear_refs").write_text("5")
        t0 = time.perf_counter()
        row: dict = {"path": path}
        try:
            cloud = pointcvx.load(path, n_points=2000, seed=0)
            finite = bool(np.isfinite(cloud.points).all() and np.isfinite(cloud.normals).all())
            back = cloud.normalization.inverse(cloud.points)
            row.update(
                outcome="ok",
                points=len(cloud),
                finite=finite and bool(np.isfinite(back).all()),
                info={k: v for k, v in cloud.info.items() if isinstance(v, (int, float, str, bool))},
            )
        except pointcvx.PointcvxError as exc:
            row.update(outcome="error", type=type(exc).__name__, message=str(exc))
        except BaseException as exc:  # noqa: BLE001 - anything else is what the corpus looks for
            import traceback

            row.update(
                outcome="crash",
                type=type(exc).__name__,
                message=str(exc)[:300],
                where=traceback.format_exc().splitlines()[-3:],
            )
        row["seconds"] = round(time.perf_counter() - t0, 3)
        row["peak_mb"] = round(_peak_rss_mb())
        print(json.dumps(row, default=str), flush=True)


def _pump(stream, lines: queue.Queue) -> None:
    """Copy ``stream``'s lines into ``lines``, then an empty string for its end."""
    for line in stream:
        lines.put(line)
    lines.put("")


def run_api(paths: list[str | os.PathLike], seconds: float = INFO_SECONDS) -> dict[str, dict]:
    """Load every path with ``pointcvx.load`` in child processes (as many files per process as
    possible) under :data:`MEMORY_BYTES`; a file that takes over ``seconds``, or kills its child,
    is recorded as such and the rest go on in a fresh child. Returns path -> outcome row."""
    todo = [str(p) for p in paths]
    rows: dict[str, dict] = {}
    while todo:
        with tempfile.TemporaryFile("w+") as err_file:  # a file, not a pipe: a chatty child never blocks
            proc = subprocess.Popen(
                [sys.executable, __file__, "--load-each", *todo],
                stdout=subprocess.PIPE,
                stderr=err_file,
                preexec_fn=limit_memory,
                cwd=ROOT,
                text=True,
            )
            lines: queue.Queue = queue.Queue()
            threading.Thread(target=_pump, args=(proc.stdout, lines), daemon=True).start()
            current, deadline, timed_out = None, time.monotonic() + 120, False  # 120 s: the imports
            while True:
                try:
                    line = lines.get(timeout=max(0.0, deadline - time.monotonic()))
                except queue.Empty:
                    proc.kill()
                    timed_out = True
                    break
                if not line:
                    break
                msg = json.loads(line)
                if "begin" in msg:
                    current, deadline = msg["begin"], time.monotonic() + seconds
                    continue
                rows[msg["path"]] = msg
                todo.remove(msg["path"])
                current, deadline = None, time.monotonic() + seconds
            proc.wait()
            err_file.seek(0)
            err = err_file.read()
        if current is None:
            if todo:  # died between files or before the first: not a file's doing
                raise RuntimeError(f"the loader child failed (status {proc.returncode}): {err[-2000:]}")
            break
        how = f"timeout after {seconds} s" if timed_out else f"died (status {proc.returncode})"
        rows[current] = {"path": current, "outcome": how, "message": err.strip()[-500:]}
        todo.remove(current)
    return rows


def run_cli(args: list[str], seconds: float) -> dict:
    """Run ``python -m pointcvx ARGS`` under the memory limit; exit status, stderr lines, time."""
    t0 = time.perf_counter()
    try:
        res = subprocess.run(
            [sys.executable, "-m", "pointcvx", *args],
            capture_output=True,
            text=True,
            timeout=seconds,
            preexec_fn=limit_memory,
            cwd=ROOT,
            stdin=subprocess.DEVNULL,
        )
        rc, err = res.returncode, res.stderr
    except subprocess.TimeoutExpired as exc:
        rc, err = (
            "timeout",
            (exc.stderr or b"").decode("utf-8", "replace")
            if isinstance(exc.stderr, bytes)
            else (exc.stderr or ""),
        )
    return {
        "args": args,
        "rc": rc,
        "stderr": err.strip().splitlines(),
        "seconds": round(time.perf_counter() - t0, 2),
    }


def problems(member: Member, api: dict | None = None, cli: dict | None = None) -> list[str]:
    """What is wrong with the outcomes of ``member`` (empty when it behaved)."""
    out = []
    if api is not None:
        kind = api["outcome"]
        if kind not in ("ok", "error"):
            out.append(
                f"API {kind}: {api.get('type', '')} {api.get('message', '')[:200]} {api.get('where', '')}"
            )
        elif kind == "ok" and not api.get("finite", False):
            out.append("API loaded a cloud with non-finite values")
        if member.expect is not None and kind in ("ok", "error") and kind != member.expect:
            out.append(f"API gave {kind} ({api.get('message', '')[:160]}), expected {member.expect}")
        if (
            member.expect == "error"
            and kind == "error"
            and member.fragment
            and member.fragment.lower() not in api["message"].lower()
        ):
            out.append(f"API message lacks {member.fragment!r}: {api['message'][:200]}")
        if kind == "error" and "memory" in api["message"].lower():
            out.append(f"API refused by running out of memory: {api['message'][:200]}")
    if cli is not None:
        if cli["rc"] not in (0, 1, 2):
            out.append(f"CLI exit {cli['rc']}: {' | '.join(cli['stderr'])[-300:]}")
        if len(cli["stderr"]) > 1:
            out.append(f"CLI printed {len(cli['stderr'])} stderr lines: {' | '.join(cli['stderr'])[-300:]}")
        text = "\n".join(cli["stderr"])
        if "Traceback" in text or "internal error" in text or "out of memory" in text:
            out.append(f"CLI: {text[-300:]}")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", nargs="?", help="folder to write the corpus into (emptied first)")
    parser.add_argument("--all", action="store_true", help="include the slow members")
    parser.add_argument("--run", action="store_true", help="run info and decompose on every member")
    parser.add_argument("--api-only", action="store_true", help="with --run: only the API loader")
    parser.add_argument("--slow-only", action="store_true", help="with --run --all: only the slow members")
    parser.add_argument("--load-each", nargs="+", metavar="PATH", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.load_each:
        load_each(args.load_each)
        return 0
    if not args.out:
        parser.error("OUT is required")
    members = build(args.out, slow=args.all)
    print(f"{len(members)} members in {args.out}")
    if not args.run:
        return 0
    if args.slow_only:
        members = [m for m in members if m.slow]
    paths = {m.name: str(Path(args.out) / m.name) for m in members}
    api = run_api(list(paths.values()))
    failed = 0
    with tempfile.TemporaryDirectory() as tmp:
        for m in members:
            found = problems(m, api=api[paths[m.name]])
            if not args.api_only:
                info = run_cli(["info", paths[m.name]], INFO_SECONDS)
                found += problems(m, cli=info)
                if info["rc"] == 0:
                    out = str(Path(tmp) / "hulls.obj")
                    dec = run_cli(
                        ["decompose", paths[m.name], *DECOMPOSE_ARGS, "-o", out, "--overwrite"],
                        DECOMPOSE_SECONDS,
                    )
                    found += problems(m, cli=dec)
            row = api[paths[m.name]]
            status = "FAIL" if found else "ok  "
            print(
                f"{status} {m.name:45s} {row['outcome']:6s} {row.get('seconds', '-')!s:>7}s "
                f"{row.get('peak_mb', '-')!s:>6}MB  {(row.get('message') or '')[:90]}",
                flush=True,
            )
            for p in found:
                print(f"       {p}", flush=True)
            failed += bool(found)
    print(f"{failed} of {len(members)} members misbehaved")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
