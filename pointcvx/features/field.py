"""Per-shape feature fields in numpy: xyz -> unit features, fitted to one shape's convex pairs.

A Fourier-feature ReLU MLP (sin/cos of xyz in 4 octaves, width 64, depth 3, 32 unit features)
fitted with Adam (cosine-decayed learning rate) to the symmetric InfoNCE loss (temperature 0.3)
on batches of 128 anchors and 64 of their negatives per step, with a hand-written backward pass
on one BLAS thread: a process that decomposes a mesh never imports torch (about 1.5 s of a
one-shot run). :func:`pointcvx.pipeline.compute_features` uses it two ways:

- ``features="optimize"`` (the default on meshes, CAD parts and scans): 300 steps at learning
  rate 3e-3 on :data:`pointcvx.pipeline.SINGLE_SHAPE_TRIPLETS` (256 candidates per anchor);
- ``features="fast"`` (opt-in): 100 steps at 1e-2 on 128 candidates per anchor
  (:data:`FAST_TRIPLETS`, :data:`FAST_STEPS`, :data:`FAST_LR`).

The negatives are drawn for all anchors at once (:func:`sample_field_triplets`), from the same
distribution as :func:`pointcvx.features.sample_triplets`. docs/benchmarks.md, "Feature
sources", has the measurements. Deterministic for a seed.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ..workers import even_slices, pmap
from .pairs import Triplets, anchor_candidates

try:  # the compiled routines behind scipy's sparse matrices (:func:`_spread`)
    from scipy.sparse import _sparsetools
except ImportError:  # pragma: no cover - a scipy that moved them: the public path
    _sparsetools = None

#: Triplet settings of the fast source (:func:`sample_field_triplets`).
FAST_TRIPLETS = {"pool_size": 8192, "n_anchors": 4096, "n_candidates": 128,
                 "n_hard": 64, "n_uniform": 64}
#: Fit settings of the fast source (:func:`fit_field`).
FAST_STEPS = 100
FAST_LR = 1e-2
#: A fit's step evaluates its rows forward and back in this many chunks, on the worker threads
#: (:mod:`pointcvx.workers`): a fixed number, so the sums (hence the field) are the same with
#: any number of threads.
STEP_CHUNKS = 2


def _draw_columns(rng: np.random.Generator, weights: np.ndarray, k: int) -> np.ndarray:
    """(a, k) column indices, drawn with replacement in each row of (a, c) non-negative
    ``weights`` (each row with a positive sum) with probability proportional to its weights."""
    a, c = weights.shape
    cum = np.cumsum(weights, axis=1)
    cum /= cum[:, -1:]
    rows = np.arange(a)[:, None]
    flat = (cum + rows).ravel()  # row i's cumulative weights live in (i, i + 1]
    u = rng.random((a, k)) + rows
    cols = np.searchsorted(flat, u.ravel(), side="right").reshape(a, k) - rows * c
    return np.clip(cols, 0, c - 1)


def sample_field_triplets(solid, points: np.ndarray, normals: np.ndarray, *,
                          pool_size: int | None = 8192, n_anchors: int = 4096, n_candidates: int = 128,
                          n_hard: int = 64, n_uniform: int = 64, power: float = 1.0,
                          seed: int = 0) -> Triplets:
    """Anchors, positives and hard/uniform negatives as
    :func:`pointcvx.features.sample_triplets` defines them (same pool, anchors, rays and
    weights), with the negatives drawn for all anchors in one vectorised pass (the draws, not
    their distribution, differ). ``points`` (n, 3) float and ``normals`` (n, 3) float are the
    surface samples of ``solid``; negative has ``n_uniform + n_hard`` columns. Seeded."""
    rng = np.random.default_rng(seed)
    points, anchor, pos, cand, neg = anchor_candidates(solid, points, normals, rng, n_anchors=n_anchors,
                                                       n_candidates=n_candidates, pool_size=pool_size)
    parts = [np.zeros((len(anchor), 0), np.int64)]
    if len(anchor) and n_uniform:
        parts.append(np.take_along_axis(cand, _draw_columns(rng, neg.astype(np.float64), n_uniform), 1))
    if len(anchor) and n_hard:
        d = np.linalg.norm(points[cand] - pos[:, None, :], axis=2)
        w = np.where(neg, 1.0 / (d + 1e-3) ** power, 0.0)
        parts.append(np.take_along_axis(cand, _draw_columns(rng, w, n_hard), 1))
    return Triplets(points, anchor, pos, np.concatenate(parts, axis=1).astype(np.int64))


class FourierField:
    """A :class:`~pointcvx.features.FeatureSource`: xyz (n, 3) -> (n, dim) unit features through
    sin/cos encodings and a ReLU MLP.

    Attributes
    ----------
    params : list of ((d_in, d_out) float32, (d_out,) float32), the layers' weights and biases.
    freqs : (n_freqs,) float32
    losses : list of float, the loss at each fitting step.
    """

    name = "field"

    def __init__(self, params: list, freqs: np.ndarray):
        self.params = params
        self.freqs = freqs
        self.losses: list[float] = []

    @classmethod
    def initial(cls, rng: np.random.Generator, dim: int = 32, n_freqs: int = 4, width: int = 64,
                depth: int = 3) -> FourierField:
        """A field with layers initialised as torch's ``nn.Linear`` does (uniform in
        +-1/sqrt(fan_in)), drawn from ``rng``: ``depth`` hidden layers of ``width``, ``dim``
        output features, ``n_freqs`` octaves of sin/cos per coordinate."""
        params, d_in = [], 3 + 6 * n_freqs
        for d_out in [width] * depth + [dim]:
            bound = 1.0 / math.sqrt(d_in)
            params.append((rng.uniform(-bound, bound, (d_in, d_out)).astype(np.float32),
                           rng.uniform(-bound, bound, d_out).astype(np.float32)))
            d_in = d_out
        return cls(params, ((2.0 ** np.arange(n_freqs)) * np.pi).astype(np.float32))

    @property
    def dim(self) -> int:
        """Number of features per point."""
        return self.params[-1][0].shape[1]

    def _encode(self, xyz: np.ndarray) -> np.ndarray:
        """(n, 3) points -> (n, 3 + 6 * n_freqs) float32: xyz, then sin and cos of each octave."""
        x = np.asarray(xyz, dtype=np.float32).reshape(-1, 3)
        ang = (x[:, :, None] * self.freqs).reshape(len(x), -1)
        return np.concatenate([x, np.sin(ang), np.cos(ang)], axis=1)

    def _forward(self, xyz: np.ndarray):
        """(n, dim) unit features of (n, 3) points, the layers' inputs and outputs (list of
        (n, d) float32: the encoding, then each layer after its ReLU) and the (n, 1) norms of the
        raw outputs, the last two kept for :meth:`_backward`."""
        return self._forward_encoded(self._encode(xyz))

    def _forward_encoded(self, h: np.ndarray):
        """:meth:`_forward` from the (n, 3 + 6 * n_freqs) encodings of the points (a fit
        encodes its pool once, not at every step)."""
        acts = [h]
        for i, (w, b) in enumerate(self.params):
            h = h @ w
            h += b
            if i < len(self.params) - 1:
                np.maximum(h, 0, out=h)
            acts.append(h)
        norm = np.maximum(np.sqrt(np.einsum("ij,ij->i", h, h)), 1e-12)[:, None]
        return h / norm, acts, norm

    def _backward(self, grad: np.ndarray, feats: np.ndarray, acts: list, norm: np.ndarray) -> list:
        """Gradients of the layers' (weights, biases), as :attr:`params` holds them, from the
        (n, dim) gradient w.r.t. the (n, dim) unit features of :meth:`_forward`."""
        g = grad - feats * np.einsum("ij,ij->i", feats, grad)[:, None]
        g /= norm
        grads = [None] * len(self.params)
        ones = np.ones(len(g), g.dtype)  # a bias's gradient as a product: 6x faster than g.sum(0)
        for i in range(len(self.params) - 1, -1, -1):
            grads[i] = (acts[i].T @ g, ones @ g)
            if i > 0:
                g = g @ self.params[i][0].T
                np.multiply(g, acts[i] > 0, out=g)  # through the ReLU
        return grads

    def features(self, points: np.ndarray, chunk: int = 65536) -> np.ndarray:
        """(n, 3) float points (normalised frame) -> (n, dim) float32 unit features."""
        from threadpoolctl import threadpool_limits

        points = np.asarray(points).reshape(-1, 3)
        with threadpool_limits(1):
            out = [self._forward(points[s : s + chunk])[0] for s in range(0, len(points), chunk)]
        return np.concatenate(out).astype(np.float32) if out else np.zeros((0, self.dim), np.float32)


def info_nce_grad(anchor: np.ndarray, positive: np.ndarray, negatives: np.ndarray, tau: float):
    """The symmetric InfoNCE of :func:`pointcvx.features.loss.info_nce` on unit features and its
    gradients, for (a, k) anchors and positives and (a, m, k) negatives at temperature ``tau``:
    (loss, d/d anchor (a, k), d/d positive (a, k), d/d negatives (a, m, k))."""
    a = len(anchor)
    ap = (anchor * positive).sum(1)
    loss = 0.0
    g_anchor, g_positive = np.zeros_like(anchor), np.zeros_like(positive)
    g_neg = np.zeros_like(negatives)
    for query, g_query in ((anchor, g_anchor), (positive, g_positive)):
        logits = np.concatenate([ap[:, None], np.einsum("ak,amk->am", query, negatives)], 1) / tau
        top = logits.max(1, keepdims=True)
        e = np.exp(logits - top)
        z = e.sum(1, keepdims=True)
        loss += float((np.log(z[:, 0]) + top[:, 0] - logits[:, 0]).mean())
        s = e / z
        s[:, 0] -= 1.0
        s *= 0.5 / (a * tau)  # d(0.5 * mean cross-entropy) / d(similarity)
        g_anchor += s[:, :1] * positive
        g_positive += s[:, :1] * anchor
        g_query += np.einsum("am,amk->ak", s[:, 1:], negatives)
        g_neg += s[:, 1:, None] * query[:, None, :]
    return 0.5 * loss, g_anchor, g_positive, g_neg


def pool_info_nce_grad(pool: np.ndarray, anchor: np.ndarray, positive: np.ndarray,
                       negative: np.ndarray, tau: float, chunks: int = 1):
    """:func:`info_nce_grad` with the anchors and negatives given as rows of one (u, k) ``pool``
    of unit features: (a,) int ``anchor`` and (a, m) int ``negative`` index it, (a, k)
    ``positive`` are the positives' features. Returns (loss, d/d pool (u, k), d/d positive
    (a, k)), the gradients of the rows summed over every place they are used. The negatives'
    gradients go to the pool through one sparse (u, 2a) product instead of an (a, m, k) array
    scattered row by row: the fit's step is a third faster, the same sums in another order.
    The anchors are taken in ``chunks`` runs on the worker threads (:mod:`pointcvx.workers`),
    their pool gradients summed: the same up to round-off as one run, whatever the threads."""
    a = len(anchor)
    runs = even_slices(a, chunks)
    parts = pmap(lambda r: _pool_info_nce_run(pool, anchor[r], positive[r], negative[r], tau, a), runs)
    g_pool = parts[0][1]
    for _, more, _ in parts[1:]:
        g_pool += more
    return sum(p[0] for p in parts) / (2 * a), g_pool, np.concatenate([p[2] for p in parts])


def _pool_info_nce_run(pool: np.ndarray, anchor: np.ndarray, positive: np.ndarray,
                       negative: np.ndarray, tau: float, total: int):
    """One run of :func:`pool_info_nce_grad`'s anchors, of ``total`` in the step: (sum of its
    2a cross-entropies, its (u, k) pool gradient, its (a, k) positive gradient)."""
    a, m = negative.shape
    anc = pool[anchor]
    negf = pool[negative]  # (a, m, k)
    queries = np.concatenate([anc, positive])  # (2a, k): each query is scored against its negatives
    logits = np.empty((2 * a, m + 1), pool.dtype)
    logits[:a, 0] = logits[a:, 0] = np.einsum("ak,ak->a", anc, positive)
    logits[:a, 1:] = np.einsum("ak,amk->am", anc, negf)
    logits[a:, 1:] = np.einsum("ak,amk->am", positive, negf)
    logits /= tau
    top = logits.max(1, keepdims=True)
    e = np.exp(logits - top)
    z = e.sum(1, keepdims=True)
    loss = float((np.log(z[:, 0]) + top[:, 0] - logits[:, 0]).sum())
    s = e / z
    s[:, 0] -= 1.0
    s *= 0.5 / (total * tau)  # d(0.5 * mean cross-entropy) / d(similarity), per direction
    both = (s[:a, 0] + s[a:, 0])[:, None]  # the anchor-positive similarity is in both directions
    sn = s[:, 1:]
    g_anchor = both * positive + np.einsum("am,amk->ak", sn[:a], negf)
    g_positive = both * anc + np.einsum("am,amk->ak", sn[a:], negf)
    g_pool = _spread(negative, sn, queries, len(pool))
    np.add.at(g_pool, anchor, g_anchor)
    return loss, g_pool, g_positive


def _spread(negative: np.ndarray, weights: np.ndarray, queries: np.ndarray, n: int) -> np.ndarray:
    """(n, k) float32: row ``i`` sums ``weights[q, j] * queries[q]`` over the places (q, j) where
    query ``q`` has pool row ``i`` as its ``j``-th negative; (a, m) int ``negative`` serves the
    first and second ``a`` of the (2a, m) float32 ``weights`` and (2a, k) float32 ``queries``.

    The sparse (n, 2a) product of scipy's ``csr_matrix((data, (rows, cols))) @ queries``, built
    by the same compiled routines without the wrapper's checks (half of this step's time at a
    fit's sizes): the same sums in the same order, bit for bit. scipy's public path where those
    routines are missing."""
    a2, m = weights.shape
    rows = np.concatenate([negative, negative]).ravel()
    if _sparsetools is None or n >= 2**31 or a2 * m >= 2**31:
        from scipy import sparse

        cols = np.repeat(np.arange(a2), m)
        spread = sparse.csr_matrix((weights.ravel(), (rows, cols)), shape=(n, a2))
        return np.asarray(spread @ queries, dtype=queries.dtype)
    rows = rows.astype(np.int32)
    cols = np.repeat(np.arange(a2, dtype=np.int32), m)
    nnz = len(rows)
    indptr, indices = np.empty(n + 1, np.int32), np.empty(nnz, np.int32)
    data = np.empty(nnz, weights.dtype)
    _sparsetools.coo_tocsr(n, a2, nnz, rows, cols, np.ascontiguousarray(weights).ravel(),
                           indptr, indices, data)
    # each row's columns are already in order (the entries come query by query): only the
    # repeated ones (a negative drawn twice for one query) are summed, as csr_matrix does
    _sparsetools.csr_sum_duplicates(n, a2, indptr, indices, data)
    nnz = int(indptr[-1])
    out = np.zeros((n, queries.shape[1]), np.result_type(weights, queries))
    _sparsetools.csr_matvecs(n, a2, queries.shape[1], indptr, indices[:nnz], data[:nnz],
                             np.ascontiguousarray(queries).ravel(), out.ravel())
    return out


def _unique_rows(idx: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(idx, return_inverse=True)`` for (k,) int ``idx`` in [0, n), by marking
    instead of sorting (7x faster at a step's 8,000 indices of 8,192)."""
    mark = np.zeros(n, bool)
    mark[idx] = True
    return np.flatnonzero(mark), (np.cumsum(mark) - 1)[idx]


