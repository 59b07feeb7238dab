"""PLY reading with clear errors, header sniffing, and an atomic writer for oriented clouds."""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass

import numpy as np

from ..errors import InputError, first_line
from .files import atomic_path, check_readable

MAX_HEADER = 1 << 20


@dataclass(frozen=True)
class PlyHeader:
    """What a PLY header declares: format and, per element, its count and property names."""

    format: str
    elements: dict[str, tuple[int, tuple[str, ...]]]
    comments: tuple[str, ...]

    def count(self, element: str) -> int:
        return self.elements.get(element, (0, ()))[0]

    def properties(self, element: str) -> tuple[str, ...]:
        return self.elements.get(element, (0, ()))[1]


def read_header(path: str | os.PathLike) -> PlyHeader:
    """Parse only the header of a PLY file; :class:`InputError` if it is not a valid header."""
    p = check_readable(path)
    with open(p, "rb") as f:
        head = f.read(MAX_HEADER)
    if not head.startswith(b"ply"):
        raise InputError(f"{p}: not a PLY file (no 'ply' magic)")
    end = head.find(b"end_header")
    if end < 0:
        raise InputError(f"{p}: corrupted PLY: the header never ends (no 'end_header')")
    fmt = ""
    elements: dict[str, tuple[int, list[str]]] = {}
    comments = []
    current = None
    for raw in head[:end].decode("ascii", errors="replace").splitlines()[1:]:
        parts = raw.split()
        if not parts:
            continue
        key = parts[0]
        if key == "format" and len(parts) >= 2:
            fmt = parts[1]
        elif key in ("comment", "obj_info"):
            comments.append(raw[len(key):].strip())
        elif key == "element" and len(parts) >= 3:
            try:
                count = int(parts[2])
            except ValueError:
                raise InputError(f"{p}: corrupted PLY header: bad element line {raw!r}") from None
            current = parts[1]
            elements[current] = (count, [])
        elif key == "property" and current is not None and len(parts) >= 3:
            elements[current][1].append(parts[-1])
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise InputError(f"{p}: corrupted PLY header: unknown format {fmt!r}")
    return PlyHeader(fmt, {k: (c, tuple(v)) for k, (c, v) in elements.items()}, tuple(comments))


def read_ply(path: str | os.PathLike):
    """The whole file as a ``plyfile.PlyData``; :class:`InputError` if truncated or corrupted."""
    from plyfile import PlyData, PlyParseError

    p = check_readable(path)
    header = read_header(p)
    if header.count("vertex") == 0:
        raise InputError(f"{p}: the PLY has no vertices")
    try:
        with open(p, "rb") as f:
            data = PlyData.read(f)
    except (PlyParseError, ValueError, EOFError, struct.error, IndexError, UnicodeDecodeError) as exc:
        msg = first_line(exc)
        raise InputError(f"{p}: truncated or corrupted PLY ({msg})") from None
    return data


def vertex_array(data, names: tuple[str, ...]) -> np.ndarray:
    """(n, len(names)) float64 columns of the vertex element, looked up by property name."""
    v = data["vertex"].data
    missing = [n for n in names if n not in v.dtype.names]
    if missing:
        raise InputError(f"PLY vertex element lacks properties {missing}")
    return np.stack([np.asarray(v[n], dtype=np.float64) for n in names], axis=1)


def write_cloud_ply(path, points: np.ndarray, normals: np.ndarray | None = None,
                    colors: np.ndarray | None = None, extra: dict[str, np.ndarray] | None = None) -> None:
    """Write (n, 3) points with optional (n, 3) normals, (n, 3) colours in [0, 1] and extra (n,)
    float columns as a binary little-endian PLY, atomically."""
    from plyfile import PlyData, PlyElement

    n = len(points)
    cols = [("x", "f4"), ("y", "f4"), ("z", "f4")]
    if normals is not None:
        cols += [("nx", "f4"), ("ny", "f4"), ("nz", "f4")]
    if colors is not None:
        cols += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    extra = extra or {}
    cols += [(name, "f4") for name in extra]
    arr = np.empty(n, dtype=cols)
    arr["x"], arr["y"], arr["z"] = points.T
    if normals is not None:
        arr["nx"], arr["ny"], arr["nz"] = normals.T
    if colors is not None:
        c = np.clip(np.round(np.asarray(colors) * 255), 0, 255).astype(np.uint8)
        arr["red"], arr["green"], arr["blue"] = c.T
    for name, values in extra.items():
        arr[name] = values
    with atomic_path(path) as tmp:
        PlyData([PlyElement.describe(arr, "vertex")], text=False).write(str(tmp))
