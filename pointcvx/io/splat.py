"""Gaussian splats (INRIA PLY, PlayCanvas compressed PLY, Niantic SPZ, antimatter15 .splat) -> clouds.

Every decoder returns the same plain dict of numpy arrays for ``n`` Gaussians:

``centers`` (n, 3) float64
    Gaussian means, in the file's units and the PLY (RDF) axis convention.
``scales`` (n, 3) float64
    Linear standard deviations along the Gaussian's local axes (``exp`` of stored log-scales).
``rotations`` (n, 4) float64
    Unit quaternions ``(w, x, y, z)``; column ``j`` of their matrix is local axis ``j``.
``opacity`` (n,) float64 in [0, 1]
    Sigmoid of the stored logit.
``colors`` (n, 3) float32 in [0, 1]
    Base colour from the SH DC term, ``0.5 + SH_C0 * f_dc``, clipped.
``normals`` (n, 3) float64, optional
    Only when the file stores ``nx ny nz``.

:func:`load_splat_file` turns them into an :class:`~pointcvx.cloud.OrientedCloud`: it drops
non-finite, nearly transparent and floating Gaussians and statistical outliers; takes as normal
the shortest axis of the local Gaussian mixture (a trained splat flattens onto the surface it
models, but single Gaussians are often badly turned, so each is mixed with its neighbours, see
:func:`mixture_normals`); makes the normals consistent and outward (sign propagation, then votes
of the directions each point is seen from, see :func:`orient_by_visibility`); and optionally
draws several surface samples per Gaussian.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gzip
import logging
import os
import struct
import zlib
from pathlib import Path

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from ..cloud import OrientedCloud
from ..errors import InputError, MissingExtraError
from .files import atomic_path, check_readable
from .options import LoadOptions
from .orient import knn, orient_normals
from .ply import read_ply, vertex_array

log = logging.getLogger(__name__)

#: Zeroth-order real spherical harmonic, the factor between ``f_dc`` and colour.
SH_C0 = 0.28209479177387814
#: SPZ stores colours as ``f_dc * 0.15 + 0.5`` (not SH_C0) to keep room for out-of-range values.
SPZ_COLOR_SCALE = 0.15
#: Gaussians per chunk of the PlayCanvas compressed PLY.
CHUNK_SIZE = 256
#: Largest SPZ point count accepted before allocating anything.
MAX_SPZ_POINTS = 100_000_000

#: Neighbours mixed with each Gaussian to find its normal (0: its own shortest axis only).
MIXTURE_NEIGHBORS = 16
#: Neighbours of the k-NN graph along which normal signs are propagated.
ORIENT_NEIGHBORS = 12
#: Directions the cloud is z-buffered from to tell the outside of each surface piece.
VISIBILITY_VIEWS = 32
# With a point budget (n_points) and one point per Gaussian, at most this many Gaussians times the
# budget (and at least WORK_MIN) go through filtering and normal estimation: the cloud is a
# uniform subset of them anyway, and normals from a uniform subset are as good.
WORK_FACTOR = 10
WORK_MIN = 200_000
NORMALS_NOTE = (f"smallest axis of the local Gaussian mixture (each Gaussian + {MIXTURE_NEIGHBORS} "
                "neighbours), oriented (MST propagation + hull vote, then visibility votes from "
                f"{VISIBILITY_VIEWS} directions)")

_ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"


# ---------------------------------------------------------------------------------------- maths
def _sigmoid(x: np.ndarray) -> np.ndarray:
    """(n,) float logistic function, overflow-free."""
    x = np.asarray(x, dtype=np.float64)
    out = np.empty_like(x)
    pos = x >= 0
    out[pos] = 1.0 / (1.0 + np.exp(-x[pos]))
    ex = np.exp(x[~pos])
    out[~pos] = ex / (1.0 + ex)
    return out


def _logit(p: np.ndarray) -> np.ndarray:
    """(n,) float inverse of the sigmoid, clipped away from 0 and 1."""
    p = np.clip(np.asarray(p, dtype=np.float64), 1e-6, 1.0 - 1e-6)
    return np.log(p / (1.0 - p))


def _dc_to_color(f_dc: np.ndarray) -> np.ndarray:
    """(n, 3) SH DC coefficients -> (n, 3) float32 colours in [0, 1]."""
    return np.clip(0.5 + SH_C0 * np.asarray(f_dc, dtype=np.float64), 0.0, 1.0).astype(np.float32)


def normalize_quaternions(q: np.ndarray) -> np.ndarray:
    """(n, 4) float quaternions scaled to unit length (zero ones become the identity)."""
    q = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    out = q / np.where(norm > 0, norm, 1.0)
    out[norm[:, 0] == 0] = (1.0, 0.0, 0.0, 0.0)
    return out


def quaternion_matrices(q: np.ndarray) -> np.ndarray:
    """(n, 4) quaternions ``(w, x, y, z)`` -> (n, 3, 3) rotation matrices (normalised first)."""
    w, x, y, z = normalize_quaternions(q).T
    m = np.empty((len(w), 3, 3))
    m[:, 0, 0] = 1 - 2 * (y * y + z * z)
    m[:, 0, 1] = 2 * (x * y - w * z)
    m[:, 0, 2] = 2 * (x * z + w * y)
    m[:, 1, 0] = 2 * (x * y + w * z)
    m[:, 1, 1] = 1 - 2 * (x * x + z * z)
    m[:, 1, 2] = 2 * (y * z - w * x)
    m[:, 2, 0] = 2 * (x * z - w * y)
    m[:, 2, 1] = 2 * (y * z + w * x)
    m[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return m


def _matrix_quaternion(m: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix -> (4,) unit quaternion ``(w, x, y, z)``."""
    t = np.trace(m)
    if t > 0:
        s = 2.0 * np.sqrt(1.0 + t)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k])
        q = np.zeros(4)
        q[0] = (m[k, j] - m[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (m[j, i] + m[i, j]) / s
        q[1 + k] = (m[k, i] + m[i, k]) / s
    q = np.asarray(q, dtype=np.float64)
    return q / np.linalg.norm(q)


def _quaternion_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions ``(w, x, y, z)``: (4,) or (n, 4) each, broadcast."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, dtype=np.float64), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, dtype=np.float64), -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def gaussian_normals(scales: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """(n, 3) unit normals: each Gaussian's shortest axis, rotated into world space (unoriented).

    Parameters
    ----------
    scales : (n, 3) float
        Per-axis extents (linear or log: only their order matters).
    rotations : (n, 4) float
        Quaternions ``(w, x, y, z)``.
    """
    mats = quaternion_matrices(rotations)
    axis = np.argmin(np.asarray(scales), axis=1)
    return mats[np.arange(len(mats)), :, axis]


def mixture_normals(centers: np.ndarray, scales: np.ndarray, rotations: np.ndarray,
                    weights: np.ndarray, k: int = 16, neighbors: np.ndarray | None = None,
                    chunk: int = 32768) -> np.ndarray:
    """(n, 3) unit normals (unoriented) of the local Gaussian mixture around each Gaussian.

    For Gaussian ``i`` and its ``k`` nearest neighbours ``j`` (weights ``w_j``, normalised), the
    mixture covariance is ``sum_j w_j (Sigma_j + (c_j - mu)(c_j - mu)^T)`` with
    ``Sigma_j = R_j diag(s_j^2) R_j^T``; the normal is its eigenvector of smallest eigenvalue. An
    isolated flat Gaussian gives its own shortest axis (``k = 0`` is exactly
    :func:`gaussian_normals`); in a crowd, the spread of the centres and the neighbours' shapes
    outvote a single badly oriented Gaussian.

    Parameters
    ----------
    centers : (n, 3) float
    scales : (n, 3) float
        Linear extents.
    rotations : (n, 4) float
        Quaternions ``(w, x, y, z)``.
    weights : (n,) float
        Non-negative mixture weights (opacity, say).
    k : int
        Neighbours besides the Gaussian itself.
    neighbors : (n, >= k) int, optional
        Precomputed nearest-neighbour indices (nearest first, self excluded), as :func:`knn`.
    """
    n = len(centers)
    k = int(min(k, n - 1))
    if k <= 0:
        return gaussian_normals(scales, rotations)
    idx = knn(centers, k)[1] if neighbors is None else neighbors[:, :k]
    idx = np.concatenate([np.arange(n)[:, None], idx], axis=1)
    mats = quaternion_matrices(rotations)
    sigma = np.einsum("nij,nj,nkj->nik", mats, np.asarray(scales, dtype=np.float64) ** 2, mats)
    w_all = np.maximum(np.asarray(weights, dtype=np.float64), 0.0)
    out = np.empty((n, 3))
    for start in range(0, n, chunk):
        nb = idx[start:start + chunk]
        w = w_all[nb]
        total = w.sum(axis=1, keepdims=True)
        w = np.where(total > 0, w / np.where(total > 0, total, 1.0), 1.0 / nb.shape[1])
        pts = centers[nb]
        d = pts - np.einsum("nk,nki->ni", w, pts)[:, None, :]
        cov = np.einsum("nk,nki,nkj->nij", w, d, d) + np.einsum("nk,nkij->nij", w, sigma[nb])
        out[start:start + chunk] = np.linalg.eigh(cov)[1][:, :, 0]
    return out


def _gaussians(centers, scales, rotations, opacity, colors, normals=None) -> dict[str, np.ndarray]:
    """The decoders' common output dict, with the documented dtypes."""
    out = {
        "centers": np.asarray(centers, dtype=np.float64).reshape(-1, 3),
        "scales": np.asarray(scales, dtype=np.float64).reshape(-1, 3),
        "rotations": normalize_quaternions(np.asarray(rotations, dtype=np.float64).reshape(-1, 4)),
        "opacity": np.clip(np.asarray(opacity, dtype=np.float64).reshape(-1), 0.0, 1.0),
        "colors": np.clip(np.asarray(colors, dtype=np.float32).reshape(-1, 3), 0.0, 1.0),
    }
    if normals is not None:
        out["normals"] = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    return out


def _sh_degree(n_rest: int) -> int:
    """SH degree from the number of ``f_rest_*`` coefficients (0, 9, 24, 45, 72)."""
    for degree in range(5):
        if 3 * ((degree + 1) ** 2 - 1) >= n_rest:
            return degree
    return 4


# ------------------------------------------------------------------------------- INRIA PLY
def _read_inria_ply(path) -> tuple[dict[str, np.ndarray], dict]:
    p = check_readable(path)
    data = read_ply(p)
    names = set(data["vertex"].data.dtype.names)
    need = ["x", "y", "z", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
            "opacity"]
    missing = [n for n in need if n not in names]
    if missing:
        raise InputError(f"{p}: not an INRIA splat PLY: the vertex element lacks {missing}")
    cols = vertex_array(data, tuple(need))
    if {"f_dc_0", "f_dc_1", "f_dc_2"} <= names:
        colors = _dc_to_color(vertex_array(data, ("f_dc_0", "f_dc_1", "f_dc_2")))
    elif {"red", "green", "blue"} <= names:
        colors = (vertex_array(data, ("red", "green", "blue")) / 255.0).astype(np.float32)
    else:
        colors = np.full((len(cols), 3), 0.5, dtype=np.float32)
    normals = None
    if {"nx", "ny", "nz"} <= names:
        normals = vertex_array(data, ("nx", "ny", "nz"))
    with np.errstate(over="ignore", invalid="ignore"):
        scales = np.exp(cols[:, 3:6])
    g = _gaussians(cols[:, 0:3], scales, cols[:, 6:10], _sigmoid(cols[:, 10]), colors, normals)
    n_rest = sum(1 for n in names if n.startswith("f_rest_"))
    degree = _sh_degree(n_rest)
    detail = f"INRIA 3DGS PLY ({len(names)} vertex properties, SH degree {degree})"
    return g, {"format_detail": detail, "sh_degree": degree}


def read_inria_ply(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Decode an INRIA 3DGS PLY; properties are looked up by name, so their order is free.

    Needs ``x y z scale_0..2 rot_0..3 opacity``; ``f_dc_0..2`` (or ``red green blue``),
    ``f_rest_*`` (any SH degree) and ``nx ny nz`` are optional. Returns the decoder dict (see the
    module docstring); :class:`InputError` when the file is truncated or lacks a property.
    """
    return _read_inria_ply(path)[0]


def write_inria_ply(path, centers, scales, rotations, opacity, colors, sh_degree: int = 0,
                    normals=False, rng: np.random.Generator | None = None) -> None:
    """Write Gaussians as a binary INRIA 3DGS PLY, atomically.

    Parameters
    ----------
    centers : (n, 3) float
    scales : (n, 3) float
        Linear; stored as their log.
    rotations : (n, 4) float
        ``(w, x, y, z)``, stored as given (not normalised).
    opacity : (n,) float in (0, 1)
        Stored as its logit.
    colors : (n, 3) float in [0, 1]
        Stored as ``f_dc = (color - 0.5) / SH_C0``.
    sh_degree : int
        Number of ``f_rest_*`` bands to add (zero-valued, ``3 * ((d + 1)^2 - 1)`` columns).
    normals : bool or (n, 3) float
        ``True`` adds zero ``nx ny nz`` columns as the INRIA trainer does; an array writes it.
    rng : numpy Generator, optional
        When given, the property order is shuffled with it (readers must look names up).
    """
    from plyfile import PlyData, PlyElement

    centers = np.asarray(centers, dtype=np.float64)
    n = len(centers)
    cols: dict[str, np.ndarray] = {}
    cols["x"], cols["y"], cols["z"] = centers.T
    if normals is not False and normals is not None:
        nrm = np.zeros((n, 3)) if normals is True else np.asarray(normals, dtype=np.float64)
        cols["nx"], cols["ny"], cols["nz"] = nrm.T
    f_dc = (np.asarray(colors, dtype=np.float64) - 0.5) / SH_C0
    for i in range(3):
        cols[f"f_dc_{i}"] = f_dc[:, i]
    for i in range(3 * ((sh_degree + 1) ** 2 - 1)):
        cols[f"f_rest_{i}"] = np.zeros(n)
    cols["opacity"] = _logit(opacity)
    log_scales = np.log(np.maximum(np.asarray(scales, dtype=np.float64), 1e-30))
    for i in range(3):
        cols[f"scale_{i}"] = log_scales[:, i]
    rot = np.asarray(rotations, dtype=np.float64)
    for i in range(4):
        cols[f"rot_{i}"] = rot[:, i]
    names = list(cols)
    if rng is not None:
        names = [names[i] for i in rng.permutation(len(names))]
    arr = np.empty(n, dtype=[(name, "<f4") for name in names])
    for name in names:
        arr[name] = cols[name]
    with atomic_path(path) as tmp:
        PlyData([PlyElement.describe(arr, "vertex")], text=False).write(str(tmp))


# -------------------------------------------------------------------------- compressed PLY
_CHUNK_PROPS = ("min_x", "min_y", "min_z", "max_x", "max_y", "max_z",
                "min_scale_x", "min_scale_y", "min_scale_z", "max_scale_x", "max_scale_y", "max_scale_z")
_CHUNK_COLOR_PROPS = ("min_r", "min_g", "min_b", "max_r", "max_g", "max_b")
_PACKED_PROPS = ("packed_position", "packed_rotation", "packed_scale", "packed_color")


def _unorm(values: np.ndarray, shift: int, bits: int) -> np.ndarray:
    """(n,) float in [0, 1]: the ``bits``-bit field at ``shift`` of (n,) uint32 ``values``."""
    mask = (1 << bits) - 1
    return ((values >> np.uint32(shift)) & np.uint32(mask)).astype(np.float64) / mask


def _unpack_11_10_11(values: np.ndarray) -> np.ndarray:
    """(n,) uint32 -> (n, 3) float in [0, 1]: x in bits 21-31, y in 11-20, z in 0-10."""
    return np.stack([_unorm(values, 21, 11), _unorm(values, 11, 10), _unorm(values, 0, 11)], axis=1)


def _unpack_compressed_rotation(values: np.ndarray) -> np.ndarray:
    """(n,) uint32 -> (n, 4) quaternions ``(w, x, y, z)`` from PlayCanvas 'smallest three'.

    Bits 30-31 give the index (in ``rot_0..rot_3`` order) of the largest component, which is
    positive and rebuilt from the unit norm; the other three follow in order as 10-bit fields
    (bits 20-29, 10-19, 0-9) mapping [0, 1] to [-1/sqrt(2), 1/sqrt(2)].
    """
    n = len(values)
    small = np.stack([_unorm(values, 20, 10), _unorm(values, 10, 10), _unorm(values, 0, 10)], axis=1)
    small = (small - 0.5) * np.sqrt(2.0)
    largest = np.sqrt(np.maximum(0.0, 1.0 - (small * small).sum(axis=1)))
    which = (values >> np.uint32(30)).astype(np.int64)
    q = np.empty((n, 4))
    slots = np.arange(4)[None, :]
    others = np.where(slots[:, :3] < which[:, None], slots[:, :3], slots[:, :3] + 1)  # (n, 3)
    rows = np.arange(n)[:, None]
    q[rows, others] = small
    q[np.arange(n), which] = largest
    return q


def _read_compressed_ply(path) -> tuple[dict[str, np.ndarray], dict]:
    p = check_readable(path)
    data = read_ply(p)
    elements = {e.name: e for e in data.elements}
    if "chunk" not in elements:
        raise InputError(f"{p}: not a compressed splat PLY: no 'chunk' element")
    chunk = elements["chunk"].data
    vert = elements["vertex"].data
    missing = [n for n in _CHUNK_PROPS if n not in chunk.dtype.names]
    missing += [n for n in _PACKED_PROPS if n not in vert.dtype.names]
    if missing:
        raise InputError(f"{p}: corrupted compressed splat PLY: missing properties {missing}")
    n = len(vert)
    n_chunks = -(-n // CHUNK_SIZE)
    if len(chunk) != n_chunks:
        raise InputError(
            f"{p}: corrupted compressed splat PLY: {len(chunk)} chunks for {n} splats "
            f"(expected {n_chunks})"
        )
    packed = {name: np.asarray(vert[name]).astype(np.uint32) for name in _PACKED_PROPS}
    ci = np.arange(n) // CHUNK_SIZE

    def chunk_cols(names):
        return np.stack([np.asarray(chunk[nm], dtype=np.float64)[ci] for nm in names], axis=1)

    lo, hi = chunk_cols(_CHUNK_PROPS[0:3]), chunk_cols(_CHUNK_PROPS[3:6])
    centers = lo + (hi - lo) * _unpack_11_10_11(packed["packed_position"])
    slo, shi = chunk_cols(_CHUNK_PROPS[6:9]), chunk_cols(_CHUNK_PROPS[9:12])
    with np.errstate(over="ignore", invalid="ignore"):
        scales = np.exp(slo + (shi - slo) * _unpack_11_10_11(packed["packed_scale"]))
    rotations = _unpack_compressed_rotation(packed["packed_rotation"])
    col = packed["packed_color"]
    rgb = np.stack([_unorm(col, 24, 8), _unorm(col, 16, 8), _unorm(col, 8, 8)], axis=1)
    has_colors = all(nm in chunk.dtype.names for nm in _CHUNK_COLOR_PROPS)
    if has_colors:
        clo, chi = chunk_cols(_CHUNK_COLOR_PROPS[0:3]), chunk_cols(_CHUNK_COLOR_PROPS[3:6])
        rgb = clo + (chi - clo) * rgb
    opacity = _unorm(col, 0, 8)
    degree = 0
    if "sh" in elements:
        degree = _sh_degree(len(elements["sh"].data.dtype.names))
    g = _gaussians(centers, scales, rotations, opacity, rgb)
    detail = (f"PlayCanvas compressed PLY ({n_chunks} chunks of {CHUNK_SIZE}"
              f"{', chunk colour ranges' if has_colors else ''}, SH degree {degree})")
    return g, {"format_detail": detail, "sh_degree": degree}


def read_compressed_ply(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Decode a PlayCanvas / SuperSplat compressed PLY.

    Layout: element ``chunk`` (one per 256 splats) with float ``min/max_x,y,z``,
    ``min/max_scale_x,y,z`` and optionally ``min/max_r,g,b``; element ``vertex`` with uint32
    ``packed_position`` (11-10-11 bits, lerped in the chunk box), ``packed_rotation`` (2-bit
    largest index + 3 x 10 bits, 'smallest three'), ``packed_scale`` (11-10-11, log-scale lerped in
    the chunk range) and ``packed_color`` (8-8-8-8 RGBA: colour lerped in the chunk colour range,
    alpha is the opacity). An ``sh`` element only sets the reported SH degree.
    """
    return _read_compressed_ply(path)[0]


# ------------------------------------------------------------------------------------ SPZ
def _zstd_ctypes():
    """``ZSTD_decompress`` from the system libzstd through ctypes, or None."""
    names = [ctypes.util.find_library("zstd"), "libzstd.so.1", "libzstd.dylib", "libzstd.dll"]
    for name in names:
        if not name:
            continue
        try:
            lib = ctypes.CDLL(name)
        except OSError:
            continue
        lib.ZSTD_decompress.restype = ctypes.c_size_t
        lib.ZSTD_decompress.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p, ctypes.c_size_t]
        lib.ZSTD_isError.restype = ctypes.c_uint
        lib.ZSTD_isError.argtypes = [ctypes.c_size_t]
        lib.ZSTD_getErrorName.restype = ctypes.c_char_p
        lib.ZSTD_getErrorName.argtypes = [ctypes.c_size_t]

        def decompress(data: bytes, size: int, _lib=lib) -> bytes:
            out = ctypes.create_string_buffer(max(size, 1))
            got = _lib.ZSTD_decompress(out, size, data, len(data))
            if _lib.ZSTD_isError(got):
                raise ValueError(_lib.ZSTD_getErrorName(got).decode("ascii", "replace"))
            return out.raw[:got]

        return decompress
    return None


def _zstd_decompressor():
    """A function ``(data, size) -> bytes`` decoding one zstd frame of ``size`` output bytes.

    Tries the ``zstandard`` package, ``compression.zstd`` (Python 3.14) or its backport,
    ``pyzstd``, then the system libzstd through ctypes; :class:`MissingExtraError` if none.
    """
    try:
        import zstandard

        def with_zstandard(data: bytes, size: int) -> bytes:
            try:
                return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
            except zstandard.ZstdError as exc:
                raise ValueError(str(exc)) from None

        return with_zstandard
    except ImportError:
        pass
    for module in ("compression.zstd", "backports.zstd", "pyzstd"):
        try:
            mod = __import__(module, fromlist=["decompress"])
        except ImportError:
            continue
        error = getattr(mod, "ZstdError", ValueError)

        def with_module(data: bytes, size: int, _mod=mod, _error=error) -> bytes:
            try:
                return _mod.decompress(data)
            except (_error, EOFError) as exc:
                raise ValueError(str(exc)) from None

        return with_module
    found = _zstd_ctypes()
    if found is None:
        raise MissingExtraError("SPZ version 4 (zstd-compressed) files", "spz", "zstandard")
    return found


def _unpack_spz_positions(raw: np.ndarray, n: int, fractional_bits: int) -> np.ndarray:
    """(n * 9,) uint8 little-endian signed 24-bit fixed point -> (n, 3) float."""
    b = raw.reshape(n, 3, 3).astype(np.int32)
    fixed = b[..., 0] | (b[..., 1] << 8) | (b[..., 2] << 16)
    fixed = np.where(fixed & 0x800000, fixed - (1 << 24), fixed)
    return fixed.astype(np.float64) / float(1 << fractional_bits)


def _unpack_spz_smallest_three(raw: np.ndarray, n: int) -> np.ndarray:
    """(n * 4,) uint8 -> (n, 4) ``(w, x, y, z)``: SPZ v3+ quaternions, stored ``x y z w``.

    A little-endian uint32 holds the largest component's index (bits 30-31, in x y z w order) and,
    from the highest index down, each other component as 9 magnitude bits (scaled to
    [0, 1/sqrt(2)]) and a sign bit, lowest bits last.
    """
    comp = raw.reshape(n, 4).astype(np.uint32)
    comp = comp[:, 0] | (comp[:, 1] << 8) | (comp[:, 2] << 16) | (comp[:, 3] << 24)
    largest = (comp >> np.uint32(30)).astype(np.int64)
    xyzw = np.zeros((n, 4))
    for i in range(3, -1, -1):
        take = largest != i
        mag = (comp & np.uint32(511)).astype(np.float64) * (np.sqrt(0.5) / 511.0)
        neg = ((comp >> np.uint32(9)) & np.uint32(1)).astype(bool)
        xyzw[take, i] = np.where(neg, -mag, mag)[take]
        comp = np.where(take, comp >> np.uint32(10), comp)
    rest = (xyzw * xyzw).sum(axis=1)
    xyzw[np.arange(n), largest] = np.sqrt(np.maximum(0.0, 1.0 - rest))
    return xyzw[:, [3, 0, 1, 2]]


def _unpack_spz_first_three(raw: np.ndarray, n: int) -> np.ndarray:
    """(n * 3,) uint8 -> (n, 4) ``(w, x, y, z)``: SPZ v1/v2 xyz bytes, w >= 0 rebuilt."""
    xyz = raw.reshape(n, 3).astype(np.float64) / 127.5 - 1.0
    w = np.sqrt(np.maximum(0.0, 1.0 - (xyz * xyz).sum(axis=1)))
    return np.concatenate([w[:, None], xyz], axis=1)


def _spz_sh_dim(degree: int) -> int:
    """SH coefficients per colour channel beyond DC for ``degree`` (0, 3, 8, 15, 24)."""
    return (degree + 1) ** 2 - 1


# Axis directions in a right-handed world frame (Right=+x, Up=+y, Back=+z).
_AXIS_DIRECTION = {"R": (1, 0, 0), "L": (-1, 0, 0), "U": (0, 1, 0), "D": (0, -1, 0),
                   "B": (0, 0, 1), "F": (0, 0, -1)}
SPZ_COORDINATE_EXTENSION = 0xADBE0003
# The reference library's CoordinateSystem enum (include/spz/splat-types.h); 0 means unspecified.
_SPZ_COORDINATES = {1: "LDB", 2: "RDB", 3: "LUB", 4: "RUB", 5: "LDF", 6: "RDF", 7: "LUF", 8: "RUF",
                    9: "LFD", 10: "RFD", 11: "LFU", 12: "RFU", 13: "LBD", 14: "RBD", 15: "LBU",
                    16: "RBU"}


def _axes_change(source: str, target: str = "RDF") -> np.ndarray:
    """(3, 3) float signed permutation taking coordinates in ``source`` axes to ``target`` axes."""
    def basis(name):
        return np.array([_AXIS_DIRECTION[c] for c in name], dtype=np.float64).T

    return basis(target).T @ basis(source)


def _to_ply_axes(g: dict[str, np.ndarray], source: str) -> None:
    """Convert centres and rotations of ``g`` in place from ``source`` axes to PLY's RDF."""
    m = _axes_change(source)
    if np.allclose(m, np.eye(3)):
        return
    g["centers"] = g["centers"] @ m.T
    if "normals" in g:
        g["normals"] = g["normals"] @ m.T
    # The covariance R S^2 R^T must become M R S^2 R^T M^T. With P = det(M) M (a rotation), P R
    # does it; for pure axis flips M R M^T = P R P^T does too and keeps the reference library's
    # quaternions (w unchanged, x y z flipped).
    rot = _matrix_quaternion(m * np.sign(np.linalg.det(m)))
    q = _quaternion_product(rot, g["rotations"])
    if np.allclose(np.abs(np.diag(m)), 1.0):
        q = _quaternion_product(q, rot * np.array([1.0, -1.0, -1.0, -1.0]))
    g["rotations"] = q


def _spz_arrays(p: Path, n: int, fractional_bits: int, smallest_three: bool, float16: bool,
                streams: list[np.ndarray]) -> dict[str, np.ndarray]:
    """Decode the five attribute byte arrays (positions, alphas, colours, scales, rotations)."""
    pos_raw, alpha_raw, color_raw, scale_raw, rot_raw = streams
    if float16:
        centers = pos_raw.view("<f2").reshape(n, 3).astype(np.float64)
    else:
        centers = _unpack_spz_positions(pos_raw, n, fractional_bits)
    opacity = alpha_raw.astype(np.float64) / 255.0
    f_dc = (color_raw.reshape(n, 3).astype(np.float64) / 255.0 - 0.5) / SPZ_COLOR_SCALE
    scales = np.exp(scale_raw.reshape(n, 3).astype(np.float64) / 16.0 - 10.0)
    if smallest_three:
        rotations = _unpack_spz_smallest_three(rot_raw, n)
    else:
        rotations = _unpack_spz_first_three(rot_raw, n)
    return _gaussians(centers, scales, rotations, opacity, _dc_to_color(f_dc))


def _spz_sizes(n: int, degree: int, version: int) -> list[int]:
    """Byte sizes of the SPZ attribute arrays: positions, alphas, colours, scales, rotations, SH."""
    return [n * (6 if version == 1 else 9), n, 3 * n, 3 * n, n * (4 if version >= 3 else 3),
            n * 3 * _spz_sh_dim(degree)]


def _parse_legacy_spz(p: Path, buf: bytes) -> tuple[dict[str, np.ndarray], dict]:
    """SPZ v1-v3 payload (already decompressed): 16-byte header, extensions, then the arrays."""
    if len(buf) < 16:
        raise InputError(f"{p}: truncated SPZ: {len(buf)} bytes is shorter than the 16-byte header")
    magic, version, n, degree, frac, flags, _ = struct.unpack_from("<4sIIBBBB", buf, 0)
    if magic != b"NGSP":
        raise InputError(f"{p}: corrupted SPZ: bad magic {magic!r} (expected b'NGSP')")
    if not 1 <= version <= 3:
        raise InputError(f"{p}: unsupported SPZ version {version} in a gzip container (expected 1-3)")
    if n > MAX_SPZ_POINTS or degree > 4:
        raise InputError(f"{p}: corrupted SPZ header ({n} points, SH degree {degree})")
    sizes = _spz_sizes(n, degree, version)
    start = len(buf) - sum(sizes)  # extension records, if any, sit between header and data
    if start < 16 or (start > 16 and not flags & 0x2):
        if start < 16:
            raise InputError(
                f"{p}: truncated SPZ: {len(buf)} bytes hold less than the {16 + sum(sizes)} "
                f"bytes {n} Gaussians need"
            )
        log.warning("%s: %d unexpected bytes after the SPZ header ignored", p, start - 16)
    arrays, offset = [], start
    for size in sizes[:5]:
        arrays.append(np.frombuffer(buf, dtype=np.uint8, count=size, offset=offset))
        offset += size
    g = _spz_arrays(p, n, frac, version >= 3, version == 1, arrays)
    _to_ply_axes(g, "RUB")
    detail = f"Niantic SPZ v{version} (gzip, {n} Gaussians, SH degree {degree}, RUB -> RDF axes)"
    return g, {"format_detail": detail, "sh_degree": int(degree)}


def _spz_coordinate_extension(p: Path, raw: bytes, start: int, end: int) -> str:
    """The axes declared by an SPZ v4 coordinate-system extension record, or ``RUB``.

    v4 extension records are ``uint32 type, uint32 byte length, payload``; the coordinate system
    (type ``0xADBE0003``) carries one uint32 value of the reference library's enum.
    """
    offset = start
    while offset + 8 <= end:
        kind, length = struct.unpack_from("<II", raw, offset)
        if offset + 8 + length > end:
            break
        if kind == SPZ_COORDINATE_EXTENSION and length >= 4:
            (value,) = struct.unpack_from("<I", raw, offset + 8)
            if value in _SPZ_COORDINATES:
                return _SPZ_COORDINATES[value]
            log.warning("%s: unknown SPZ coordinate system %d; assuming RUB", p, value)
        offset += 8 + length
    return "RUB"


def _parse_ngsp_v4(p: Path, raw: bytes) -> tuple[dict[str, np.ndarray], dict]:
    """SPZ v4: 32-byte plain header, optional extensions, a table of streams, zstd streams.

    Header (little-endian): magic ``NGSP``, uint32 version, uint32 numPoints, uint8 shDegree,
    uint8 fractionalBits, uint8 flags, uint8 numStreams, uint32 tocByteOffset, 12 reserved bytes.
    At ``tocByteOffset``: ``numStreams`` x (uint64 compressed size, uint64 uncompressed size), then
    the zstd frames back to back, in the order positions, alphas, colours, scales, rotations, SH
    (empty streams are left out).
    """
    if len(raw) < 32:
        raise InputError(f"{p}: truncated SPZ: {len(raw)} bytes is shorter than the 32-byte header")
    _, version, n, degree, frac, flags, n_streams, toc = struct.unpack_from("<4sIIBBBBI", raw, 0)
    if n > MAX_SPZ_POINTS or degree > 4 or frac > 23:
        raise InputError(f"{p}: corrupted SPZ header ({n} points, SH degree {degree})")
    if toc < 32 or toc + 16 * n_streams > len(raw):
        raise InputError(f"{p}: truncated SPZ: the stream table lies past the end of the file")
    table = np.frombuffer(raw, dtype="<u8", count=2 * n_streams, offset=toc).reshape(-1, 2)
    expected = [s for s in _spz_sizes(n, degree, version) if s > 0]
    if n_streams != len(expected) or not np.array_equal(table[:, 1], expected):
        raise InputError(
            f"{p}: corrupted SPZ: stream sizes {table[:, 1].tolist()} do not fit {n} Gaussians "
            f"of SH degree {degree} (expected {expected})"
        )
    offset = toc + 16 * n_streams
    if offset + int(table[:, 0].sum()) > len(raw):
        raise InputError(
            f"{p}: truncated SPZ: the streams need {offset + int(table[:, 0].sum())} bytes, "
            f"the file has {len(raw)}"
        )
    decompress = _zstd_decompressor()
    arrays = []
    for i, (csize, usize) in enumerate(table[:5].tolist()):
        chunk = raw[offset:offset + csize]
        offset += csize
        try:
            out = decompress(chunk, usize)
        except ValueError as exc:
            raise InputError(f"{p}: corrupted SPZ: zstd stream {i} does not decode ({exc})") from None
        if len(out) != usize:
            raise InputError(f"{p}: corrupted SPZ: zstd stream {i} gives {len(out)} bytes, not {usize}")
        arrays.append(np.frombuffer(out, dtype=np.uint8))
    g = _spz_arrays(p, n, frac, True, False, arrays)
    axes = _spz_coordinate_extension(p, raw, 32, toc) if flags & 0x2 else "RUB"
    _to_ply_axes(g, axes)
    detail = (f"Niantic SPZ v{version} (zstd, {n_streams} streams, {n} Gaussians, "
              f"SH degree {degree}, {axes} -> RDF axes)")
    return g, {"format_detail": detail, "sh_degree": int(degree)}


def _read_spz(path) -> tuple[dict[str, np.ndarray], dict]:
    p = check_readable(path)
    raw = p.read_bytes()
    if raw[:2] == b"\x1f\x8b":
        try:
            buf = gzip.decompress(raw)
        except (OSError, EOFError, zlib.error) as exc:
            raise InputError(f"{p}: truncated or corrupted SPZ gzip stream ({exc})") from None
        return _parse_legacy_spz(p, buf)
    if raw[:4] == _ZSTD_MAGIC:  # a legacy payload wrapped in one zstd frame (third-party writers)
        try:
            buf = _zstd_decompressor()(raw, 64 * len(raw) + (1 << 20))
        except ValueError as exc:
            raise InputError(f"{p}: truncated or corrupted SPZ zstd stream ({exc})") from None
        return _parse_legacy_spz(p, buf)
    if raw[:4] != b"NGSP":
        raise InputError(f"{p}: not an SPZ file (no gzip, zstd or 'NGSP' magic)")
    if len(raw) < 8:
        raise InputError(f"{p}: truncated SPZ header")
    (version,) = struct.unpack_from("<I", raw, 4)
    if version >= 4:
        if version > 4:
            log.warning("%s: SPZ version %d is newer than 4; decoding it as version 4", p, version)
        return _parse_ngsp_v4(p, raw)
    return _parse_legacy_spz(p, raw)  # an uncompressed legacy payload


def read_spz(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Decode a Niantic SPZ file (versions 1-3 gzip-wrapped, version 4 zstd multi-stream).

    Positions are 24-bit fixed point with ``fractionalBits``, alphas uint8 after the sigmoid,
    colours uint8 ``f_dc * 0.15 + 0.5``, scales uint8 log-scale ``v / 16 - 10``, rotations 3 bytes
    ``xyz`` (v1/v2) or 4 bytes 'smallest three' (v3+). SPZ stores RUB axes (OpenGL); the result is
    converted to the PLY convention (RDF: y and z negated), as the reference library does when
    writing PLY, unless a v4 coordinate-system extension says otherwise. Version 4 needs a zstd
    decoder (see :func:`_zstd_decompressor`).
    """
    return _read_spz(path)[0]


def write_spz(path, centers, scales, rotations, opacity, colors, version: int = 3,
              fractional_bits: int = 12) -> None:
    """Write Gaussians as a gzip-wrapped SPZ of version 2 or 3 (SH degree 0), atomically.

    Inputs are in PLY (RDF) axes like the decoder's output; they are stored in SPZ's RUB axes.
    Mostly for tests: it follows the reference packer's quantisation.
    """
    if version not in (2, 3):
        raise ValueError("write_spz writes SPZ versions 2 and 3")
    g = _gaussians(centers, scales, rotations, opacity, colors)
    _to_ply_axes(g, "RUB")  # RUB <-> RDF is its own inverse
    n = len(g["centers"])
    fixed = np.round(g["centers"] * (1 << fractional_bits)).astype(np.int64).reshape(-1)
    pos = np.stack([fixed & 0xFF, (fixed >> 8) & 0xFF, (fixed >> 16) & 0xFF], axis=1).astype(np.uint8)
    alpha = np.clip(np.round(g["opacity"] * 255.0), 0, 255).astype(np.uint8)
    f_dc = (g["colors"].astype(np.float64) - 0.5) / SH_C0
    color = np.clip(np.round(f_dc * SPZ_COLOR_SCALE * 255.0 + 127.5), 0, 255).astype(np.uint8)
    scale = np.clip(np.round((np.log(np.maximum(g["scales"], 1e-30)) + 10.0) * 16.0), 0, 255)
    xyzw = g["rotations"][:, [1, 2, 3, 0]]
    if version == 2:
        xyzw = xyzw * np.where(xyzw[:, 3:] < 0, -1.0, 1.0)
        rot = np.clip(np.round(xyzw[:, :3] * 127.5 + 127.5), 0, 255).astype(np.uint8)
    else:
        largest = np.argmax(np.abs(xyzw), axis=1)
        xyzw = xyzw * np.where(xyzw[np.arange(n), largest] < 0, -1.0, 1.0)[:, None]
        comp = largest.astype(np.uint64)
        for i in range(4):
            take = largest != i
            mag = np.round(511.0 * np.abs(xyzw[:, i]) / np.sqrt(0.5)).astype(np.uint64)
            bits = ((xyzw[:, i] < 0).astype(np.uint64) << np.uint64(9)) | np.minimum(mag, 511)
            comp = np.where(take, (comp << np.uint64(10)) | bits, comp)
        comp = comp.astype(np.uint32)
        rot = np.stack([(comp >> np.uint32(s)) & np.uint32(0xFF) for s in (0, 8, 16, 24)], axis=1)
        rot = rot.astype(np.uint8)
    header = struct.pack("<4sIIBBBB", b"NGSP", version, n, 0, fractional_bits, 0, 0)
    payload = b"".join([header, pos.tobytes(), alpha.tobytes(), color.tobytes(),
                        scale.astype(np.uint8).tobytes(), rot.tobytes()])
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(gzip.compress(payload))


# ------------------------------------------------------------------------------ .splat
_DOT_SPLAT_DTYPE = np.dtype([("pos", "<f4", (3,)), ("scale", "<f4", (3,)), ("rgba", "u1", (4,)),
                             ("rot", "u1", (4,))])


def _read_dot_splat(path) -> tuple[dict[str, np.ndarray], dict]:
    p = check_readable(path)
    raw = p.read_bytes()
    if len(raw) % _DOT_SPLAT_DTYPE.itemsize:
        raise InputError(
            f"{p}: truncated .splat file ({len(raw)} bytes is not a multiple of "
            f"{_DOT_SPLAT_DTYPE.itemsize})"
        )
    rec = np.frombuffer(raw, dtype=_DOT_SPLAT_DTYPE)
    rgba = rec["rgba"].astype(np.float64) / 255.0
    rotations = (rec["rot"].astype(np.float64) - 128.0) / 128.0
    g = _gaussians(rec["pos"], np.abs(rec["scale"].astype(np.float64)), rotations, rgba[:, 3],
                   rgba[:, :3])
    return g, {"format_detail": f"antimatter15 .splat ({len(rec)} records of 32 bytes)", "sh_degree": 0}


def read_dot_splat(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Decode an antimatter15 ``.splat``: headerless 32-byte records.

    Each record: 3 float32 position, 3 float32 linear scale, 4 uint8 RGBA (alpha is the opacity),
    4 uint8 rotation ``(w, x, y, z)`` stored as ``q * 128 + 128``.
    """
    return _read_dot_splat(path)[0]


def write_dot_splat(path, centers, scales, rotations, opacity, colors) -> None:
    """Write Gaussians as an antimatter15 ``.splat`` (inverse of :func:`read_dot_splat`), atomically."""
    centers = np.asarray(centers, dtype=np.float64)
    rec = np.zeros(len(centers), dtype=_DOT_SPLAT_DTYPE)
    rec["pos"] = centers
    rec["scale"] = np.asarray(scales, dtype=np.float64)
    rgba = np.concatenate([np.asarray(colors, dtype=np.float64).reshape(-1, 3),
                           np.asarray(opacity, dtype=np.float64).reshape(-1, 1)], axis=1)
    rec["rgba"] = np.clip(np.round(rgba * 255.0), 0, 255).astype(np.uint8)
    q = normalize_quaternions(rotations)
    rec["rot"] = np.clip(np.round(q * 128.0 + 128.0), 0, 255).astype(np.uint8)
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(rec.tobytes())


# ------------------------------------------------------------------------------ filters
def finite_mask(g: dict[str, np.ndarray]) -> np.ndarray:
    """(n,) bool: Gaussians whose centre, scales, rotation and opacity are all finite."""
    ok = np.isfinite(g["centers"]).all(axis=1)
    ok &= np.isfinite(g["scales"]).all(axis=1)
    ok &= np.isfinite(g["rotations"]).all(axis=1)
    ok &= np.isfinite(g["opacity"])
    return ok


def floater_mask(points: np.ndarray, ratio: float, k: int = 8, factor: float = 4.0) -> np.ndarray:
    """(n,) bool keeping points whose cluster holds at least ``ratio`` of all points.

    Clusters are connected components of the k-nearest-neighbour graph with edges longer than
    ``factor`` x the median k-th neighbour distance cut. When no cluster is big enough, the
    largest one is kept.
    """
    n = len(points)
    keep = np.ones(n, dtype=bool)
    if ratio <= 0 or n <= k + 1:
        return keep
    dist, idx = knn(points, k)
    radius = factor * float(np.median(dist[:, -1]))
    edges = dist.ravel() <= radius
    rows = np.repeat(np.arange(n), idx.shape[1])[edges]
    graph = sparse.coo_matrix((np.ones(int(edges.sum())), (rows, idx.ravel()[edges])), shape=(n, n))
    _, labels = csgraph.connected_components(graph, directed=False)
    sizes = np.bincount(labels)
    big = sizes >= ratio * n
    if not big.any():
        big[np.argmax(sizes)] = True
    return big[labels]


def outlier_mask(points: np.ndarray, k: int, std: float) -> np.ndarray:
    """(n,) bool: statistical outlier removal (mean k-NN distance within mean + std x sigma)."""
    n = len(points)
    if k <= 0 or n <= k + 1:
        return np.ones(n, dtype=bool)
    dist, _ = knn(points, k)
    mean = dist.mean(axis=1)
    return mean <= mean.mean() + std * mean.std()


def gaussian_weights(g: dict[str, np.ndarray]) -> np.ndarray:
    """(n,) float importance of each Gaussian: opacity x geometric mean of its three scales."""
    return g["opacity"] * np.cbrt(np.prod(np.maximum(g["scales"], 0.0), axis=1))


def _subset(g: dict[str, np.ndarray], keep: np.ndarray) -> dict[str, np.ndarray]:
    return {k: v[keep] for k, v in g.items()}


def view_directions(m: int) -> np.ndarray:
    """(m, 3) unit vectors spread evenly over the sphere (Fibonacci lattice)."""
    i = np.arange(m) + 0.5
    polar = np.arccos(1.0 - 2.0 * i / m)
    azimuth = np.pi * (1.0 + np.sqrt(5.0)) * i
    return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)],
                    axis=1)