def _flatten(params: list) -> tuple[np.ndarray, list]:
    """(p,) float32: the layers' (weight, bias) arrays of ``params`` one after the other, and
    the same layers as views of it."""
    flat = np.concatenate([part.ravel() for layer in params for part in layer])
    views, at = [], 0
    for layer in params:
        parts = []
        for part in layer:
            parts.append(flat[at : at + part.size].reshape(part.shape))
            at += part.size
        views.append(tuple(parts))
    return flat, views


def step_gradients(field: FourierField, rng: np.random.Generator, enc_pool: np.ndarray,
                   enc_pos: np.ndarray, anchor: np.ndarray, negative: np.ndarray, batch: int,
                   negatives_per_step: int, tau: float) -> tuple[float, list]:
    """One step of :func:`fit_field` before its update: draws ``batch`` anchors and
    ``negatives_per_step`` of each one's (a, k) ``negative`` columns from ``rng``, evaluates the
    field once on the (u, e) encoded pool rows involved and the (a, e) encoded positives, and
    returns (loss, the layers' gradients of each of the :data:`STEP_CHUNKS` row chunks, as
    :meth:`FourierField._backward` gives them), the chunks on the worker threads."""
    pick = rng.integers(0, len(anchor), min(batch, len(anchor)))
    cols = rng.integers(0, negative.shape[1], (len(pick), negatives_per_step))
    neg = np.take_along_axis(negative[pick], cols, 1)
    used, inv = _unique_rows(np.concatenate([anchor[pick], neg.ravel()]), len(enc_pool))
    a_idx, n_idx = inv[: len(pick)], inv[len(pick) :].reshape(neg.shape)
    rows = np.concatenate([enc_pool[used], enc_pos[pick]])
    chunks = even_slices(len(rows), STEP_CHUNKS)
    ahead = pmap(field._forward_encoded, [rows[c] for c in chunks])
    feats = np.concatenate([f for f, _, _ in ahead])
    f_pool, f_pos = feats[: len(used)], feats[len(used) :]
    loss, g_pool, g_p = pool_info_nce_grad(f_pool, a_idx, f_pos, n_idx, tau, STEP_CHUNKS)
    grad = np.concatenate([g_pool, g_p])
    back = pmap(lambda job: field._backward(*job),
                [(grad[c], *a) for c, a in zip(chunks, ahead, strict=True)])
    return loss, back


