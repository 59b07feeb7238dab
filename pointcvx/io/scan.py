"""Point clouds without (trustworthy) normals: PLY vertices, OBJ ``v`` lines, PCD, XYZ/PTS, LAS.

Every reader returns ``(points, normals, colors)``: (n, 3) float64 points, (n, 3) float64 normals
or None, (n, 3) float64 colours in [0, 1] or None. :func:`cloud_from_points` then turns them into
an :class:`~pointcvx.cloud.OrientedCloud` with ``modality="scan"``:

1. non-finite coordinates are rejected (:class:`~pointcvx.errors.InputError` naming how many);
2. optional voxel down-sampling (points and colours averaged per voxel), and with ``n_points``
   a seeded thinning of very large inputs;
3. statistical outlier removal (mean distance to the k nearest neighbours above the global mean
   plus ``outlier_std`` standard deviations);
4. normals: PCA of the ``normal_neighbors`` nearest neighbours when the input has none;
5. a consistent outward sign: :func:`pointcvx.io.orient.orient_normals` (MST propagation, then a
   convex-hull vote per piece), then :func:`face_one_viewer`, which turns every piece of a partial
   (one-sided) scan towards the same viewer. Normals read from the file keep their sign when it
   is consistent with that result (:func:`orient_given_normals`).

``cloud.info`` records ``normals`` (how they were obtained), ``normals_flipped``,
``dropped_outliers``, ``one_sided`` and ``openness``, ``colors``, ``input_points`` and, when they
happened, ``voxel_downsampled_from`` and ``presampled_from``.
"""

from __future__ import annotations

import io
import logging
import os
import re
import struct
from pathlib import Path

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from ..cloud import OrientedCloud, check_extent, check_points
from ..errors import InputError, MissingExtraError
from .files import check_readable
from .orient import estimate_normals, orient_normals

log = logging.getLogger(__name__)

#: Orientation propagates signs over a k-NN graph of this many neighbours (at most).
ORIENT_NEIGHBORS = 12
#: With ``n_points`` set, inputs above this multiple of it are randomly thinned before the
#: neighbourhood work (outliers, normals, orientation), which is what costs time on big scans.
PRESAMPLE_FACTOR = 4
#: Share of points whose file normal may disagree with the propagated sign for the file's signs to
#: still count as consistent (kept as they are, or flipped as a whole).
GIVEN_NORMALS_TOLERANCE = 0.1
#: Area-weighted mean normal length above which an oriented piece counts as one-sided (a partial
#: view). Closed surfaces measure about 0 (0.01-0.1 on the dev scans, non-uniform sampling
#: included); single views of them 0.45-0.97.
ONE_SIDED_OPENNESS = 0.3

Arrays = tuple[np.ndarray, "np.ndarray | None", "np.ndarray | None"]


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
        msg = str(exc).splitlines()[0] if str(exc) else "unparseable number"
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


