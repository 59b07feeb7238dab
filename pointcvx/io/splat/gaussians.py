"""Gaussians as arrays: activations, quaternions, normals of Gaussian mixtures, surface samples.

Every decoder returns the same plain dict of numpy arrays for ``n`` Gaussians
(:func:`gaussian_arrays` builds it):

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
"""

from __future__ import annotations

import numpy as np

from ..orient import knn

#: Zeroth-order real spherical harmonic, the factor between ``f_dc`` and colour.
SH_C0 = 0.28209479177387814


def sigmoid(x: np.ndarray) -> np.ndarray:
    """(n,) float logistic function, overflow-free."""
    x = np.asarray(x, dtype=np.float64)
    out = np.empty_like(x)
    pos = x >= 0
    out[pos] = 1.0 / (1.0 + np.exp(-x[pos]))
    ex = np.exp(x[~pos])
    out[~pos] = ex / (1.0 + ex)
    return out


def logit(p: np.ndarray) -> np.ndarray:
    """(n,) float inverse of the sigmoid, clipped away from 0 and 1."""
    p = np.clip(np.asarray(p, dtype=np.float64), 1e-6, 1.0 - 1e-6)
    return np.log(p / (1.0 - p))


def dc_to_color(f_dc: np.ndarray) -> np.ndarray:
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


def matrix_quaternion(m: np.ndarray) -> np.ndarray:
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


def quaternion_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
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


def gaussian_arrays(centers, scales, rotations, opacity, colors, normals=None) -> dict[str, np.ndarray]:
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


def sh_degree_from_rest(n_rest: int) -> int:
    """SH degree from the number of ``f_rest_*`` coefficients (0, 9, 24, 45, 72)."""
    for degree in range(5):
        if 3 * ((degree + 1) ** 2 - 1) >= n_rest:
            return degree
    return 4


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