def fit_field(triplets: Triplets, *, dim: int = 32, steps: int = FAST_STEPS, batch: int = 128,
              negatives_per_step: int = 64, lr: float = FAST_LR, tau: float = 0.3, seed: int = 0,
              betas: tuple = (0.9, 0.999), eps: float = 1e-8,
              progress: Callable[[int, float], None] | None = None) -> FourierField:
    """Fit a :class:`FourierField` to ``triplets`` with Adam (cosine-decayed learning rate) and the
    symmetric InfoNCE loss (:func:`pointcvx.features.loss.info_nce`): each step
    draws ``batch`` anchors and ``negatives_per_step`` of each one's negatives, and evaluates
    the field once on the pool points involved. ``progress(step, loss)`` after each step.
    One BLAS thread per worker thread; each step's rows go forward and back in
    :data:`STEP_CHUNKS` chunks on the worker threads. Deterministic for a seed, whatever the
    number of threads."""
    from threadpoolctl import threadpool_limits

    rng = np.random.default_rng(seed)
    field = FourierField.initial(rng, dim=dim)
    if len(triplets) == 0 or steps <= 0:  # convex shape: nothing to separate
        return field
    pool = np.asarray(triplets.pool, dtype=np.float32)
    anchor = np.asarray(triplets.anchor)
    positive = np.asarray(triplets.positive, dtype=np.float32)
    negative = np.asarray(triplets.negative)
    # The layers' weights and biases as views of one flat vector, so that each Adam update is
    # a handful of operations on it, not a handful per array: element by element the same
    # arithmetic (the parameters after each step are the same, bit for bit).
    flat, field.params = _flatten(field.params)
    m, v = np.zeros_like(flat), np.zeros_like(flat)
    b1, b2 = betas
    with threadpool_limits(1):
        enc_pool, enc_pos = field._encode(pool), field._encode(positive)
        for step in range(steps):
            rate = lr * 0.5 * (1.0 + math.cos(math.pi * step / steps))
            loss, back = step_gradients(field, rng, enc_pool, enc_pos, anchor, negative, batch,
                                        negatives_per_step, tau)
            t = step + 1
            g = 0  # the chunks' gradients summed in chunk order
            for chunk_grads in back:
                g = g + np.concatenate([part.ravel() for layer in chunk_grads for part in layer])
            m *= b1
            m += (1 - b1) * g
            v *= b2
            v += (1 - b2) * g * g
            flat -= (rate / (1 - b1**t)) * m / (np.sqrt(v / (1 - b2**t)) + eps)
            field.losses.append(loss)
            if progress is not None:
                progress(step, loss)
    return field