def visibility_votes(points: np.ndarray, normals: np.ndarray, views: int = VISIBILITY_VIEWS,
                     pixel: float = 2.0, spacing: float | None = None,
                     depth_tolerance: float = 3.0, layer_gap: float = 2.0) -> np.ndarray:
    """(n,) float: how strongly each normal faces the directions its point is seen from.

    The points are z-buffered orthographically from ``views`` directions ``v`` around the cloud,
    with square pixels ``pixel`` x the median distance to the 4th neighbour (``spacing``), so the
    splat looks closed. In each pixel, going back from the front-most point, the points of the
    first layer are seen from ``v``: those before the first depth gap wider than ``layer_gap``
    spacings, at most ``depth_tolerance`` pixels behind the front. Each votes ``n . v``.
    Outward normals face the outside, where an onlooker stands, so a positive sum means
    'outward'; thin parts (a guitar neck) get their two sides right, which sign propagation
    along a neighbour graph cannot. Zero for points never seen.

    Why layers: Gaussian centres scatter in depth, so a tolerance of a few pixels finds more of
    a noisy front surface, but a plain tolerance also takes the far side of a thin wall. On the
    bundled mug splat (a cup wall 3.7 spacings thick) a two-pixel tolerance without the gap
    test got 85 % of the normals right (52 % on the cup's inner wall), one pixel 98 %; the
    gap test keeps 98 % at three pixels, where a tolerance alone helps real splats (the dev
    donut's normals agree with its torus 95 %, 93 % with one pixel).
    """
    n = len(points)
    votes = np.zeros(n)
    if n < 5:
        return votes
    if spacing is None:
        spacing = float(np.median(knn(points, 4)[0][:, -1]))
    centered = points - points.mean(axis=0)
    extent = float(np.linalg.norm(centered, axis=1).max())
    h = max(pixel * spacing, extent / 2048.0, 1e-12)
    # (A spacing of 0, from duplicated centres, would make every step a gap.)
    gap = layer_gap * max(spacing, h / pixel)
    for v in view_directions(views):
        a = np.cross(v, (1.0, 0.0, 0.0) if abs(v[0]) < 0.9 else (0.0, 1.0, 0.0))
        a /= np.linalg.norm(a)
        b = np.cross(v, a)
        u = np.floor(centered @ a / h).astype(np.int64)
        w = np.floor(centered @ b / h).astype(np.int64)
        u -= u.min()
        w -= w.min()
        key = u * (int(w.max()) + 1) + w
        depth = centered @ v  # larger is nearer to an onlooker far out along +v
        seen = np.zeros(n, dtype=bool)
        seen[_first_layer(key, depth, gap, depth_tolerance * h)] = True
        votes[seen] += normals[seen] @ v
    return votes


