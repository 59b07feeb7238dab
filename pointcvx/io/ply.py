"""PLY reading with clear errors, header sniffing, and an atomic writer for oriented clouds."""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError, first_line
from .files import atomic_path, check_readable

MAX_HEADER = 1 << 20


#: Bytes of each PLY scalar type (the spec's names, their sized aliases and numpy codes); a type
#: not listed counts as one byte, the readers then judge it.
PLY_TYPE_SIZES = {"char": 1, "int8": 1, "uchar": 1, "uint8": 1, "short": 2, "int16": 2, "ushort": 2,
                  "uint16": 2, "int": 4, "int32": 4, "uint": 4, "uint32": 4, "float": 4, "float32": 4,
                  "double": 8, "float64": 8, "int64": 8, "uint64": 8, "i1": 1, "u1": 1, "b1": 1, "i2": 2,
                  "u2": 2, "i4": 4, "u4": 4, "f4": 4, "f8": 8, "i8": 8, "u8": 8}


@dataclass(frozen=True)
class PlyHeader:
    """What a PLY header declares: format and, per element, its count and property names.

    ``row_bytes`` gives, per element, the fewest bytes one row can take in the file (a list
    property counted empty), and ``data_offset`` where the body starts.
    """

    format: str
    elements: dict[str, tuple[int, tuple[str, ...]]]
    comments: tuple[str, ...]
    row_bytes: dict[str, int] = field(default_factory=dict)
    data_offset: int = 0

    def count(self, element: str) -> int:
        return self.elements.get(element, (0, ()))[0]

    def properties(self, element: str) -> tuple[str, ...]:
        return self.elements.get(element, (0, ()))[1]


def _property_bytes(parts: list[str], fmt: str, p, raw: str) -> int:
    """Fewest bytes of one ``property`` line's value in a row (a list with no items)."""
    if len(parts) < (5 if parts[1] == "list" else 3):
        raise InputError(f"{p}: corrupted PLY header: bad property line {raw.strip()[:80]!r}")
    if fmt == "ascii":
        return 2  # one digit and a separator
    return PLY_TYPE_SIZES.get(parts[2] if parts[1] == "list" else parts[1], 1)  # a list: its count


def read_header(path: str | os.PathLike) -> PlyHeader:
    """Parse only the header of a PLY file; :class:`InputError` if it is not a valid header, or if
    the counts it declares need more bytes than the file holds (checked before anything is
    allocated: a header may declare 10^12 vertices over three rows)."""
    p = check_readable(path)
    size = p.stat().st_size
    with open(p, "rb") as f:
        head = f.read(MAX_HEADER)
    if not head.startswith(b"ply"):
        raise InputError(f"{p}: not a PLY file (no 'ply' magic)")
    end = head.find(b"end_header")
    if end < 0:
        raise InputError(f"{p}: corrupted PLY: the header never ends (no 'end_header')")
    newline = head.find(b"\n", end)
    data_offset = newline + 1 if newline >= 0 else len(head)
    lines = head[:end].decode("ascii", errors="replace").splitlines()[1:]
    fmt = next((ln.split()[1] for ln in lines if ln.split()[:1] == ["format"] and len(ln.split()) >= 2), "")
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise InputError(f"{p}: corrupted PLY header: unknown format {fmt!r}")
    elements: dict[str, tuple[int, list[str]]] = {}
    row_bytes: dict[str, int] = {}
    comments = []
    current = None
    for raw in lines:
        parts = raw.split()
        if not parts:
            continue
        key = parts[0]
        if key in ("comment", "obj_info"):
            comments.append(raw[len(key):].strip())
        elif key == "element" and len(parts) >= 3:
            try:
                count = int(parts[2])
            except ValueError:
                raise InputError(f"{p}: corrupted PLY header: bad element line {raw!r}") from None
            if count < 0:
                raise InputError(f"{p}: corrupted PLY header: element {parts[1]!r} has {count} rows")
            current = parts[1]
            elements[current] = (count, [])
            row_bytes[current] = 0
        elif key == "property" and current is not None and len(parts) >= 2:
            row_bytes[current] += _property_bytes(parts, fmt, p, raw)
            elements[current][1].append(parts[-1])
    header = PlyHeader(fmt, {k: (c, tuple(v)) for k, (c, v) in elements.items()}, tuple(comments),
                       row_bytes, data_offset)
    check_declared_size(p, header, size)
    return header


def check_declared_size(p, header: PlyHeader, size: int) -> None:
    """:class:`InputError` when the rows ``header`` declares cannot fit in a file of ``size`` bytes."""
    need = sum(count * header.row_bytes.get(name, 0) for name, (count, _) in header.elements.items())
    body = size - header.data_offset
    if need > body:
        rows = " and ".join(f"{count} " + ("vertices" if name == "vertex" else f"{name} rows")
                            for name, (count, _) in header.elements.items() if count)
        raise InputError(f"{p}: truncated or corrupted PLY: the header declares {rows}, needing at "
                         f"least {need} bytes, but the file holds {max(body, 0)} after its header")


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
