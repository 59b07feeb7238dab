"""Niantic SPZ splats: read versions 1-3 (gzip) and 4 (zstd streams), write versions 2-3.

Also the zstd decoders version 4 needs, and the change from SPZ's axes to the PLY convention.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gzip
import io
import logging
import os
import struct
import zlib
from pathlib import Path

import numpy as np

from ...errors import InputError, MissingExtraError
from ..files import atomic_path, check_readable
from .gaussians import SH_C0, dc_to_color, gaussian_arrays, matrix_quaternion, quaternion_product

log = logging.getLogger(__name__)

#: SPZ stores colours as ``f_dc * 0.15 + 0.5`` (not SH_C0) to keep room for out-of-range values.
SPZ_COLOR_SCALE = 0.15
#: Largest SPZ point count accepted before allocating anything.
MAX_SPZ_POINTS = 100_000_000

#: Bytes inflated at a time: memory follows what a compressed stream really holds.
INFLATE_STEP = 64 << 20
#: Most bytes deflate can expand one byte to: the bound on what a gzip stream can hold.
DEFLATE_MAX_RATIO = 1032
#: Bytes allowed past a legacy payload's arrays: extension records (flag 0x2), or stray bytes.
EXTENSION_SLACK, TRAILING_SLACK = 1 << 20, 1 << 16

#: The first four bytes of a zstd frame.
_ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"


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
        raise _no_zstd_error()
    return found


def _no_zstd_error() -> MissingExtraError:
    """The error when no zstd decoder is found: ``zstandard`` is a dependency, not an extra."""
    return MissingExtraError("SPZ version 4 (zstd-compressed) files", None, "zstandard")


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


def axes_change(source: str, target: str = "RDF") -> np.ndarray:
    """(3, 3) float signed permutation taking coordinates in ``source`` axes to ``target`` axes."""
    def basis(name):
        return np.array([_AXIS_DIRECTION[c] for c in name], dtype=np.float64).T

    return basis(target).T @ basis(source)


def to_ply_axes(g: dict[str, np.ndarray], source: str) -> None:
    """Convert centres and rotations of ``g`` in place from ``source`` axes to PLY's RDF."""
    m = axes_change(source)
    if np.allclose(m, np.eye(3)):
        return
    g["centers"] = g["centers"] @ m.T
    if "normals" in g:
        g["normals"] = g["normals"] @ m.T
    # The covariance R S^2 R^T must become M R S^2 R^T M^T. With P = det(M) M (a rotation), P R
    # does it; for pure axis flips M R M^T = P R P^T does too and keeps the reference library's
    # quaternions (w unchanged, x y z flipped).
    rot = matrix_quaternion(m * np.sign(np.linalg.det(m)))
    q = quaternion_product(rot, g["rotations"])
    if np.allclose(np.abs(np.diag(m)), 1.0):
        q = quaternion_product(q, rot * np.array([1.0, -1.0, -1.0, -1.0]))
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
    return gaussian_arrays(centers, scales, rotations, opacity, dc_to_color(f_dc))


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
    warnings: list[str] = []
    start = len(buf) - sum(sizes)  # extension records, if any, sit between header and data
    if start < 16 or (start > 16 and not flags & 0x2):
        if start < 16:
            raise InputError(
                f"{p}: truncated SPZ: {len(buf)} bytes hold less than the {16 + sum(sizes)} "
                f"bytes {n} Gaussians need"
            )
        warnings.append(f"{start - 16} unexpected bytes after the SPZ header ignored")
    arrays, offset = [], start
    for size in sizes[:5]:
        arrays.append(np.frombuffer(buf, dtype=np.uint8, count=size, offset=offset))
        offset += size
    g = _spz_arrays(p, n, frac, version >= 3, version == 1, arrays)
    to_ply_axes(g, "RUB")
    detail = f"Niantic SPZ v{version} (gzip, {n} Gaussians, SH degree {degree}, RUB -> RDF axes)"
    return g, {"format_detail": detail, "sh_degree": int(degree), "warnings": warnings}


def _spz_coordinate_extension(p: Path, raw: bytes, start: int, end: int, warnings: list[str]) -> str:
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
            warnings.append(f"unknown SPZ coordinate system {value}; assuming RUB")
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
    _zstd_decompressor()  # MissingExtraError before anything is read when no decoder exists
    arrays = []
    for i, (csize, usize) in enumerate(table[:5].tolist()):
        chunk = raw[offset:offset + csize]
        offset += csize
        try:
            out, more = _unzstd(p, chunk, usize)
        except ValueError as exc:
            raise InputError(f"{p}: corrupted SPZ: zstd stream {i} does not decode ({exc})") from None
        if more:
            raise InputError(f"{p}: corrupted SPZ: zstd stream {i} inflates past the {usize} bytes it "
                             "declares")
        if len(out) != usize:
            raise InputError(f"{p}: corrupted SPZ: zstd stream {i} gives {len(out)} bytes, not {usize}")
        arrays.append(np.frombuffer(out, dtype=np.uint8))
    g = _spz_arrays(p, n, frac, True, False, arrays)
    warnings: list[str] = []
    axes = _spz_coordinate_extension(p, raw, 32, toc, warnings) if flags & 0x2 else "RUB"
    to_ply_axes(g, axes)
    detail = (f"Niantic SPZ v{version} (zstd, {n_streams} streams, {n} Gaussians, "
              f"SH degree {degree}, {axes} -> RDF axes)")
    return g, {"format_detail": detail, "sh_degree": int(degree), "warnings": warnings}