def _first_layer(key: np.ndarray, depth: np.ndarray, gap: float, tolerance: float) -> np.ndarray:
    """Indices of the points in the front layer of their pixel: (n,) int ``key`` pixel ids,
    (n,) float ``depth`` (larger is nearer). Going back from the front-most point of a pixel, a
    layer ends at the first step deeper than ``gap`` or ``tolerance`` behind the front."""
    if len(key) == 0:
        return np.zeros(0, dtype=np.int64)
    order = np.lexsort((-depth, key))  # by pixel, front first
    k, d = key[order], depth[order]
    first = np.r_[True, k[1:] != k[:-1]]
    group = np.cumsum(first) - 1
    step = np.r_[0.0, d[:-1] - d[1:]]
    broken = np.cumsum((step > gap) & ~first)
    passed = broken - broken[first][group] > 0  # a wide step lies between the front and here
    return order[~passed & (d >= d[first][group] - tolerance)]


def orient_by_visibility(points: np.ndarray, normals: np.ndarray, views: int = VISIBILITY_VIEWS,
                         k: int = ORIENT_NEIGHBORS, min_vote: float = 0.5,
                         neighbors: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, int]:
    """Flip (n, 3) consistently signed ``normals`` where :func:`visibility_votes` disagree.

    Each point's vote is smoothed with those of its ``k`` nearest neighbours lying along its
    tangent plane (``|edge . n| < 0.5``, so the far side of a thin part does not count), each
    counted as ``vote_j (n_i . n_j)``. Points whose score reaches ``min_vote`` take its sign; the
    others keep theirs. ``neighbors`` may pass precomputed ``knn(points, >= max(k, 4))``.
    Returns the normals and how many changed sign.
    """
    dist, idx = knn(points, max(k, 4)) if neighbors is None else neighbors
    votes = visibility_votes(points, normals, views, spacing=float(np.median(dist[:, 3])))
    idx = idx[:, :k]
    edge = points[idx] - points[:, None, :]
    edge /= np.maximum(np.linalg.norm(edge, axis=2, keepdims=True), 1e-300)
    tangential = np.abs(np.einsum("nkj,nj->nk", edge, normals)) < 0.5
    align = np.einsum("nkj,nj->nk", normals[idx], normals)
    count = np.maximum(tangential.sum(axis=1), 1)
    score = votes + 3.0 * (votes[idx] * align * tangential).sum(axis=1) / count
    flip = score <= -min_vote
    sign = np.where(flip, -1.0, 1.0)
    return normals * sign[:, None], int(flip.sum())


