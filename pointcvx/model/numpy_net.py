"""The feature network's inference in numpy: a checkpoint's weights read without torch, and
:class:`~pointcvx.model.network.FeatureNet`'s forward pass and plane queries, op for op.

A splat decomposed with the model's features then never imports torch (about 1.5 s of a
one-shot run). Each op below is the torch op of ``network.py`` it stands for, in float32, with
the same layouts; the features agree with torch's to float32 round-off
(``tests/test_model.py``). Training, GPUs and ``pointcvx train`` keep the torch network.
"""

from __future__ import annotations

import os
import pickle
import zipfile
from collections import OrderedDict
from pathlib import Path

import numpy as np

from .config import CONTEXT_LINES, PLANE_AXES

_DTYPES = {"FloatStorage": np.float32, "DoubleStorage": np.float64, "HalfStorage": np.float16,
           "LongStorage": np.int64, "IntStorage": np.int32, "BoolStorage": np.bool_,
           "ByteStorage": np.uint8}


# -------------------------------------------------------------------------- checkpoints
class _Storage:
    def __init__(self, dtype):
        self.dtype = dtype


def _rebuild_tensor(storage, offset, size, stride, *_):
    """A tensor of ``torch._utils._rebuild_tensor_v2``: a strided view of its storage."""
    item = storage.itemsize
    return np.lib.stride_tricks.as_strided(storage[offset:], shape=tuple(size),
                                           strides=tuple(s * item for s in stride)).copy()


class _CheckpointUnpickler(pickle.Unpickler):
    """``torch.load(weights_only=True)`` for plain tensors, dicts and numbers, into numpy:
    only the names a state dict uses are resolved, anything else is refused."""

    def __init__(self, file, archive: zipfile.ZipFile, prefix: str):
        super().__init__(file)
        self.archive, self.prefix = archive, prefix

    def find_class(self, module, name):
        if module == "torch._utils" and name == "_rebuild_tensor_v2":
            return _rebuild_tensor
        if module == "torch" and name in _DTYPES:
            return _Storage(_DTYPES[name])
        if module == "collections" and name == "OrderedDict":
            return OrderedDict
        raise pickle.UnpicklingError(f"{module}.{name} is not part of a weights checkpoint")

    def persistent_load(self, pid):
        kind, storage, key, _location, numel = pid
        if kind != "storage" or not isinstance(storage, _Storage):
            raise pickle.UnpicklingError(f"unexpected persistent id {pid[:2]}")
        data = self.archive.read(f"{self.prefix}data/{key}")
        return np.frombuffer(data, dtype=storage.dtype, count=numel)


def read_checkpoint(path: str | os.PathLike) -> dict:
    """The dict of a checkpoint written by :func:`pointcvx.model.train.save_checkpoint` (torch's
    zip format), every tensor as a numpy array, without importing torch. Raises
    ``pickle.UnpicklingError``, ``KeyError`` or ``zipfile.BadZipFile`` on anything else."""
    with zipfile.ZipFile(Path(path)) as archive:
        pkl = next(n for n in archive.namelist() if n.endswith("data.pkl"))
        prefix = pkl[: -len("data.pkl")]
        with archive.open(pkl) as f:
            return _CheckpointUnpickler(f, archive, prefix).load()


# -------------------------------------------------------------------------- ops
def linear(x: np.ndarray, w: np.ndarray, b: np.ndarray | None) -> np.ndarray:
    """``nn.Linear``: (..., i) float32, (o, i) weight, (o,) bias -> (..., o)."""
    y = x @ w.T
    return y if b is None else y + b


def gelu(x: np.ndarray) -> np.ndarray:
    """``nn.GELU()`` (the exact, erf form)."""
    from scipy.special import erf

    return (0.5 * x * (1.0 + erf(x * np.float32(1 / np.sqrt(2.0))))).astype(np.float32)