def read_pcd(path: str | os.PathLike) -> Arrays:
    """PCD v0.7 (``DATA ascii``, ``binary`` or ``binary_compressed``): x y z, optional
    normal_x/normal_y/normal_z and packed ``rgb``/``rgba``.

    ASCII and binary are parsed here strictly (open3d silently pads a truncated ASCII file);
    binary_compressed goes through open3d, its point count checked against the header.
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
    if mode == "binary_compressed":
        return _read_pcd_open3d(p, n)
    columns: list[tuple[str, str]] = []
    for name, size, typ, count in zip(names, sizes, types, counts, strict=True):
        code = _PCD_TYPES.get((typ, size))
        if code is None:
            raise InputError(f"{p}: corrupted PCD header: unsupported TYPE {typ} SIZE {size}")
        columns += [(name if count == 1 else f"{name}_{i}", code) for i in range(count)]
        if name == "_":  # padding fields are legal and may repeat
            columns[-count:] = [(f"_pad{len(columns)}_{i}", code) for i in range(count)]
    dtype = np.dtype(columns)
    if mode == "binary":
        need = n * dtype.itemsize
        have = len(data) - offset
        if have < need:
            raise InputError(f"{p}: truncated PCD: {have} data bytes, {n} points need {need}")
        table = np.frombuffer(data, dtype=dtype, count=n, offset=offset)
    elif mode == "ascii":
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


def read_las(path: str | os.PathLike) -> Arrays:
    """LAS (and LAZ when laspy has a backend): scaled x, y, z and RGB when the point format has it."""
    try:
        import laspy
    except ImportError:
        raise MissingExtraError("LAS input", "las", "laspy") from None
    p = check_readable(path)
    try:
        las = laspy.read(str(p))
    except laspy.errors.LaspyException as exc:
        if "LazBackend" in str(exc) or "laz" in str(exc).lower():
            raise MissingExtraError("compressed LAZ input", "las", "lazrs") from None
        raise InputError(f"{p}: corrupted LAS ({str(exc).splitlines()[0]})") from None
    except (ValueError, OSError, EOFError, struct.error, IndexError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"{p}: truncated or corrupted LAS ({msg})") from None
    declared = int(las.header.point_count)
    points = np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], axis=1).astype(np.float64)
    if len(points) != declared:
        raise InputError(f"{p}: truncated LAS: {len(points)} of the {declared} declared points")
    colors = None
    dims = set(las.point_format.dimension_names)
    if {"red", "green", "blue"} <= dims:
        rgb = np.stack([np.asarray(las.red), np.asarray(las.green), np.asarray(las.blue)], axis=1)
        if rgb.any():
            colors = colors_to_unit(rgb, rgb.dtype)
    return points, None, colors


def read_scan(path: str | os.PathLike, fmt: str) -> Arrays:
    """Dispatch on ``fmt`` (``ply-points``, ``obj-points``, ``pcd``, ``xyz``, ``pts``, ``las``)."""
    if fmt == "ply-points":
        return read_ply_points(path)
    if fmt == "obj-points":
        return read_obj_points(path)
    if fmt == "pcd":
        return read_pcd(path)
    if fmt in ("xyz", "pts"):
        return read_xyz(path, fmt)
    if fmt == "las":
        return read_las(path)
    raise InputError(f"{path}: {fmt!r} is not a point-cloud format")


# ---------------------------------------------------------------------------------------- filters
def statistical_outliers(points: np.ndarray, k: int = 20, std_ratio: float = 2.5) -> np.ndarray:
    """(n,) bool, True for points whose mean distance to their ``k`` nearest neighbours exceeds
    the mean of that statistic by more than ``std_ratio`` standard deviations (open3d's rule)."""
    n = len(points)
    if k <= 0 or n <= k + 1:
        return np.zeros(n, dtype=bool)
    dist, _ = cKDTree(points).query(points, k=k + 1, workers=-1)
    mean_d = dist[:, 1:].mean(axis=1)
    return mean_d > mean_d.mean() + std_ratio * mean_d.std()


def voxel_downsample(points: np.ndarray, size: float, normals: np.ndarray | None = None,
                     colors: np.ndarray | None = None) -> Arrays:
    """One point per occupied voxel of edge ``size``: the mean of its points (and colours).

    Normals are summed after aligning each to the voxel's first point's normal, then renormalised.
    Returns (m, 3) points, (m, 3) normals or None, (m, 3) colours or None, in voxel order.
    """
    keys = np.floor((points - points.min(axis=0)) / size).astype(np.int64)
    _, first, inverse, counts = np.unique(keys, axis=0, return_index=True, return_inverse=True,
                                          return_counts=True)
    inverse = inverse.ravel()
    m = len(counts)

    def mean(values: np.ndarray) -> np.ndarray:
        out = np.zeros((m, values.shape[1]))
        np.add.at(out, inverse, values)
        return out / counts[:, None]

    out_normals = None
    if normals is not None:
        ref = normals[first][inverse]
        signs = np.where(np.einsum("ij,ij->i", normals, ref) < 0, -1.0, 1.0)
        total = np.zeros((m, 3))
        np.add.at(total, inverse, normals * signs[:, None])
        length = np.linalg.norm(total, axis=1, keepdims=True)
        out_normals = np.where(length > 1e-12, total / np.where(length > 0, length, 1.0), normals[first])
    return mean(points), out_normals, None if colors is None else mean(colors)


def _consistent_pieces(points: np.ndarray, normals: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(n,) int labels of the pieces joined by k-NN edges whose normals agree in sign, and (n,)
    float area weights (squared mean neighbour distance: sparse points stand for more surface)."""
    n = len(points)
    dist, idx = cKDTree(points).query(points, k=k + 1, workers=-1)
    dist, idx = dist[:, 1:], idx[:, 1:]
    rows = np.repeat(np.arange(n), idx.shape[1])
    cols = idx.ravel()
    agree = np.einsum("ij,ij->i", normals[rows], normals[cols]) > 0
    graph = sparse.coo_matrix((np.ones(int(agree.sum())), (rows[agree], cols[agree])), shape=(n, n))
    _, labels = csgraph.connected_components(graph.tocsr(), directed=False)
    return labels, dist.mean(axis=1) ** 2


def face_one_viewer(points: np.ndarray, normals: np.ndarray, k: int = ORIENT_NEIGHBORS
                    ) -> tuple[np.ndarray, float, int]:
    """Re-sign the pieces of a one-sided scan so they all face the viewer of the largest piece.

    The convex-hull vote of :func:`orient_normals` is reliable for closed surfaces, but on a
    partial scan (one view of an object: an open patch whose back is missing) the far rim lies on
    the hull's back and votes the wrong way, so pieces separated by occlusion gaps can come out
    facing away from the sensor. A closed surface's area-weighted normals sum to zero, a one-sided
    patch's do not: when the largest consistently oriented piece has an area-weighted mean normal
    longer than ``ONE_SIDED_OPENNESS``, every other piece is flipped, if needed, to agree with it.

    Returns (n, 3) normals, the openness (length of that mean, 0..1) and how many were flipped.
    """
    if len(points) <= k + 1:
        return normals, 0.0, 0
    labels, area = _consistent_pieces(points, normals, k)
    main = labels == np.argmax(np.bincount(labels, weights=area))
    mean = (normals[main] * area[main, None]).sum(axis=0) / max(float(area[main].sum()), 1e-300)
    openness = float(np.linalg.norm(mean))
    if openness < ONE_SIDED_OPENNESS:
        return normals, openness, 0
    score = np.bincount(labels, weights=area * (normals @ (mean / openness)))
    flip = (score < 0)[labels]
    return np.where(flip[:, None], -normals, normals), openness, int(flip.sum())


def orient_scan_normals(points: np.ndarray, normals: np.ndarray, k: int = ORIENT_NEIGHBORS
                        ) -> tuple[np.ndarray, int, dict]:
    """Consistent outward (n, 3) normals for a scan: :func:`orient_normals`, then
    :func:`face_one_viewer`. Returns them, how many differ in sign from ``normals``, and details
    for ``info`` (``one_sided``, ``openness``)."""
    oriented, _ = orient_normals(points, normals, k=k)
    oriented, openness, _ = face_one_viewer(points, oriented, k=k)
    flipped = int(np.count_nonzero(np.einsum("ij,ij->i", oriented, normals) < 0))
    return oriented, flipped, {"one_sided": openness >= ONE_SIDED_OPENNESS, "openness": round(openness, 3)}


def orient_given_normals(points: np.ndarray, normals: np.ndarray, k: int = ORIENT_NEIGHBORS
                         ) -> tuple[np.ndarray, int, str, dict]:
    """Consistent outward normals starting from normals read from a file.

    :func:`orient_scan_normals` propagates signs and turns each piece outward. If the file's
    signs agree with that result on all but ``GIVEN_NORMALS_TOLERANCE`` of the points, the file
    was consistently oriented: its signs are kept (scanner normals face the sensor, and the few
    disagreements are more likely propagation mistakes). If they disagree on nearly all points,
    the file was consistent but inward: every normal is flipped. Otherwise the file's signs are
    unreliable and the propagated ones are used.

    Returns (n, 3) normals, how many were flipped, a description for ``info["normals"]`` and the
    details of :func:`orient_scan_normals`.
    """
    oriented, flipped, details = orient_scan_normals(points, normals, k=k)
    disagree = flipped / max(len(normals), 1)
    if disagree <= GIVEN_NORMALS_TOLERANCE:
        return normals, 0, "from file", details
    if disagree >= 1.0 - GIVEN_NORMALS_TOLERANCE:
        return -normals, len(normals), "from file, flipped outward (they pointed inward)", details
    return oriented, flipped, "from file, re-oriented (their signs were inconsistent)", details


# ---------------------------------------------------------------------------------------- cloud
def cloud_from_points(
    points: np.ndarray,
    normals: np.ndarray | None = None,
    colors: np.ndarray | None = None,
    *,
    outlier_neighbors: int = 20,
    outlier_std: float = 2.5,
    voxel_size: float | None = None,
    normal_neighbors: int = 24,
    n_points: int | None = None,
    seed: int = 0,
    modality: str = "scan",
    info: dict | None = None,
) -> OrientedCloud:
    """Clean (n, 3) ``points`` and give them consistent outward unit normals.

    Parameters
    ----------
    points : (n, 3) float
        Coordinates; NaN or infinite rows raise :class:`InputError`.
    normals : (n, 3) float, optional
        Normals read with the points; oriented with :func:`orient_given_normals`. Estimated by
        PCA when absent or when some are zero or non-finite.
    colors : (n, 3) float in [0, 1], optional
    outlier_neighbors, outlier_std : int, float
        Statistical outlier removal (:func:`statistical_outliers`); 0 neighbours disables it.
    voxel_size : float, optional
        Voxel down-sampling edge in the points' units (:func:`voxel_downsample`).
    normal_neighbors : int
        Neighbours of the PCA normal estimate.
    n_points : int, optional
        Cap on the output size: a seeded random subset (bigger inputs are thinned to
        ``PRESAMPLE_FACTOR * n_points`` before the neighbourhood work).
    seed : int
        Seed of the random thinning; everything else is deterministic.
    modality : str
        ``scan`` for scan files; ``points`` for bare arrays.
    info : dict, optional
        Extra provenance merged into the cloud's ``info``.

    Returns
    -------
    OrientedCloud
        In the input's units; ``info`` records normals source, flips, dropped outliers, etc.
    """
    pts = check_points(points)
    n_in = len(pts)
    meta: dict = dict(info or {})
    meta["input_points"] = n_in
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != pts.shape:
            raise InputError(f"normals must have shape {pts.shape}, got {normals.shape}")
        length = np.linalg.norm(normals, axis=1)
        bad = ~np.isfinite(length) | (length <= 1e-12)
        if bad.any():
            log.info("%d of %d given normals are zero or non-finite: estimating all normals",
                     int(bad.sum()), n_in)
            meta["invalid_file_normals"] = int(bad.sum())
            normals = None
        else:
            normals = normals / length[:, None]
    if colors is not None:
        colors = np.asarray(colors, dtype=np.float64)
        if colors.shape != pts.shape:
            raise InputError(f"colors must have shape {pts.shape}, got {colors.shape}")

    if voxel_size is not None:
        if not voxel_size > 0:
            raise InputError(f"voxel_size must be positive, got {voxel_size}")
        pts, normals, colors = voxel_downsample(pts, float(voxel_size), normals, colors)
        meta["voxel_downsampled_from"] = n_in
        log.debug("voxel %.4g: %d -> %d points", voxel_size, n_in, len(pts))

    if n_points is not None and len(pts) > PRESAMPLE_FACTOR * n_points:
        rng = np.random.default_rng(seed)
        keep = np.sort(rng.choice(len(pts), size=PRESAMPLE_FACTOR * n_points, replace=False))
        meta["presampled_from"] = len(pts)
        pts = pts[keep]
        normals = None if normals is None else normals[keep]
        colors = None if colors is None else colors[keep]

    outliers = statistical_outliers(pts, outlier_neighbors, outlier_std)
    meta["dropped_outliers"] = int(outliers.sum())
    if outliers.any():
        inliers = ~outliers
        pts = pts[inliers]
        normals = None if normals is None else normals[inliers]
        colors = None if colors is None else colors[inliers]
        log.debug("dropped %d statistical outliers", int(outliers.sum()))
    check_extent(pts)

    k_orient = min(ORIENT_NEIGHBORS, normal_neighbors, len(pts) - 1)
    if normals is None:
        k_pca = min(normal_neighbors, len(pts) - 1)
        normals = estimate_normals(pts, k=k_pca)
        normals, flipped, details = orient_scan_normals(pts, normals, k=k_orient)
        meta["normals"] = f"estimated (PCA k={k_pca}) + oriented"
    else:
        normals, flipped, how, details = orient_given_normals(pts, normals, k=k_orient)
        meta["normals"] = how
    meta.update(details)
    meta["normals_flipped"] = int(flipped)
    meta["colors"] = colors is not None
    cloud = OrientedCloud(pts, normals, colors=colors, modality=modality, info=meta)
    if n_points is not None:
        cloud = cloud.resample(n_points, seed=seed)
    return cloud


def load_scan_file(path: str | os.PathLike, fmt: str, opts) -> OrientedCloud:
    """Read a point-cloud file (``fmt`` from :func:`pointcvx.io.sniff.detect`) and orient it.

    ``opts`` is a :class:`pointcvx.io.options.LoadOptions`; the scan fields are passed to
    :func:`cloud_from_points`. The cloud stays in the file's units (``load`` normalises).
    """
    points, normals, colors = read_scan(path, fmt)
    log.debug("%s: read %d points (normals: %s, colours: %s)", path, len(points),
              normals is not None, colors is not None)
    try:
        return cloud_from_points(
            points, normals, colors,
            outlier_neighbors=opts.outlier_neighbors,
            outlier_std=opts.outlier_std,
            voxel_size=opts.voxel_size,
            normal_neighbors=opts.normal_neighbors,
            n_points=opts.n_points,
            seed=opts.seed,
            modality="scan",
            info={"source": str(path)},
        )
    except InputError as exc:  # name the file in checks that only know the arrays
        if str(path) in str(exc):
            raise
        raise type(exc)(f"{path}: {exc}") from None
