"""Point-cloud files: PLY vertices, OBJ ``v`` lines, XYZ/PTS text, PCD and LAS -> arrays.

Every reader returns ``(points, normals, colors)``: (n, 3) float64 points, (n, 3) float64 normals
or None, (n, 3) float64 colours in [0, 1] or None; :func:`read_scan` picks the reader of a
detected format. :mod:`pointcvx.io.scan` turns the arrays into an oriented cloud.
"""

from __future__ import annotations

import io
import logging
import os
import re
import struct
from pathlib import Path

import numpy as np

from ..errors import InputError, MissingExtraError, first_line
from .files import check_readable

log = logging.getLogger(__name__)

Arrays = tuple[np.ndarray, "np.ndarray | None", "np.ndarray | None"]
"""(points, normals or None, colors or None) as every reader returns them."""


# ---------------------------------------------------------------------------------------- helpers
def colors_to_unit(values: np.ndarray, dtype: np.dtype | None = None) -> np.ndarray:
    """(n, 3) raw colour values -> (n, 3) float64 in [0, 1].

    Integer colours are divided by 255, or by 65535 when they exceed 255 (16-bit LAS/PLY); float
    colours already in [0, 1] are kept, larger ones are treated as 8 or 16-bit values.
    """
    c = np.asarray(values, dtype=np.float64)
    finite = c[np.isfinite(c)]
    top = float(finite.max()) if finite.size else 0.0
    is_int = dtype is not None and np.dtype(dtype).kind in "iu"
    if is_int or top > 1.0:
        c = c / (255.0 if top <= 255.0 else 65535.0)
    return np.clip(np.nan_to_num(c, nan=0.0), 0.0, 1.0)


def _unit_rows(v: np.ndarray) -> np.ndarray:
    """(n,) bool: rows of (n, 3) ``v`` that are finite with a length near 1 (a stored normal)."""
    length = np.linalg.norm(v, axis=1)
    return np.isfinite(length) & (np.abs(length - 1.0) < 0.05)


def _integers_in_byte_range(v: np.ndarray) -> bool:
    return bool(len(v)) and bool(np.all(np.isfinite(v))) and bool(
        np.all((v >= 0) & (v <= 255) & (v == np.round(v)))
    )


def _parse_rows(lines: list[str], path: Path, what: str) -> np.ndarray:
    """(n, m) float64 from text rows of numbers; InputError when rows are ragged or not numeric."""
    try:
        arr = np.loadtxt(io.StringIO("\n".join(lines)), dtype=np.float64, ndmin=2, comments=None)
    except ValueError as exc:
        msg = first_line(exc) if str(exc) else "unparseable number"
        raise InputError(f"{path}: corrupted {what} ({msg})") from None
    return arr


# ---------------------------------------------------------------------------------------- readers
_PLY_COLORS = (("red", "green", "blue"), ("r", "g", "b"), ("diffuse_red", "diffuse_green", "diffuse_blue"))


def read_ply_points(path: str | os.PathLike) -> Arrays:
    """Vertices of a PLY with no faces: x, y, z, optional nx/ny/nz and red/green/blue (or r/g/b)."""
    from .ply import read_ply, vertex_array

    p = Path(path)
    data = read_ply(p)
    names = data["vertex"].data.dtype.names or ()
    try:
        points = vertex_array(data, ("x", "y", "z"))
    except InputError as exc:
        raise InputError(f"{p}: {exc}") from None
    normals = colors = None
    if {"nx", "ny", "nz"} <= set(names):
        normals = vertex_array(data, ("nx", "ny", "nz"))
    for triple in _PLY_COLORS:
        if set(triple) <= set(names):
            dtype = data["vertex"].data.dtype[triple[0]]
            colors = colors_to_unit(vertex_array(data, triple), dtype)
            break
    return points, normals, colors