def _gunzip(p: Path, raw: bytes, limit: int) -> tuple[bytearray, bool]:
    """At most ``limit`` bytes of the gzip stream ``raw``, inflated step by step (memory follows the
    output), and whether the stream holds more."""
    d = zlib.decompressobj(wbits=31)
    out, data, more = bytearray(), raw, False
    try:
        while len(out) < limit and not d.eof:
            piece = d.decompress(data, min(INFLATE_STEP, limit - len(out)))
            data = d.unconsumed_tail
            if not piece and not data:
                piece = d.decompress(b"", min(INFLATE_STEP, limit - len(out)))  # output still pending
                if not piece:
                    break
            out += piece
        if not d.eof and len(out) >= limit:
            more = bool(d.decompress(data, 1))
    except zlib.error as exc:
        raise InputError(f"{p}: truncated or corrupted SPZ gzip stream ({exc})") from None
    if not d.eof and not more:
        raise InputError(f"{p}: truncated or corrupted SPZ gzip stream (it ends before its end marker)")
    return out, more


def _unzstd(p: Path, raw: bytes, limit: int) -> tuple[bytes | bytearray, bool]:
    """At most ``limit`` bytes of the zstd data ``raw`` and whether it holds more; :class:`ValueError`
    when it does not decode. Streamed with ``zstandard`` (a dependency); other decoders get
    ``limit`` as their output bound."""
    try:
        import zstandard
    except ImportError:
        return _zstd_decompressor()(raw, limit), False
    reader = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(raw), read_across_frames=True)
    out = bytearray()
    try:
        while len(out) < limit:
            chunk = reader.read(min(INFLATE_STEP, limit - len(out)))
            if not chunk:
                break
            out += chunk
        more = bool(reader.read(1))
    except zstandard.ZstdError as exc:
        raise ValueError(str(exc)) from None
    return out, more


def _legacy_need(head: bytes) -> tuple[int, int, int]:
    """(bytes the Gaussians declared by a legacy 16-byte header need, slack allowed past them, the
    count); a header too broken to size gives 16 (:func:`_parse_legacy_spz` then says why)."""
    if len(head) < 16:
        return 16, 0, 0
    magic, version, n, degree, _, flags, _ = struct.unpack_from("<4sIIBBBB", head, 0)
    if magic != b"NGSP" or not 1 <= version <= 3 or n > MAX_SPZ_POINTS or degree > 4:
        return 16, 0, n
    return 16 + sum(_spz_sizes(n, degree, version)), EXTENSION_SLACK if flags & 0x2 else TRAILING_SLACK, n


def _inflate_legacy(p: Path, raw: bytes, kind: str) -> bytes | bytearray:
    """A legacy SPZ payload wrapped in gzip or zstd, inflated no further than its header's count needs
    (plus extension slack): a bomb is refused after the bytes it declares, never fully inflated."""
    unpack = _gunzip if kind == "gzip" else _unzstd

    def inflate(limit: int) -> tuple[bytes | bytearray, bool]:
        return unpack(p, raw, limit)

    try:
        head, _ = inflate(16)
        need, slack, n = _legacy_need(bytes(head))
        if kind == "gzip" and need > DEFLATE_MAX_RATIO * len(raw) + 1024:
            raise InputError(f"{p}: truncated or corrupted SPZ: its header declares {n} Gaussians "
                             f"({need} bytes), more than {len(raw)} bytes of gzip can hold")
        buf, more = inflate(need + slack)
    except ValueError as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"{p}: truncated or corrupted SPZ {kind} stream ({exc})") from None
    if more:
        raise InputError(f"{p}: corrupted SPZ: its {kind} stream inflates past the {need + slack} bytes its "
                         f"{n} Gaussians need (a decompression bomb?); refused")
    return buf


def decode_spz(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict]:
    """Decode a Niantic SPZ file: the decoder dict and ``{"format_detail": str, "sh_degree": int,
    "warnings": [str]}`` (what :func:`pointcvx.io.splat.decode_splat` returns; the warnings are
    logged by whoever finishes the load, so a failing load prints its error alone); see
    :func:`read_spz`."""
    p = check_readable(path)
    raw = p.read_bytes()
    if raw[:2] == b"\x1f\x8b":
        return _parse_legacy_spz(p, _inflate_legacy(p, raw, "gzip"))
    if raw[:4] == _ZSTD_MAGIC:  # a legacy payload wrapped in one zstd frame (third-party writers)
        return _parse_legacy_spz(p, _inflate_legacy(p, raw, "zstd"))
    if raw[:4] != b"NGSP":
        raise InputError(f"{p}: not an SPZ file (no gzip, zstd or 'NGSP' magic)")
    if len(raw) < 8:
        raise InputError(f"{p}: truncated SPZ header")
    (version,) = struct.unpack_from("<I", raw, 4)
    if version >= 4:
        g, meta = _parse_ngsp_v4(p, raw)
        if version > 4:
            meta["warnings"].insert(0, f"SPZ version {version} is newer than 4; decoded as version 4")
        return g, meta
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
    g, meta = decode_spz(path)
    for warning in meta["warnings"]:
        log.warning("%s: %s", path, warning)
    return g


def write_spz(path, centers, scales, rotations, opacity, colors, version: int = 3,
              fractional_bits: int = 12) -> None:
    """Write Gaussians as a gzip-wrapped SPZ of version 2 or 3 (SH degree 0), atomically.

    Inputs are in PLY (RDF) axes like the decoder's output; they are stored in SPZ's RUB axes.
    Mostly for tests: it follows the reference packer's quantisation.
    """
    if version not in (2, 3):
        raise ValueError("write_spz writes SPZ versions 2 and 3")
    g = gaussian_arrays(centers, scales, rotations, opacity, colors)
    to_ply_axes(g, "RUB")  # RUB <-> RDF is its own inverse
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