def group_norm(x: np.ndarray, groups: int, w: np.ndarray, b: np.ndarray, eps: float = 1e-5) -> np.ndarray:
    """``nn.GroupNorm`` of one (c, *spatial) item."""
    c = x.shape[0]
    g = x.reshape(groups, -1)
    mean = g.mean(axis=1, keepdims=True)
    var = g.var(axis=1, keepdims=True)
    y = ((g - mean) / np.sqrt(var + eps)).reshape(x.shape)
    shape = (c,) + (1,) * (x.ndim - 1)
    return y * w.reshape(shape) + b.reshape(shape)


def layer_norm(x: np.ndarray, w: np.ndarray, b: np.ndarray, eps: float = 1e-5) -> np.ndarray:
    """``nn.LayerNorm`` over the last axis."""
    mean = x.mean(axis=-1, keepdims=True)
    var = x.var(axis=-1, keepdims=True)
    return (x - mean) / np.sqrt(var + eps) * w + b


def conv(x: np.ndarray, w: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``nn.Conv2d`` / ``nn.Conv3d`` with stride 1 and 'same' zero padding of odd kernels, on a
    batch (m, c_in, *spatial) with (c_out, c_in, *kernel) weights -> (m, c_out, *spatial).

    With more input than output channels, every tap's weights are applied to the whole input
    in one product, (m * cells, c_in) @ (c_in, taps * c_out), and the taps' outputs are added
    shifted into place (no (cells, taps * c_in) copy of the input; 0.6x the time of the aware
    and first voxel convolutions); otherwise the copy (im2col) and one product, the cheaper
    way there. The same sums, in another order."""
    m, c_in = x.shape[:2]
    spatial, kernel = x.shape[2:], w.shape[2:]
    c_out = w.shape[0]
    if c_in <= c_out:
        pad = [(0, 0), (0, 0)] + [(k // 2, k // 2) for k in kernel]
        windows = np.lib.stride_tricks.sliding_window_view(np.pad(x, pad), kernel,
                                                           axis=tuple(range(2, x.ndim)))
        # (m, c_in, *spatial, *kernel) -> rows (m, *spatial) of (c_in, *kernel), as w is laid out
        d = len(spatial)
        order = (0,) + tuple(range(2, 2 + d)) + (1,) + tuple(range(2 + d, windows.ndim))
        y = windows.transpose(order).reshape(-1, w[0].size) @ w.reshape(c_out, -1).T + b
        return np.moveaxis(y.reshape((m,) + spatial + (c_out,)), -1, 1)
    rows = np.moveaxis(x, 1, -1).reshape(-1, c_in)  # channels last
    taps = np.moveaxis(w.reshape(c_out, c_in, -1), -1, 0)  # (taps, c_out, c_in)
    z = (rows @ taps.transpose(2, 0, 1).reshape(c_in, -1)).reshape((m,) + spatial + (len(taps), c_out))
    y = np.broadcast_to(b, (m,) + spatial + (c_out,)).copy()
    for t, offset in enumerate(np.ndindex(*kernel)):
        # output cell p takes tap t's product at input cell p + offset - k // 2
        dst, src = [slice(None)], [slice(None)]
        for o, k, n in zip(offset, kernel, spatial, strict=True):
            s = o - k // 2
            dst.append(slice(max(0, -s), n - max(0, s)))
            src.append(slice(max(0, s), n - max(0, -s)))
        y[tuple(dst)] += z[tuple(src) + (t,)]
    return np.moveaxis(y, -1, 1)


def max_pool2(x: np.ndarray) -> np.ndarray:
    """``nn.MaxPool2d(2)`` of (m, c, h, w) (even sides)."""
    m, c, h, w = x.shape
    return x.reshape(m, c, h // 2, 2, w // 2, 2).max(axis=(3, 5))


def grid_index(xyz: np.ndarray, res: int) -> np.ndarray:
    """:func:`pointcvx.model.network.grid_index`: (..., d) float32 -> (..., d) int in [0, res)."""
    return np.clip(np.floor((xyz + np.float32(1.0)) * np.float32(0.5 * res)).astype(np.int64), 0, res - 1)


def scatter_mean(values: np.ndarray, index: np.ndarray, size: int) -> np.ndarray:
    """(n, c) values, (n,) int bins -> (size, c) means (0 for empty bins)."""
    order = np.argsort(index, kind="stable")
    bins, start, count = np.unique(index[order], return_index=True, return_counts=True)
    total = np.zeros((size, values.shape[1]), np.float32)
    if len(bins):
        total[bins] = np.add.reduceat(values[order], start, axis=0) / count[:, None].astype(np.float32)
    return total


def _corners(coord: np.ndarray, size: int):
    """Border-clamped ``align_corners=False`` sampling of one axis: (lower index, upper index,
    weight of the upper)."""
    p = np.clip(((coord + 1.0) * size - 1.0) * 0.5, 0.0, size - 1).astype(np.float32)
    lo = np.floor(p).astype(np.int64)
    return lo, np.minimum(lo + 1, size - 1), p - lo


def sample_grid(grid: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """``F.grid_sample(..., "bilinear", "border", align_corners=False)`` of one (c, *spatial)
    grid at (n, d) points whose coordinates run x (last axis of the grid) first: (n, c)."""
    dims = grid.shape[1:][::-1]  # sizes along x, y, (z)
    axes = [_corners(xyz[:, a], s) for a, s in enumerate(dims)]
    out = np.zeros((len(xyz), grid.shape[0]), np.float32)
    flat = np.ascontiguousarray(grid.reshape(grid.shape[0], -1).T)  # a cell's channels in a row
    strides = np.cumprod((1,) + dims[:-1])  # x varies fastest
    for corner in np.ndindex(*(2,) * len(dims)):
        index = np.zeros(len(xyz), np.int64)
        weight = np.ones(len(xyz), np.float32)
        for a, (lo, hi, t) in enumerate(axes):
            index += (hi if corner[a] else lo) * strides[a]
            weight *= t if corner[a] else 1.0 - t
        out += flat[index] * weight[:, None]
    return out


def cross_plane_context(planes: np.ndarray) -> np.ndarray:
    """:func:`pointcvx.model.network.cross_plane_context` of (3, c, P, P) planes: (3, 2c, P, P)."""
    out = []
    p = planes.shape[-1]
    for lines in CONTEXT_LINES:
        parts = []
        for j, axis, along_w in lines:
            line = planes[j].mean(axis=axis)  # (c, P)
            part = line[:, None, :] if along_w else line[:, :, None]
            parts.append(np.broadcast_to(part, (line.shape[0], p, p)))
        out.append(np.concatenate(parts, axis=0))
    return np.stack(out)


def attention(x: np.ndarray, w_in, b_in, w_out, b_out, heads: int) -> np.ndarray:
    """``nn.MultiheadAttention`` self-attention of (t, w) tokens, no mask."""
    t, width = x.shape
    d = width // heads
    q, k, v = np.split(linear(x, w_in, b_in), 3, axis=1)
    q, k, v = (a.reshape(t, heads, d).transpose(1, 0, 2) for a in (q, k, v))
    s = q @ k.transpose(0, 2, 1) / np.float32(np.sqrt(d))
    s = np.exp(s - s.max(axis=-1, keepdims=True))
    s /= s.sum(axis=-1, keepdims=True)
    return linear((s @ v).transpose(1, 0, 2).reshape(t, width), w_out, b_out)


def _groups(c: int) -> int:
    for g in (8, 4, 2):
        if c % g == 0:
            return g
    return 1


# -------------------------------------------------------------------------- the network
class NumpyFeatureNet:
    """:class:`~pointcvx.model.network.FeatureNet` for inference: ``encode`` a cloud into
    (3, C, P, P) float32 planes, ``query`` unit features at points.

    Parameters
    ----------
    config : ModelConfig
    weights : dict of name -> float32 array, the torch state dict's names.
    path : str, optional, the checkpoint read (named in errors).
    shipped : bool, whether it is the package's own model (whose weights are known to fit).
    """

    def __init__(self, config, weights: dict[str, np.ndarray], path: str | None = None,
                 shipped: bool = False):
        self.config, self.path, self.shipped = config, path, shipped
        self.w = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in weights.items()}
        bad = [k for k, v in self.w.items() if not np.isfinite(v).all()]
        if bad:  # NaN features would reach the split's k-means (load_cached_model: InputError)
            raise ValueError(f"{len(bad)} weight tensors hold NaN or infinite values: {bad[0]}, ...")
        self.dim = config.head.feature_dim
        self.sdf_channels = config.head.sdf_channels

    @classmethod
    def load(cls, path: str | os.PathLike, shipped: bool = False) -> NumpyFeatureNet:
        """The network of checkpoint ``path``; ``shipped``: it is the package's own model."""
        from .config import ModelConfig

        state = read_checkpoint(path)
        return cls(ModelConfig.from_dict(state["config"]), state["model"], str(path), shipped)

    def _lin(self, name: str, x: np.ndarray) -> np.ndarray:
        return linear(x, self.w[f"{name}.weight"], self.w.get(f"{name}.bias"))

    def _conv(self, name: str, x: np.ndarray) -> np.ndarray:
        return conv(x, self.w[f"{name}.weight"], self.w[f"{name}.bias"])

    def _norm(self, name: str, x: np.ndarray) -> np.ndarray:
        w = self.w[f"{name}.weight"]
        return group_norm(x, _groups(len(w)), w, self.w[f"{name}.bias"])

    def _encoder(self, xyz: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """(n, 3) points and normals -> (n, c) point features (PVCNN)."""
        e = self.config.encoder
        base = np.maximum(self._lin("encoder.mlp.0", np.concatenate([xyz, normals], axis=1)), 0)
        base = np.maximum(self._lin("encoder.mlp.2", base), 0)
        h = base
        for i, res in enumerate(e.voxel_resolutions):
            name = f"encoder.blocks.{i}"
            ijk = grid_index(xyz, res)
            index = (ijk[:, 2] * res + ijk[:, 1]) * res + ijk[:, 0]
            g = scatter_mean(h, index, res**3).T.reshape(1, -1, res, res, res)
            for a, b in ((0, 1), (3, 4)):
                g = self._norm(f"{name}.voxel.{b}", self._conv(f"{name}.voxel.{a}", g)[0])[None]
                g = np.where(g >= 0, g, np.float32(0.1) * g)
            h = np.maximum(sample_grid(g[0], xyz) + self._lin(f"{name}.point", h), 0)
        return self._lin("encoder.out", np.concatenate([h, base], axis=1))

    def encode(self, xyz: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """(n, 3) float points and normals (normalised frame) -> (3, C, P, P) float32 planes.
        :class:`~pointcvx.errors.InputError` when the checkpoint's weights do not fit its
        config (found here, where they are used: checking beforehand would cost a forward pass)."""
        try:
            return self._encode(xyz, normals)
        except (KeyError, ValueError, IndexError) as exc:
            if self.path is None or self.shipped:
                raise  # the shipped model fits: anything here is a fault of this code
            from ..errors import InputError, first_line

            raise InputError(f"{self.path}: not a pointcvx model checkpoint (its weights do not "
                             f"fit its config: {first_line(exc, 120)})") from None

    def _encode(self, xyz: np.ndarray, normals: np.ndarray) -> np.ndarray:
        xyz = np.asarray(xyz, np.float32)
        normals = np.asarray(normals, np.float32)
        p = self.config.planes
        feats = self._encoder(xyz, normals)
        res = p.resolution
        ij = grid_index(xyz, res)
        index = np.concatenate([ij[:, v] * res + ij[:, u] + k * res * res
                                for k, (u, v) in enumerate(PLANE_AXES)])
        planes = scatter_mean(np.concatenate([feats] * 3), index, 3 * res * res)
        planes = planes.reshape(3, res, res, -1).transpose(0, 3, 1, 2)  # (3, c, P, P)
        return self._backbone(np.ascontiguousarray(planes))

    def _backbone(self, planes: np.ndarray) -> np.ndarray:
        cfg = self.config
        for i in range(cfg.planes.aware_layers):
            x = np.concatenate([planes, cross_plane_context(planes)], axis=1)
            y = self._conv(f"backbone.aware.{i}.conv", x)
            planes = planes + gelu(np.stack([self._norm(f"backbone.aware.{i}.norm", a) for a in y]))
        x = planes
        t = x
        for i in range(len(cfg.planes.down_channels)):
            t = max_pool2(gelu(self._conv(f"backbone.down.{3 * i}", t)))
        s = t.shape[-1]
        t = t.reshape(3, t.shape[1], s * s).transpose(0, 2, 1)  # (3, s^2, c)
        if "backbone.proj.weight" in self.w:
            t = self._lin("backbone.proj", t)
        t = (t + self.w["backbone.pos"][0] + self.w["backbone.plane"][0]).reshape(3 * s * s, -1)
        heads = cfg.transformer.heads
        for i in range(cfg.transformer.layers):
            n = f"backbone.vit.layers.{i}"
            h = layer_norm(t, self.w[f"{n}.norm1.weight"], self.w[f"{n}.norm1.bias"])
            a = f"{n}.self_attn"
            t = t + attention(h, self.w[f"{a}.in_proj_weight"], self.w[f"{a}.in_proj_bias"],
                              self.w[f"{a}.out_proj.weight"], self.w[f"{a}.out_proj.bias"], heads)
            h = layer_norm(t, self.w[f"{n}.norm2.weight"], self.w[f"{n}.norm2.bias"])
            t = t + self._lin(f"{n}.linear2", gelu(self._lin(f"{n}.linear1", h)))
        t = layer_norm(t, self.w["backbone.vit.norm.weight"], self.w["backbone.vit.norm.bias"])
        t = t.reshape(3, s, s, -1).transpose(0, 3, 1, 2)  # (3, w, s, s)
        # ConvTranspose2d with kernel = stride: each token paints its own k x k block
        w_up, b_up = self.w["backbone.up.weight"], self.w["backbone.up.bias"]  # (w, o, k, k)
        k = w_up.shape[-1]
        up = np.einsum("mcij,coab->moiajb", t, w_up).reshape(3, w_up.shape[1], s * k, s * k)
        up += b_up[None, :, None, None]
        r = self._conv("backbone.residual.2", gelu(self._conv("backbone.residual.0", x)))
        return (up + r).astype(np.float32)

    def query(self, planes: np.ndarray, xyz: np.ndarray) -> np.ndarray:
        """(3, C, P, P) planes, (n, 3) points -> (n, dim) float32 unit features."""
        xyz = np.asarray(xyz, np.float32)
        raw = sum(sample_grid(planes[k], xyz[:, list(axes)]) for k, axes in enumerate(PLANE_AXES))
        f = raw[:, self.sdf_channels :]
        return f / np.maximum(np.linalg.norm(f, axis=1, keepdims=True), np.float32(1e-12))


class NumpyModelSource:
    """:class:`~pointcvx.model.source.ModelFeatureSource` (one view) in numpy: the cloud is
    encoded once; :meth:`features` samples the planes."""

    name = "model"

    def __init__(self, net: NumpyFeatureNet, cloud_points: np.ndarray,
                 cloud_normals: np.ndarray | None = None):
        self.net = net
        pts = np.asarray(cloud_points, np.float32)
        nrm = np.zeros_like(pts) if cloud_normals is None else np.asarray(cloud_normals, np.float32)
        self.planes = net.encode(pts, nrm)

    views = 1

    @property
    def dim(self) -> int:
        return self.net.dim

    def features(self, points: np.ndarray, chunk: int = 65536) -> np.ndarray:
        """(n, 3) float points -> (n, dim) float32 unit features."""
        points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
        out = [self.net.query(self.planes, points[s : s + chunk]) for s in range(0, len(points), chunk)]
        return np.concatenate(out).astype(np.float32) if out else np.zeros((0, self.dim), np.float32)