def read_obj_points(path: str | os.PathLike) -> Arrays:
    """``v x y z [r g b]`` lines of an OBJ without faces; ``vn`` lines are used when they pair up
    one to one with the vertices."""
    p = check_readable(path)
    try:
        text = p.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise InputError(f"{p}: cannot read ({exc.strerror})") from None
    v_lines, vn_lines = [], []
    for line in text.splitlines():
        if line.startswith("v "):
            v_lines.append(line[2:].split("#", 1)[0])
        elif line.startswith("vn "):
            vn_lines.append(line[3:].split("#", 1)[0])
    if not v_lines:
        raise InputError(f"{p}: the OBJ has no 'v' lines")
    widths = {len(s.split()) for s in v_lines}
    if min(widths) < 3:
        raise InputError(f"{p}: corrupted OBJ: a 'v' line has fewer than 3 coordinates")
    if len(widths) > 1:  # mixed 'v x y z' and 'v x y z r g b': keep the common part
        v_lines = [" ".join(s.split()[:3]) for s in v_lines]
    rows = _parse_rows(v_lines, p, "OBJ vertex")
    points = rows[:, :3]
    colors = colors_to_unit(rows[:, 3:6]) if rows.shape[1] >= 6 else None
    normals = None
    if len(vn_lines) == len(points):
        vn = _parse_rows(vn_lines, p, "OBJ normal")
        if vn.shape[1] >= 3:
            normals = vn[:, :3]
    return points, normals, colors


_HEADER_NAMES = {
    "x": "x", "y": "y", "z": "z",
    "nx": "nx", "ny": "ny", "nz": "nz", "normal_x": "nx", "normal_y": "ny", "normal_z": "nz",
    "r": "r", "g": "g", "b": "b", "red": "r", "green": "g", "blue": "b",
}
_NUMBER = re.compile(r"^[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?$|^[-+]?(?:nan|inf|infinity)$", re.I)
_SPLIT = re.compile(r"[\s,;]+")


def _columns_from_header(header: str | None, ncols: int) -> dict[str, int]:
    """Column index of x/y/z/nx.../r/g/b named by a header line, or {} when it names none."""
    if not header:
        return {}
    tokens = [t.strip("\"' ").lower() for t in _SPLIT.split(header.strip().lstrip("/#"))]
    tokens = [t for t in tokens if t]
    if len(tokens) != ncols:
        return {}
    cols = {_HEADER_NAMES[t]: i for i, t in enumerate(tokens) if t in _HEADER_NAMES}
    return cols if {"x", "y", "z"} <= set(cols) else {}


