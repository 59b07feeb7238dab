"""Input augmentation, so one model serves every modality (meshes, CAD, scans, splats, points).

Only the *input* cloud (``points``, ``normals``) is corrupted: point-count changes, Gaussian noise,
partial views, flipped normals, splat-like anisotropic jitter. The supervision (``pool``,
``positive``, ``sdf_points``, ...) stays clean. Rotations are the exception: they move the
whole sample, input and supervision alike, so anchor/positive/negative geometry stays consistent.

Every corruption is a small function ``f(points, normals, rng, ...) -> (points, normals)`` on
(n, 3) float arrays; :func:`rotate_sample` and :func:`augment_sample` act on a sample dict as
written by :func:`pointcvx.training.data.prepare_shape`. All randomness comes from the numpy
Generator passed in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .shapes import random_rotation

#: Sample keys holding points or directions that rotations move (missing keys are skipped).
POINT_KEYS = ("points", "pool", "positive", "sdf_points")
NORMAL_KEYS = ("normals", "pool_normals")


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def up_rotation(rng: np.random.Generator, up: int = 2) -> np.ndarray:
    """(3, 3) float rotation by a uniform random angle about coordinate axis ``up``."""
    t = rng.uniform(0.0, 2.0 * np.pi)
    c, s = np.cos(t), np.sin(t)
    i, j = [a for a in range(3) if a != up]
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def rotate_sample(sample: dict, rotation: np.ndarray) -> dict:
    """A copy of ``sample`` with every point and normal key rotated by (3, 3) ``rotation``
    (about the origin, the centre of the normalised frame); index arrays are untouched."""
    out = dict(sample)
    r = np.asarray(rotation)
    for key in POINT_KEYS + NORMAL_KEYS:
        if key in out:
            a = np.asarray(out[key])
            out[key] = (a.reshape(-1, 3) @ r.T).reshape(a.shape).astype(a.dtype)
    return out


def random_rotate(sample: dict, rng: np.random.Generator, mode: str = "so3", up: int = 2) -> dict:
    """``sample`` rotated uniformly on SO(3) (``mode="so3"``) or about axis ``up`` (``"up"``)."""
    if mode == "so3":
        r = random_rotation(rng)
    elif mode == "up":
        r = up_rotation(rng, up)
    else:
        raise ValueError(f"unknown rotation mode {mode!r}")
    return rotate_sample(sample, r)


def resample(points: np.ndarray, normals: np.ndarray, rng: np.random.Generator,
             n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` of the (m, 3) points/normals: a random subset if ``n <= m``, else with repeats."""
    m = len(points)
    idx = rng.choice(m, size=n, replace=n > m)
    return points[idx], normals[idx]


