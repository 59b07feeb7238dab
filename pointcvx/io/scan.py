"""Scans: point clouds without (trustworthy) normals -> oriented clouds (``modality="scan"``).

The file readers (PLY vertices, OBJ ``v`` lines, PCD, XYZ/PTS, LAS) are in
:mod:`pointcvx.io.pointfiles`; :func:`cloud_from_points` turns their arrays into an
:class:`~pointcvx.cloud.OrientedCloud`:

1. non-finite coordinates are rejected (:class:`~pointcvx.errors.InputError` naming how many);
   files are cleaned first: :func:`load_scan_file` drops and counts the rows without a usable
   position (NaN is "no measurement" in organised depth frames), see :func:`drop_unusable`;
2. optional voxel down-sampling (points and colours averaged per voxel), and with ``n_points``
   a seeded thinning of very large inputs;
3. statistical outlier removal (mean distance to the k nearest neighbours above the global mean
   plus ``outlier_std`` standard deviations);
4. normals: PCA of the ``normal_neighbors`` nearest neighbours when the input has none;
5. a consistent outward sign: :func:`pointcvx.io.orient.orient_normals` (MST propagation, then a
   convex-hull vote per piece), then :func:`face_one_viewer`, which turns every piece of a partial
   (one-sided) scan towards the same viewer. Normals read from the file keep their sign when it
   is consistent with that result (:func:`orient_given_normals`). An organised depth frame's
   normals, estimated or read, are instead turned to face its sensor (:func:`face_sensor`): one
   frame sees only surfaces that face it.

``cloud.info`` records ``normals`` (how they were obtained), ``normals_flipped``,
``non_finite_dropped`` (files), ``organized`` and ``viewpoint`` (PCD frames),
``dropped_outliers``, ``one_sided`` and ``openness``, ``colors``, ``input_points`` and, when they
happened, ``voxel_downsampled_from`` and ``presampled_from``.
"""

from __future__ import annotations

import logging
import os

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from ..cloud import MAX_COORDINATE, OrientedCloud, check_extent, check_points
from ..errors import InputError
from ..scene import frame_sensor
from .orient import estimate_normals, orient_normals
from .outliers import outlier_mask
from .pointfiles import Arrays, read_scan

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
#: view): closed surfaces measure about 0, single views of them well above this.
ONE_SIDED_OPENNESS = 0.3


# ---------------------------------------------------------------------------------------- filters
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


def face_sensor(points: np.ndarray, normals: np.ndarray, sensor: np.ndarray) -> tuple[np.ndarray, int]:
    """(n, 3) ``normals`` of (n, 3) ``points`` turned to face ``sensor`` (3,), and how many were
    flipped. In one depth frame every measured surface faced the sensor, so its outward normal
    has a positive component towards it: the sign needs no propagation, and one frame's pieces
    cannot disagree. (The convex-hull vote of :func:`orient_normals` would read a frame's far
    walls, the bulk of its hull, as the outside, and turn them away from the sensor.)"""
    flip = np.einsum("ij,ij->i", normals, sensor - points) < 0
    return np.where(flip[:, None], -normals, normals), int(flip.sum())


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
    cap: bool = True,
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
        Statistical outlier removal (:func:`pointcvx.io.outliers.outlier_mask`); 0 neighbours disables it.
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
    cap : bool
        Apply the ``n_points`` cap here. ``load`` passes False: it caps after isolating the
        object (:func:`pointcvx.io.finalize`), so a frame whose object is a quarter of its points
        still gives the object the whole budget.

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

    outliers = outlier_mask(pts, outlier_neighbors, outlier_std)
    meta["dropped_outliers"] = int(outliers.sum())
    if outliers.any():
        inliers = ~outliers
        pts = pts[inliers]
        normals = None if normals is None else normals[inliers]
        colors = None if colors is None else colors[inliers]
        log.debug("dropped %d statistical outliers", int(outliers.sum()))
    check_extent(pts)

    k_orient = min(ORIENT_NEIGHBORS, normal_neighbors, len(pts) - 1)
    k_pca = min(normal_neighbors, len(pts) - 1)
    sensor = frame_sensor(meta)
    if sensor is not None:  # one depth frame: every normal faces the sensor
        given = normals is not None
        if not given:
            normals = estimate_normals(pts, k=k_pca)
        normals, flipped = face_sensor(pts, normals, sensor)
        details = {"one_sided": True}
        meta["normals"] = ("from file" if given else f"estimated (PCA k={k_pca})") + ", facing the sensor"
    elif normals is None:
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
    if n_points is not None and cap:
        cloud = cloud.resample(n_points, seed=seed)
    return cloud