def _guess_columns(rows: np.ndarray, fmt: str) -> tuple[int | None, int | None]:
    """Start columns of normals and of RGB among the extra columns of an XYZ/PTS table.

    A triple whose rows are unit vectors is read as normals; one of integers in [0, 255] as RGB.
    PTS (Leica) rows are ``x y z intensity r g b``, so with 7 columns (or in a PTS) RGB is looked
    for after the intensity first.
    """
    m = rows.shape[1]
    normal_at = color_at = None
    sample = rows[:: max(1, len(rows) // 20000)]
    starts = list(range(3, m - 2))
    if (fmt == "pts" or m == 7) and 4 in starts:
        starts.remove(4)
        starts.insert(0, 4)
    for s in starts:
        if normal_at is None and _unit_rows(sample[:, s:s + 3]).mean() > 0.99:
            normal_at = s
    for s in starts:
        overlaps = normal_at is not None and abs(s - normal_at) < 3
        if not overlaps and color_at is None and _integers_in_byte_range(sample[:, s:s + 3]):
            color_at = s
    return normal_at, color_at


def read_xyz(path: str | os.PathLike, fmt: str = "xyz") -> Arrays:
    """XYZ or PTS text: one point a row, numbers separated by spaces, commas or semicolons.

    Non-numeric lines before the data are headers (a header naming the columns, like
    ``X Y Z R G B``, is used to find them); lines holding a single integer are PTS point counts and
    are skipped. Extra columns (intensity, RGB, normals) are allowed; see :func:`_guess_columns`.
    """
    p = check_readable(path)
    try:
        text = p.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise InputError(f"{p}: cannot read ({exc.strerror})") from None
    lines = text.replace(",", " ").replace(";", " ").splitlines()
    header = None
    start = 0
    for start, raw in enumerate(lines):  # noqa: B007 - ``start`` is used after the loop
        line = raw.strip()
        if not line:
            continue
        tokens = line.split()
        if line.startswith(("#", "//")) or not all(_NUMBER.match(t) for t in tokens):
            header = line.lstrip("#/ ") or header
            continue
        if len(tokens) == 1 and tokens[0].isdigit():
            continue  # a PTS point count
        break
    else:
        start = len(lines)
    # Past the header, single-integer lines are PTS counts (a PTS may hold several scans, each
    # with its count); np.loadtxt rejects any other non-numeric row with its position.
    body = []
    for number, raw in enumerate(lines[start:], start=start + 1):
        tokens = raw.split()
        if not tokens or tokens[0].startswith(("#", "//")):
            continue
        if len(tokens) > 1:
            body.append(raw)
        elif not tokens[0].isdigit():
            what = fmt.upper()
            raise InputError(f"{p}: corrupted {what}: line {number} is not a point: {tokens[0][:40]!r}")
    if not body:
        raise InputError(f"{p}: the {fmt.upper()} file holds no points")
    rows = _parse_rows(body, p, fmt.upper())
    if rows.shape[1] < 3:
        raise InputError(f"{p}: {fmt.upper()} rows need at least 3 columns (x y z), found {rows.shape[1]}")
    named = _columns_from_header(header, rows.shape[1])
    normals = colors = None
    if named:
        points = rows[:, [named["x"], named["y"], named["z"]]]
        if {"nx", "ny", "nz"} <= set(named):
            normals = rows[:, [named["nx"], named["ny"], named["nz"]]]
        if {"r", "g", "b"} <= set(named):
            colors = colors_to_unit(rows[:, [named["r"], named["g"], named["b"]]])
    else:
        points = rows[:, :3]
        normal_at, color_at = _guess_columns(rows, fmt)
        if normal_at is not None:
            normals = rows[:, normal_at:normal_at + 3]
        if color_at is not None:
            colors = colors_to_unit(rows[:, color_at:color_at + 3], np.dtype(np.uint8))
    return points, normals, colors


_PCD_TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("U", 1): "u1", ("U", 2): "<u2", ("U", 4): "<u4",
              ("U", 8): "<u8", ("I", 1): "i1", ("I", 2): "<i2", ("I", 4): "<i4", ("I", 8): "<i8"}


def _pcd_header(data: bytes, p: Path) -> tuple[dict[str, list[str]], int]:
    """The PCD header's fields (upper-case keys -> tokens) and the byte offset of the data."""
    fields: dict[str, list[str]] = {}
    pos = 0
    while True:
        end = data.find(b"\n", pos)
        if end < 0:
            raise InputError(f"{p}: corrupted PCD: the header has no DATA line")
        line = data[pos:end].decode("ascii", errors="replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *rest = line.split()
        fields[key.upper()] = rest
        if key.upper() == "DATA":
            return fields, pos
        if pos > 1 << 16:
            raise InputError(f"{p}: corrupted PCD: the header never ends")


def _pcd_frame(fields: dict[str, list[str]], n: int, p: Path, info: dict | None) -> None:
    """Record in ``info`` the organisation (``organized``: [width, height], for frames of more
    than one row) and the sensor pose (``viewpoint``: tx ty tz qw qx qy qz) the header gives."""
    if info is None:
        return
    try:
        width, height = int(fields["WIDTH"][0]), int(fields.get("HEIGHT", ["1"])[0])
    except (KeyError, IndexError, ValueError):
        width = height = 0
    if height > 1 and width * height == n:
        info["organized"] = [width, height]
    if "VIEWPOINT" in fields:
        try:
            pose = [float(v) for v in fields["VIEWPOINT"]]
        except ValueError:
            pose = []
        if len(pose) == 7 and all(np.isfinite(pose)):
            info["viewpoint"] = pose
        else:
            log.debug("%s: unreadable VIEWPOINT %s ignored", p, fields["VIEWPOINT"])


#: Most bytes one LZF byte can expand to (a 3-byte back-reference copies up to 264 bytes).
LZF_MAX_RATIO = 88


def _check_pcd_compressed(data: bytes, offset: int, n: int, point_bytes: tuple[int, int], p: Path) -> None:
    """Check the sizes a binary_compressed PCD's data block declares before open3d allocates them:
    the compressed block lies in the file, and its raw size is what ``n`` points take
    (``point_bytes``: with and without padding fields) and what LZF can expand the block to."""
    if len(data) < offset + 8:
        raise InputError(f"{p}: truncated PCD: the compressed data block has no size header")
    packed, raw = struct.unpack_from("<II", data, offset)
    have = len(data) - offset - 8
    if packed > have:
        raise InputError(f"{p}: truncated PCD: the compressed block declares {packed} bytes, the file "
                         f"holds {have}")
    if raw not in (n * point_bytes[0], n * point_bytes[1]):
        raise InputError(f"{p}: corrupted PCD: the header declares {n} points ({n * point_bytes[0]} bytes), "
                         f"the compressed block {raw} bytes")
    if raw > LZF_MAX_RATIO * packed + 64:
        raise InputError(f"{p}: corrupted PCD: {packed} compressed bytes cannot hold the {raw} bytes of "
                         f"{n} points")


def read_pcd(path: str | os.PathLike, info: dict | None = None) -> Arrays:
    """PCD v0.7 (``DATA ascii``, ``binary`` or ``binary_compressed``): x y z, optional
    normal_x/normal_y/normal_z and packed ``rgb``/``rgba``; rows stay in the file's order, NaN
    rows ("no measurement" in organised frames) included.

    ASCII and binary are parsed here strictly (open3d silently pads a truncated ASCII file);
    binary_compressed goes through open3d once its block sizes are checked, its point count
    checked against the header. With ``info``, the frame's organisation and viewpoint are
    recorded there (:func:`_pcd_frame`).
    """
    p = check_readable(path)
    data = p.read_bytes()
    fields, offset = _pcd_header(data, p)
    try:
        names = fields["FIELDS"]
        sizes = [int(s) for s in fields.get("SIZE", [])]
        types = [t.upper() for t in fields.get("TYPE", [])]
        counts = [int(c) for c in fields.get("COUNT", ["1"] * len(names))]
        n = int(fields["POINTS"][0]) if "POINTS" in fields else (
            int(fields["WIDTH"][0]) * int(fields.get("HEIGHT", ["1"])[0]))
        mode = fields["DATA"][0].lower()
    except (KeyError, IndexError, ValueError):
        raise InputError(f"{p}: corrupted PCD header (bad FIELDS/SIZE/TYPE/POINTS lines)") from None
    if not (len(names) == len(sizes) == len(types) == len(counts)) or not {"x", "y", "z"} <= set(names):
        raise InputError(f"{p}: corrupted PCD header: FIELDS/SIZE/TYPE/COUNT disagree or lack x y z")
    if n <= 0:
        raise InputError(f"{p}: the PCD holds no points")
    columns: list[tuple[str, str]] = []
    for name, size, typ, count in zip(names, sizes, types, counts, strict=True):
        code = _PCD_TYPES.get((typ, size))
        if code is None or count <= 0:
            raise InputError(f"{p}: corrupted PCD header: unsupported TYPE {typ} SIZE {size} COUNT {count}")
        columns += [(name if count == 1 else f"{name}_{i}", code) for i in range(count)]
        if name == "_":  # padding fields are legal and may repeat
            columns[-count:] = [(f"_pad{len(columns)}_{i}", code) for i in range(count)]
    dtype = np.dtype(columns)
    _pcd_frame(fields, n, p, info)
    if mode == "binary_compressed":
        unpadded = sum(s * c for name, s, c in zip(names, sizes, counts, strict=True) if name != "_")
        _check_pcd_compressed(data, offset, n, (dtype.itemsize, unpadded), p)
        return _read_pcd_open3d(p, n)
    if mode == "binary":
        need = n * dtype.itemsize
        have = len(data) - offset
        if have < need:
            raise InputError(f"{p}: truncated PCD: {have} data bytes, {n} points need {need}")
        table = np.frombuffer(data, dtype=dtype, count=n, offset=offset)
    elif mode == "ascii":
        if n > (len(data) - offset) // (2 * len(columns)):  # each value takes a digit and a separator
            raise InputError(f"{p}: truncated PCD: the header declares {n} points, the file holds "
                             f"{len(data) - offset} data bytes")
        lines = [ln for ln in data[offset:].decode("ascii", errors="replace").splitlines() if ln.strip()]
        if len(lines) < n:
            raise InputError(f"{p}: truncated PCD: {len(lines)} data rows for {n} points")
        rows = _parse_rows(lines[:n], p, "PCD")
        if rows.shape[1] != len(columns):
            raise InputError(f"{p}: corrupted PCD: {rows.shape[1]} values a row, the header {len(columns)}")
        table = np.empty(n, dtype=dtype)
        for i, (name, code) in enumerate(columns):
            if name in ("rgb", "rgba") and code == "<f4":
                table[name] = rows[:, i].astype(np.float32)  # a float whose bits pack the colour
            else:
                table[name] = rows[:, i]
    else:
        raise InputError(f"{p}: corrupted PCD header: unknown DATA mode {mode!r}")
    points = np.stack([table[c].astype(np.float64) for c in ("x", "y", "z")], axis=1)
    normals = colors = None
    if {"normal_x", "normal_y", "normal_z"} <= set(dtype.names):
        normals = np.stack([table[f"normal_{c}"].astype(np.float64) for c in "xyz"], axis=1)
    packed = next((c for c in ("rgb", "rgba") if c in dtype.names), None)
    if packed is not None:
        bits = np.ascontiguousarray(table[packed]).view(np.uint32) if dtype[packed].itemsize == 4 else None
        if bits is not None:
            rgb = np.stack([(bits >> 16) & 255, (bits >> 8) & 255, bits & 255], axis=1)
            colors = rgb.astype(np.float64) / 255.0
    return points, normals, colors


def _read_pcd_open3d(p: Path, n: int) -> Arrays:
    from ..syslibs import import_open3d
    o3d = import_open3d()

    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        pc = o3d.io.read_point_cloud(str(p), format="pcd")
    got = len(pc.points)
    if got != n:
        raise InputError(f"{p}: truncated or corrupted PCD: read {got} of the {n} points the header declares")
    points = np.asarray(pc.points, dtype=np.float64).copy()
    normals = np.asarray(pc.normals, dtype=np.float64).copy() if pc.has_normals() else None
    colors = np.asarray(pc.colors, dtype=np.float64).copy() if pc.has_colors() else None
    return points, normals, colors


#: Fewest bytes of a point record of each LAS point data format (0-10).
_LAS_RECORD = {0: 20, 1: 28, 2: 26, 3: 34, 4: 57, 5: 63, 6: 30, 7: 36, 8: 38, 9: 59, 10: 67}
#: Points decoded at a time: memory follows what the file really holds, not what it declares.
LAS_CHUNK = 1_000_000


def check_las_header(p: Path, head: bytes, size: int) -> tuple[int, bool]:
    """Validate a LAS/LAZ public header block before laspy reads anything; returns the declared
    point count and whether the points are LAZ-compressed.

    Every field that sizes a read is checked against the file: version 1.0-1.4, header size,
    offset to the points, the VLR count, point format and record length, scale factors, and for
    uncompressed points the declared count times the record length.
    """
    if len(head) < 227:
        raise InputError(f"{p}: truncated LAS: {size} bytes, shorter than the 227-byte header")
    major, minor = head[24], head[25]
    header_size, offset, n_vlrs = struct.unpack_from("<HII", head, 94)
    fmt_id, record = struct.unpack_from("<BH", head, 104)
    (legacy,) = struct.unpack_from("<I", head, 107)
    scales = struct.unpack_from("<3d", head, 131)
    offsets = struct.unpack_from("<3d", head, 155)
    if major != 1 or minor > 4:
        raise InputError(f"{p}: corrupted LAS header: version {major}.{minor} (1.0-1.4 are read)")
    least = 375 if minor >= 4 else 235 if minor == 3 else 227
    if not least <= header_size <= size or not header_size <= offset <= size:
        raise InputError(f"{p}: corrupted LAS header: header size {header_size} and point offset {offset} "
                         f"do not fit a {size}-byte file")
    if n_vlrs * 54 > offset - header_size:
        raise InputError(f"{p}: corrupted LAS header: {n_vlrs} variable-length records cannot fit in the "
                         f"{offset - header_size} bytes before the points")
    compressed = bool(fmt_id & 0x80) or bool(fmt_id & 0x40)
    point_format = fmt_id & 0x3F
    if point_format not in _LAS_RECORD or record < _LAS_RECORD[point_format]:
        raise InputError(f"{p}: corrupted LAS header: point format {point_format} with {record}-byte records")
    if not all(np.isfinite(scales)) or 0.0 in scales or not all(np.isfinite(offsets)):
        raise InputError(f"{p}: corrupted LAS header: scale factors {scales} and offsets {offsets}")
    count = legacy
    if minor >= 4:
        (count64,) = struct.unpack_from("<Q", head, 247)
        count = count64 or legacy
    if not compressed and offset + count * record > size:
        raise InputError(f"{p}: truncated or corrupted LAS: the header declares {count} points of {record} "
                         f"bytes, but the file holds {size - offset} bytes of points")
    return count, compressed


def read_las(path: str | os.PathLike) -> Arrays:
    """LAS (and LAZ when laspy has a backend): scaled x, y, z and RGB when the point format has it.

    The header is checked first (:func:`check_las_header`); points are then decoded
    :data:`LAS_CHUNK` at a time, so a LAZ file declaring far more points than it holds fails when
    its data ends, having allocated only what it held.
    """
    try:
        import laspy
    except ImportError:
        raise MissingExtraError("LAS input", "las", "laspy") from None
    p = check_readable(path)
    with open(p, "rb") as f:
        head = f.read(375)
    declared, _ = check_las_header(p, head, p.stat().st_size)
    xyz, rgb = [], []
    quiet = logging.getLogger("laspy")  # laspy logs its errors too: the exception says it once
    level = quiet.level
    quiet.setLevel(logging.CRITICAL)
    try:
        with laspy.open(str(p)) as reader:
            dims = set(reader.header.point_format.dimension_names)
            has_rgb = {"red", "green", "blue"} <= dims
            for chunk in reader.chunk_iterator(LAS_CHUNK):
                xyz.append(np.stack([np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)], axis=1))
                if has_rgb:
                    rgb.append(np.stack([np.asarray(chunk.red), np.asarray(chunk.green),
                                         np.asarray(chunk.blue)], axis=1))
    except MemoryError:
        raise
    except laspy.errors.LaspyException as exc:
        if "LazBackend" in str(exc) or "laz" in str(exc).lower() and "backend" in str(exc).lower():
            raise MissingExtraError("compressed LAZ input", "las", "lazrs") from None
        raise InputError(f"{p}: truncated or corrupted LAS ({first_line(exc)})") from None
    except Exception as exc:  # noqa: BLE001 - laspy and its LAZ backend raise many types on bad data
        raise InputError(f"{p}: truncated or corrupted LAS ({first_line(exc, typed=True)})") from None
    finally:
        quiet.setLevel(level)
    points = np.concatenate(xyz).astype(np.float64) if xyz else np.zeros((0, 3))
    if len(points) != declared:
        raise InputError(f"{p}: truncated LAS: {len(points)} of the {declared} declared points")
    colors = None
    if rgb:
        rgb_all = np.concatenate(rgb)
        if rgb_all.any():
            colors = colors_to_unit(rgb_all, rgb_all.dtype)
    return points, None, colors


def read_scan(path: str | os.PathLike, fmt: str, info: dict | None = None) -> Arrays:
    """Dispatch on ``fmt`` (``ply-points``, ``obj-points``, ``pcd``, ``xyz``, ``pts``, ``las``);
    readers that know more about the capture (a PCD's organisation and viewpoint) add it to
    ``info`` when given."""
    if fmt == "ply-points":
        return read_ply_points(path)
    if fmt == "obj-points":
        return read_obj_points(path)
    if fmt == "pcd":
        return read_pcd(path, info)
    if fmt in ("xyz", "pts"):
        return read_xyz(path, fmt)
    if fmt == "las":
        return read_las(path)
    raise InputError(f"{path}: {fmt!r} is not a point-cloud format")