# ------------------------------------------------------------------------------ sampling
def sample_gaussians(g: dict[str, np.ndarray], normals: np.ndarray, per_gaussian: int,
                     seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Surface-like samples: every centre plus ``(per_gaussian - 1) x n`` tangent-plane draws.

    Extra samples are shared out in proportion to opacity x the area of each Gaussian's two
    largest axes (systematic rounding, seeded), and drawn from the 2D Gaussian spanned by those
    axes, truncated at 2 sigma. Samples inherit their Gaussian's normal.

    Returns
    -------
    points : (m, 3) float
    normals : (m, 3) float
    source : (m,) int
        Index of the Gaussian each sample came from (centres first, in order).
    """
    n = len(g["centers"])
    rng = np.random.default_rng(seed)
    extra = (per_gaussian - 1) * n
    if extra <= 0 or n == 0:
        return g["centers"], normals, np.arange(n)
    order = np.argsort(g["scales"], axis=1)
    rows = np.arange(n)
    s1 = g["scales"][rows, order[:, 2]]
    s2 = g["scales"][rows, order[:, 1]]
    share = g["opacity"] * s1 * s2
    share = np.where(np.isfinite(share) & (share > 0), share, 0.0)
    if share.sum() <= 0:
        share = np.ones(n)
    expected = extra * share / share.sum()
    cum = np.floor(np.cumsum(expected) + rng.random())
    counts = np.diff(np.concatenate([[0.0], cum])).astype(np.int64)
    src = np.repeat(rows, counts)
    mats = quaternion_matrices(g["rotations"][src])
    a1 = mats[np.arange(len(src)), :, order[src, 2]]
    a2 = mats[np.arange(len(src)), :, order[src, 1]]
    uv = rng.normal(size=(len(src), 2))
    r = np.linalg.norm(uv, axis=1, keepdims=True)
    uv = uv * np.minimum(1.0, 2.0 / np.maximum(r, 1e-12))
    pts = g["centers"][src] + a1 * (uv[:, :1] * s1[src, None]) + a2 * (uv[:, 1:] * s2[src, None])
    source = np.concatenate([rows, src])
    return np.concatenate([g["centers"], pts]), normals[source], source


# ------------------------------------------------------------------------------ loader
_DECODERS = {
    "ply-splat": _read_inria_ply,
    "ply-splat-compressed": _read_compressed_ply,
    "spz": _read_spz,
    "splat": _read_dot_splat,
}


def decode_splat(path: str | os.PathLike, fmt: str) -> tuple[dict[str, np.ndarray], dict]:
    """Decode ``path`` of format ``fmt`` (``ply-splat``, ``ply-splat-compressed``, ``spz``,
    ``splat``); returns the decoder dict and ``{"format_detail": str, "sh_degree": int}``."""
    try:
        decoder = _DECODERS[fmt]
    except KeyError:
        raise InputError(f"{path}: {fmt!r} is not a splat format; known: {sorted(_DECODERS)}") from None
    return decoder(path)


def working_budget(opts: LoadOptions) -> int | None:
    """How many Gaussians a load with ``opts`` needs at most (None: all of them).

    With a point budget ``n_points``, one point per Gaussian and no voxel grid, the output is a
    uniform random subset of the Gaussians, so a uniform subset of ``max(WORK_FACTOR * n_points,
    WORK_MIN)`` of them carries the same information: loading a 1M-Gaussian splat then costs what
    a 200k one does.
    """
    if opts.n_points is None or opts.samples_per_gaussian > 1 or opts.voxel_size is not None:
        return None
    return max(WORK_FACTOR * int(opts.n_points), WORK_MIN)


def load_splat_file(path: str | os.PathLike, fmt: str, opts: LoadOptions) -> OrientedCloud:
    """Load a splat file as an oriented cloud of Gaussian centres (or samples), in input units.

    Steps, each counted in ``cloud.info``: drop non-finite Gaussians, those with opacity below
    ``opts.min_opacity``; keep a uniform subset of at most :func:`working_budget` of the rest
    (``gaussians_used``); drop floater clusters holding less than ``opts.floater_ratio`` of the rest
    (:func:`floater_mask`) and statistical outliers (``opts.outlier_neighbors``,
    ``opts.outlier_std``, :func:`outlier_mask`). Normals: :func:`mixture_normals` of each Gaussian
    and its ``MIXTURE_NEIGHBORS`` nearest, signed by :func:`pointcvx.io.orient.orient_normals`
    and corrected by :func:`orient_by_visibility`; normals stored in the file (INRIA writes
    zeros) are not used. With ``opts.samples_per_gaussian > 1`` each Gaussian adds tangent-plane
    samples (:func:`sample_gaussians`). With ``opts.voxel_size`` one point per voxel is kept,
    the heaviest.

    ``weights`` are the Gaussian's opacity x geometric mean scale (:func:`gaussian_weights`),
    split evenly among the points drawn from it. ``colors`` are the SH DC colours.

    Raises :class:`InputError` for truncated or corrupted files and when no Gaussian survives
    the filters.
    """
    p = Path(path)
    g, meta = decode_splat(p, fmt)
    total = len(g["centers"])
    if total == 0:
        raise InputError(f"{p}: the splat holds no Gaussians")
    info: dict = {"format_detail": meta["format_detail"], "gaussians": total,
                  "sh_degree": int(meta["sh_degree"])}

    ok = finite_mask(g)
    info["dropped_nonfinite"] = int((~ok).sum())
    g = _subset(g, ok)
    ok = g["opacity"] >= opts.min_opacity
    info["dropped_low_opacity"] = int((~ok).sum())
    g = _subset(g, ok)
    if len(g["centers"]) == 0:
        raise InputError(
            f"{p}: no Gaussian is left after filtering: all {total} are non-finite or have "
            f"opacity below min_opacity={opts.min_opacity}"
        )
    budget = working_budget(opts)
    if budget is not None and len(g["centers"]) > budget:
        keep = np.sort(np.random.default_rng(opts.seed).choice(len(g["centers"]), budget, replace=False))
        info["gaussians_used"] = budget
        g = _subset(g, keep)
    ok = floater_mask(g["centers"], opts.floater_ratio)
    info["dropped_floaters"] = int((~ok).sum())
    g = _subset(g, ok)
    ok = outlier_mask(g["centers"], opts.outlier_neighbors, opts.outlier_std)
    info["dropped_outliers"] = int((~ok).sum())
    g = _subset(g, ok)
    n = len(g["centers"])
    if n < 4:
        raise InputError(f"{p}: only {n} of {total} Gaussians are left after filtering")

    axes = gaussian_normals(g["scales"], g["rotations"])
    near = knn(g["centers"], max(MIXTURE_NEIGHBORS, ORIENT_NEIGHBORS, 4))
    raw = mixture_normals(g["centers"], g["scales"], g["rotations"], g["opacity"], MIXTURE_NEIGHBORS,
                          neighbors=near[1])
    normals, _ = orient_normals(g["centers"], raw, k=ORIENT_NEIGHBORS)
    normals, changed = orient_by_visibility(g["centers"], normals, neighbors=near)
    info["normals_changed_by_visibility"] = changed
    flipped = int((np.einsum("ij,ij->i", normals, raw) < 0).sum())
    info["normals"] = NORMALS_NOTE
    info["normals_flipped"] = flipped
    info["normals_along_own_axis"] = round(float((np.abs((axes * normals).sum(axis=1)) > 0.9).mean()), 4)

    weights = gaussian_weights(g)
    points, normals, source = sample_gaussians(g, normals, opts.samples_per_gaussian, opts.seed)
    per_source = np.bincount(source, minlength=n)
    weights = weights[source] / per_source[source]
    colors = g["colors"][source]
    if opts.samples_per_gaussian > 1:
        info["samples_per_gaussian"] = int(opts.samples_per_gaussian)
    if opts.voxel_size is not None:
        keys = np.floor(points / opts.voxel_size).astype(np.int64)
        order = np.lexsort((-weights,) + tuple(keys.T[::-1]))
        _, first = np.unique(keys[order], axis=0, return_index=True)
        keep = np.sort(order[first])
        info["dropped_voxel"] = int(len(points) - len(keep))
        points, normals, colors, weights = points[keep], normals[keep], colors[keep], weights[keep]
    log.debug("%s: %d Gaussians -> %d points (%s)", p, total, len(points), info)
    return OrientedCloud(points, normals, colors=colors, weights=weights, modality="splat", info=info)