def usable_rows(points: np.ndarray) -> tuple[np.ndarray, int, int]:
    """(n,) bool: rows of (n, 3) ``points`` that are finite and within :data:`MAX_COORDINATE`;
    and how many are non-finite and how many lie beyond it."""
    finite = np.isfinite(points).all(axis=1)
    magnitude = np.abs(np.where(finite[:, None], points, 0.0)).max(axis=1, initial=0.0)
    far = finite & (magnitude > MAX_COORDINATE)
    return finite & ~far, int((~finite).sum()), int(far.sum())


def drop_unusable(points: np.ndarray, normals: np.ndarray | None, colors: np.ndarray | None,
                  meta: dict) -> Arrays:
    """Drop the rows of a scan whose coordinates are NaN or infinite (in organised depth frames
    they mean "no measurement") or beyond :data:`MAX_COORDINATE`, counting them in ``meta``
    (``non_finite_dropped``, and ``out_of_range_dropped`` when any). :class:`InputError` when
    fewer than 4 usable points remain."""
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"points must have shape (n, 3), got {points.shape}")
    keep, non_finite, far = usable_rows(points)
    meta["non_finite_dropped"] = non_finite
    if far:
        meta["out_of_range_dropped"] = far
    left = int(keep.sum())
    if left < 4:
        beyond = f", {far} beyond {MAX_COORDINATE:g}" if far else ""
        raise InputError(f"only {left} of {len(points)} points are usable ({non_finite} NaN or infinite"
                         f"{beyond}): at least 4 finite points are needed")
    if left == len(points):
        return points, normals, colors
    log.info("dropped %d non-finite and %d out-of-range points of %d", non_finite, far, len(points))
    return (points[keep], None if normals is None else np.asarray(normals)[keep],
            None if colors is None else np.asarray(colors)[keep])


def load_scan_file(path: str | os.PathLike, fmt: str, opts) -> OrientedCloud:
    """Read a point-cloud file (``fmt`` from :func:`pointcvx.io.sniff.detect`) and orient it.

    Rows without a usable position are dropped first (:func:`drop_unusable`). ``opts`` is a
    :class:`pointcvx.io.options.LoadOptions`; the scan fields are passed to
    :func:`cloud_from_points`. The cloud stays in the file's units (``load`` normalises).
    """
    meta: dict = {"source": str(path)}
    points, normals, colors = read_scan(path, fmt, meta)
    log.debug("%s: read %d points (normals: %s, colours: %s)", path, len(points),
              normals is not None, colors is not None)
    try:
        points, normals, colors = drop_unusable(points, normals, colors, meta)
        return cloud_from_points(
            points, normals, colors,
            outlier_neighbors=opts.outlier_neighbors,
            outlier_std=opts.outlier_std,
            voxel_size=opts.voxel_size,
            normal_neighbors=opts.normal_neighbors,
            n_points=opts.n_points,
            seed=opts.seed,
            modality="scan",
            info=meta,
            cap=False,
        )
    except InputError as exc:  # name the file in checks that only know the arrays
        if str(path) in str(exc):
            raise
        raise type(exc)(f"{path}: {exc}") from None
