"""PlayCanvas / SuperSplat compressed PLY splats (chunked, bit-packed): read."""

from __future__ import annotations

import os

import numpy as np

from ...errors import InputError
from ..files import check_readable
from ..ply import read_ply
from .gaussians import gaussian_arrays, sh_degree_from_rest

#: Gaussians per chunk of the PlayCanvas compressed PLY.
CHUNK_SIZE = 256
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


def decode_compressed_ply(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict]:
    """Decode a PlayCanvas compressed PLY: the decoder dict and ``{"format_detail": str, "sh_degree": int}``
    (what :func:`pointcvx.io.splat.decode_splat` returns); see :func:`read_compressed_ply`."""
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
        degree = sh_degree_from_rest(len(elements["sh"].data.dtype.names))
    g = gaussian_arrays(centers, scales, rotations, opacity, rgb)
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
    return decode_compressed_ply(path)[0]
