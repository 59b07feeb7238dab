"""antimatter15 ``.splat`` files (headerless 32-byte records): read and write."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ...errors import InputError
from ..files import atomic_path, check_readable
from .gaussians import gaussian_arrays, normalize_quaternions

_DOT_SPLAT_DTYPE = np.dtype([("pos", "<f4", (3,)), ("scale", "<f4", (3,)), ("rgba", "u1", (4,)),
                             ("rot", "u1", (4,))])


def decode_dot_splat(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict]:
    """Decode an antimatter15 ``.splat``: the decoder dict and ``{"format_detail": str, "sh_degree": int}``
    (what :func:`pointcvx.io.splat.decode_splat` returns); see :func:`read_dot_splat`."""
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
    g = gaussian_arrays(rec["pos"], np.abs(rec["scale"].astype(np.float64)), rotations, rgba[:, 3],
                   rgba[:, :3])
    return g, {"format_detail": f"antimatter15 .splat ({len(rec)} records of 32 bytes)", "sh_degree": 0}


def read_dot_splat(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Decode an antimatter15 ``.splat``: headerless 32-byte records.

    Each record: 3 float32 position, 3 float32 linear scale, 4 uint8 RGBA (alpha is the opacity),
    4 uint8 rotation ``(w, x, y, z)`` stored as ``q * 128 + 128``.
    """
    return decode_dot_splat(path)[0]


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