def random_count(points: np.ndarray, normals: np.ndarray, rng: np.random.Generator,
                 low: int = 2048, high: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Resample to a log-uniform random count in ``low``..``high`` (default: the current count)."""
    high = len(points) if high is None else high
    low = min(low, high)
    n = int(round(np.exp(rng.uniform(np.log(low), np.log(high)))))
    return resample(points, normals, rng, max(n, 1))


def gaussian_noise(points: np.ndarray, normals: np.ndarray, rng: np.random.Generator,
                   sigma: float = 0.005) -> tuple[np.ndarray, np.ndarray]:
    """Isotropic Gaussian noise of std ``sigma`` on the points; normals unchanged."""
    return points + rng.normal(scale=sigma, size=points.shape).astype(points.dtype), normals


def visible_mask(points: np.ndarray, normals: np.ndarray, view: np.ndarray, threshold: float = 0.0,
                 zbuffer: int = 0, depth_tol: float = 0.02) -> np.ndarray:
    """(n,) bool: points facing the unit direction ``view`` (``n . view > threshold``), and with
    ``zbuffer`` > 0 also not hidden: orthographic projection along ``view`` onto a grid of
    ``zbuffer``^2 cells, keeping points within ``depth_tol`` of the nearest one of their cell."""
    view = np.asarray(view, dtype=np.float64)
    keep = normals @ view > threshold
    if zbuffer > 0 and keep.any():
        helper = np.eye(3)[int(np.argmin(np.abs(view)))]
        e1 = _unit(np.cross(view, helper)[None])[0]
        e2 = np.cross(view, e1)
        uv = np.stack([points @ e1, points @ e2], axis=1)
        depth = points @ view  # larger is closer to a viewer far along +view
        lo, hi = uv.min(axis=0), uv.max(axis=0)
        cell = np.clip(((uv - lo) / np.maximum(hi - lo, 1e-12) * zbuffer).astype(np.int64), 0, zbuffer - 1)
        flat = cell[:, 0] * zbuffer + cell[:, 1]
        front = np.full(zbuffer * zbuffer, -np.inf)
        np.maximum.at(front, flat, depth)
        keep &= depth >= front[flat] - depth_tol
    return keep


def partial_view(points: np.ndarray, normals: np.ndarray, rng: np.random.Generator,
                 threshold: float = 0.0, zbuffer: int = 0, min_keep: float = 0.05
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Keep what a viewer from a random direction sees (:func:`visible_mask`): a single scan.
    If less than ``min_keep`` of the points would remain, the input is returned unchanged."""
    view = _unit(rng.normal(size=(1, 3)))[0]
    keep = visible_mask(points, normals, view, threshold, zbuffer)
    if keep.sum() < max(min_keep * len(points), 1):
        return points, normals
    return points[keep], normals[keep]


def flip_normals(points: np.ndarray, normals: np.ndarray, rng: np.random.Generator,
                 fraction: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Negate a random ``fraction`` of the normals (splat and scan normals are often flipped)."""
    flip = rng.random(len(normals)) < fraction
    out = normals.copy()
    out[flip] = -out[flip]
    return points, out


def tangent_frames(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two (n, 3) unit tangents orthogonal to each other and to the (n, 3) unit normals."""
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = _unit(np.cross(normals, helper))
    return t1, np.cross(normals, t1)


def splat_jitter(points: np.ndarray, normals: np.ndarray, rng: np.random.Generator,
                 tangent_scale: float = 0.01, normal_scale: float = 0.002
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Splat-like anisotropic offsets: each point moves in its tangent plane along a random
    direction with per-point scales up to ``tangent_scale`` (flat Gaussians: one long and one
    short axis), and by ``normal_scale`` along its normal (splat centres sit off the surface)."""
    n = len(points)
    t1, t2 = tangent_frames(_unit(normals.astype(np.float64)))
    angle = rng.uniform(0.0, 2.0 * np.pi, size=(n, 1))
    a = np.cos(angle) * t1 + np.sin(angle) * t2
    b = -np.sin(angle) * t1 + np.cos(angle) * t2
    s_long = rng.uniform(0.2, 1.0, size=(n, 1)) * tangent_scale
    s_short = s_long * rng.uniform(0.1, 0.5, size=(n, 1))
    offset = (rng.normal(size=(n, 1)) * s_long * a + rng.normal(size=(n, 1)) * s_short * b
              + rng.normal(size=(n, 1)) * normal_scale * normals)
    return (points + offset).astype(points.dtype), normals


@dataclass
class AugmentConfig:
    """Probabilities and strengths of each augmentation in :func:`augment_sample`."""

    rotation: str | None = "so3"  # "so3", "up" or None
    p_count: float = 0.5
    count_low: int = 2048
    n_points: int | None = None  # resample the input to exactly this many at the end
    p_noise: float = 0.3
    noise_sigma: tuple[float, float] = (0.001, 0.01)
    p_partial: float = 0.15
    partial_zbuffer: int = 64
    p_flip: float = 0.2
    flip_fraction: tuple[float, float] = (0.02, 0.3)
    p_splat: float = 0.2
    splat_scale: float = 0.01


def augment_sample(sample: dict, rng: np.random.Generator, config: AugmentConfig | None = None) -> dict:
    """A copy of ``sample`` with a random rotation (of everything) and random corruptions of the
    input ``points``/``normals`` only, drawn per :class:`AugmentConfig`. Normals stay unit."""
    cfg = config or AugmentConfig()
    out = random_rotate(sample, rng, cfg.rotation) if cfg.rotation else dict(sample)
    p = np.asarray(out["points"])
    n = np.asarray(out["normals"])
    if rng.random() < cfg.p_partial:
        p, n = partial_view(p, n, rng, zbuffer=cfg.partial_zbuffer)
    if rng.random() < cfg.p_count:
        p, n = random_count(p, n, rng, low=cfg.count_low)
    if rng.random() < cfg.p_splat:
        p, n = splat_jitter(p, n, rng, tangent_scale=cfg.splat_scale)
    if rng.random() < cfg.p_noise:
        p, n = gaussian_noise(p, n, rng, sigma=rng.uniform(*cfg.noise_sigma))
    if rng.random() < cfg.p_flip:
        p, n = flip_normals(p, n, rng, fraction=rng.uniform(*cfg.flip_fraction))
    if cfg.n_points is not None:
        p, n = resample(p, n, rng, cfg.n_points)
    out["points"] = p.astype(np.float32)
    out["normals"] = _unit(n.astype(np.float64)).astype(np.float32)
    return out
