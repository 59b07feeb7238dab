"""INRIA 3DGS PLY splats (the reference trainer's output): read and write."""

from __future__ import annotations

import os

import numpy as np

from ...errors import InputError
from ..files import atomic_path, check_readable
from ..ply import read_ply, vertex_array
from .gaussians import SH_C0, dc_to_color, gaussian_arrays, logit, sh_degree_from_rest, sigmoid


def decode_inria_ply(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict]:
    """Decode an INRIA 3DGS PLY: the decoder dict and ``{"format_detail": str, "sh_degree": int}``
    (what :func:`pointcvx.io.splat.decode_splat` returns); see :func:`read_inria_ply`."""
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
        colors = dc_to_color(vertex_array(data, ("f_dc_0", "f_dc_1", "f_dc_2")))
    elif {"red", "green", "blue"} <= names:
        colors = (vertex_array(data, ("red", "green", "blue")) / 255.0).astype(np.float32)
    else:
        colors = np.full((len(cols), 3), 0.5, dtype=np.float32)
    normals = None
    if {"nx", "ny", "nz"} <= names:
        normals = vertex_array(data, ("nx", "ny", "nz"))
    with np.errstate(over="ignore", invalid="ignore"):
        scales = np.exp(cols[:, 3:6])
    g = gaussian_arrays(cols[:, 0:3], scales, cols[:, 6:10], sigmoid(cols[:, 10]), colors, normals)
    n_rest = sum(1 for n in names if n.startswith("f_rest_"))
    degree = sh_degree_from_rest(n_rest)
    detail = f"INRIA 3DGS PLY ({len(names)} vertex properties, SH degree {degree})"
    return g, {"format_detail": detail, "sh_degree": degree}


def read_inria_ply(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Decode an INRIA 3DGS PLY; properties are looked up by name, so their order is free.

    Needs ``x y z scale_0..2 rot_0..3 opacity``; ``f_dc_0..2`` (or ``red green blue``),
    ``f_rest_*`` (any SH degree) and ``nx ny nz`` are optional. Returns the decoder dict (see
    :mod:`.gaussians`); :class:`InputError` when the file is truncated or lacks a property.
    """
    return decode_inria_ply(path)[0]


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
    cols["opacity"] = logit(opacity)
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
