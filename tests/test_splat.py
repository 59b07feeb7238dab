"""Gaussian splat loading: decoders against the dev captures, normals, filters, corrupt input.

The thresholds on the dev captures sit a little under what the loader reaches on them: centres of
each compressed copy against its plain PLY, and normals against PCA normals of the kept centres
(``estimate_normals``, k=24): the fraction with |cos| > 0.7, and the sign agreement there once
the PCA normals are oriented the same way.
"""

from __future__ import annotations

import gzip
import struct

import numpy as np
import pytest

import pointcvx
from conftest import DATA, SAMPLES, dev_files, load_tool
from pointcvx.errors import InputError
from pointcvx.io import splat as S
from pointcvx.io.orient import estimate_normals, orient_normals
from pointcvx.io.ply import read_header

SPLATS = DATA / "dev" / "splats"

_loaded: dict[str, pointcvx.OrientedCloud] = {}


def load_dev(name: str) -> pointcvx.OrientedCloud:
    """A dev splat loaded in its own units, once per test session."""
    if name not in _loaded:
        _loaded[name] = pointcvx.load(SPLATS / name, normalize=False)
    return _loaded[name]


# ------------------------------------------------------------------------ synthetic splats
def _frames(normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n, 4) quaternions whose third local axis is ``normals`` (random in-plane turn)."""
    t = np.cross(normals, rng.normal(size=normals.shape))
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(normals, t)
    mats = np.stack([t, b, normals], axis=2)
    return np.array([S.matrix_quaternion(m) for m in mats])


def _shape_gaussians(shape: str, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Flat Gaussians on a unit sphere or a [-1, 1]^3 box, with their true outward normals."""
    if shape == "sphere":
        normals = rng.normal(size=(n, 3))
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        centers = normals.copy()
    else:
        face = rng.integers(0, 6, n)
        axis, side = face % 3, np.where(face < 3, 1.0, -1.0)
        centers = rng.uniform(-1, 1, size=(n, 3))
        centers[np.arange(n), axis] = side
        normals = np.zeros((n, 3))
        normals[np.arange(n), axis] = side
    rotations = _frames(normals, rng)
    # Some Gaussians point their short axis inward (half turn about the first axis), others have
    # the negated, equivalent quaternion: neither may change the loader's outward normals.
    inward = rng.random(n) < 0.3
    rotations[inward] = np.array([S.quaternion_product(q, (0.0, 1.0, 0.0, 0.0)) for q in rotations[inward]])
    negated = rng.random(n) < 0.3
    rotations[negated] *= -1
    scales = np.stack([rng.uniform(0.02, 0.04, n), rng.uniform(0.02, 0.04, n), np.full(n, 0.002)], axis=1)
    centers = centers + normals * rng.normal(scale=0.003, size=(n, 1))
    return {"centers": centers, "scales": scales, "rotations": rotations,
            "opacity": rng.uniform(0.5, 0.95, n), "colors": rng.uniform(0, 1, (n, 3)), "truth": normals}


def _write(path, g, rng=None, **kw):
    S.write_inria_ply(path, g["centers"], g["scales"], g["rotations"], g["opacity"], g["colors"],
                      rng=rng, **kw)


def _truth_normals(shape: str, points: np.ndarray) -> np.ndarray:
    if shape == "sphere":
        return points / np.linalg.norm(points, axis=1, keepdims=True)
    out = np.zeros_like(points)
    axis = np.argmax(np.abs(points), axis=1)
    out[np.arange(len(points)), axis] = np.sign(points[np.arange(len(points)), axis])
    return out


# ------------------------------------------------------------------------------- dev data
@pytest.mark.parametrize("path", dev_files("splats"), ids=lambda p: p.name)
def test_every_dev_splat_loads_oriented(path):
    cloud = load_dev(path.name)
    assert cloud.modality == "splat"
    assert len(cloud) > 1000
    assert np.allclose(np.linalg.norm(cloud.normals, axis=1), 1.0)
    assert cloud.colors is not None and cloud.colors.dtype == np.float32
    assert cloud.weights is not None and (cloud.weights >= 0).all()
    info = cloud.info
    for key in ("format_detail", "gaussians", "dropped_low_opacity", "dropped_floaters",
                "dropped_outliers", "normals", "normals_flipped", "sh_degree"):
        assert key in info, key
    kept = info["gaussians"] - info["dropped_nonfinite"] - info["dropped_low_opacity"]
    isolated = sum(info["isolation"]["removed"].values())  # ground and clutter (pointcvx.scene)
    closed = info["isolation"].get("base", {}).get("points", 0)  # samples closing bases (pointcvx.scene)
    assert len(cloud) == kept - info["dropped_floaters"] - info["dropped_outliers"] - isolated + closed
    normalized = pointcvx.load(path, n_points=2000) if path.name == "donut.ply" else None
    if normalized is not None:
        assert len(normalized) == 2000 and np.abs(normalized.points).max() <= 1 + 1e-9


def test_dev_formats_and_sh_degree():
    assert load_dev("scene_tile_full_sh.ply").info["sh_degree"] == 3
    assert "v4" in load_dev("biker.spz").info["format_detail"]
    assert "compressed" in load_dev("guitar.compressed.ply").info["format_detail"]


def _compare(decoded, truth, centre_tol):
    assert len(decoded["centers"]) == len(truth["centers"])
    err = np.abs(decoded["centers"] - truth["centers"]).max()
    assert err <= centre_tol, err
    assert np.abs(np.log(decoded["scales"]) - np.log(truth["scales"])).max() < 1e-3
    assert np.abs(decoded["opacity"] - truth["opacity"]).max() < 1e-3
    assert np.abs(decoded["colors"] - truth["colors"]).max() < 1e-3
    assert np.abs((decoded["rotations"] * truth["rotations"]).sum(axis=1)).min() > 0.999


def test_compressed_ply_matches_decompressed_guitar():
    decoded = S.read_compressed_ply(SPLATS / "guitar.compressed.ply")
    truth = S.read_inria_ply(SPLATS / "guitar.ply")
    _compare(decoded, truth, centre_tol=1e-6)  # float32 rounding of the decompressed copy


def test_spz_v4_matches_decompressed_biker():
    decoded = S.read_spz(SPLATS / "biker.spz")
    truth = S.read_inria_ply(SPLATS / "biker.ply")
    assert len(decoded["centers"]) == 152746
    _compare(decoded, truth, centre_tol=1e-6)  # the PLY holds SPZ's fixed-point values (step 2^-12)


# name, fraction |cos| > 0.7 with PCA, sign agreement once oriented (each under the measured value)
AGREEMENT = [
    ("donut.ply", 0.82, 0.95),
    ("guitar.compressed.ply", 0.72, 0.91),
    ("biker.spz", 0.72, 0.92),
    ("scene_tile_full_sh.ply", 0.88, 0.94),
]


@pytest.mark.parametrize(("name", "min_unsigned", "min_signed"), AGREEMENT, ids=[a[0] for a in AGREEMENT])
def test_normals_agree_with_point_pca(name, min_unsigned, min_signed):
    # The loader's normals are those of the whole splat (isolation comes after them); re-orient
    # PCA normals on the same points, ground included.
    cloud = pointcvx.load(SPLATS / name, normalize=False, isolate="none")
    pca = estimate_normals(cloud.points, 24)
    cos = np.einsum("ij,ij->i", pca, cloud.normals)
    close = np.abs(cos) > 0.7
    assert close.mean() >= min_unsigned, close.mean()
    oriented, _ = orient_normals(cloud.points, pca, S.ORIENT_NEIGHBORS)
    oriented, _ = S.orient_by_visibility(cloud.points, oriented)
    same = np.einsum("ij,ij->i", oriented, cloud.normals)[close] > 0
    assert same.mean() >= min_signed, same.mean()


def test_first_layer_stops_at_a_gap():
    """Two pixels; in the first a front surface with depth noise and, 0.5 behind it, a back wall;
    in the second one point. Only the front surface and the lone point are the first layer."""
    rng = np.random.default_rng(0)
    front = 1.0 + 0.05 * rng.random(20)
    back = 0.5 + 0.05 * rng.random(20)
    key = np.r_[np.zeros(40, dtype=np.int64), 1]
    depth = np.r_[front, back, -3.0]
    perm = rng.permutation(41)  # any input order
    where = np.argsort(perm)  # original index -> position in the shuffled input
    seen = np.sort(S.first_layer(key[perm], depth[perm], gap=0.2, tolerance=10.0))
    assert seen.tolist() == sorted(where[list(range(20)) + [40]].tolist())
    # Without a wide enough gap, the tolerance alone bounds the layer.
    assert len(S.first_layer(key[perm], depth[perm], gap=1.0, tolerance=0.3)) == 21
    assert len(S.first_layer(key[perm], depth[perm], gap=1.0, tolerance=10.0)) == 41
    assert len(S.first_layer(key[:0], depth[:0], gap=1.0, tolerance=1.0)) == 0


def test_synthetic_splats_come_with_their_truth(tmp_path):
    """``tools/synthetic_splats.py`` writes a splat and the solid it was made from, in the same
    frame, with its floater cluster off the shape; ``tools/eval_dataset.py --truth`` finds the
    solid by stem."""
    import open3d as o3d
    import trimesh

    from pointcvx.solid import raycasting_scene

    assert load_tool("synthetic_splats").main([str(tmp_path), "--shapes", "1"]) == 0
    truth = trimesh.load(tmp_path / "truth" / "solid_00.obj", force="mesh")
    splat = tmp_path / "splats" / "solid_00.ply"
    cloud = pointcvx.load(splat, normalize=False)
    assert cloud.modality == "splat" and cloud.info["dropped_floaters"] == 90
    # Every loaded point lies on the true surface, within the depth noise (0.004): the frames
    # agree and nothing of the floater or the faint Gaussians is left.
    scene = raycasting_scene(np.asarray(truth.vertices), np.asarray(truth.faces))
    dist = scene.compute_distance(o3d.core.Tensor(cloud.points.astype(np.float32))).numpy()
    assert dist.max() < 0.03, dist.max()
    (tmp_path / "truth" / "solid_00.mtl").write_text("")
    eval_dataset, folder = load_tool("eval_dataset"), str(tmp_path / "truth")
    assert eval_dataset.truth_file(folder, str(splat)) == str(tmp_path / "truth" / "solid_00.obj")
    with pytest.raises(SystemExit):
        eval_dataset.truth_file(folder, str(tmp_path / "splats" / "other.ply"))


def test_bundled_mug_splat_normals_match_the_true_mug():
    """The bundled splat is made from a known solid (``tools/make_samples.py``): its normals are
    checked against the gradient of the mug's signed distance. The inner wall of the cup (under
    two visibility pixels behind the outer one) is the hard part: seen through the outer wall from
    the side, its points would vote their correct normals inward."""
    samples = load_tool("make_samples")
    cloud = pointcvx.load(SAMPLES / "mug_splat.ply", normalize=False)
    p, eps = cloud.points, 1e-4
    grad = np.stack([samples.mug_sdf(p + eps * e) - samples.mug_sdf(p - eps * e) for e in np.eye(3)], axis=1)
    outward = np.einsum("ij,ij->i", grad, cloud.normals) > 0
    assert outward.mean() >= 0.96, outward.mean()
    r = np.hypot(p[:, 0], p[:, 1])
    inner = (r > 0.28) & (r < 0.34) & (p[:, 2] > -0.35) & (p[:, 2] < 0.45)  # the cup's inner wall
    assert inner.sum() > 1000 and outward[inner].mean() >= 0.93, outward[inner].mean()


# ------------------------------------------------------------------------------ synthetic
@pytest.mark.parametrize("shape", ["sphere", "box"])
def test_closed_shape_normals_point_outward(tmp_path, shape):
    rng = np.random.default_rng(1)
    g = _shape_gaussians(shape, 6000, rng)
    path = tmp_path / f"{shape}.ply"
    _write(path, g, rng=np.random.default_rng(7), sh_degree=1, normals=True)
    cloud = pointcvx.load(path, normalize=False)
    truth = _truth_normals(shape, cloud.points)
    outward = np.einsum("ij,ij->i", cloud.normals, truth) > 0
    assert outward.mean() >= 0.99, outward.mean()
    assert cloud.info["sh_degree"] == 1


def test_large_splats_are_thinned_before_normals_and_stay_outward(tmp_path, monkeypatch):
    rng = np.random.default_rng(2)
    g = _shape_gaussians("sphere", 6000, rng)
    path = tmp_path / "sphere.ply"
    _write(path, g, rng=np.random.default_rng(7))
    # A small working budget (production: max(10 n_points, 200k)) so the test file stays small.
    monkeypatch.setattr(S, "WORK_MIN", 1500)
    monkeypatch.setattr(S, "WORK_FACTOR", 3)
    thin = pointcvx.load(path, normalize=False, n_points=400, seed=3)
    assert thin.info["gaussians_used"] == 1500 and len(thin) == 400
    assert pointcvx.load(path, normalize=False, n_points=400, seed=3).points.tolist() == thin.points.tolist()
    outward = np.einsum("ij,ij->i", thin.normals, _truth_normals("sphere", thin.points)) > 0
    assert outward.mean() >= 0.99, outward.mean()
    # Without a point budget every Gaussian is used.
    assert "gaussians_used" not in pointcvx.load(path, normalize=False).info


def test_inria_reader_takes_properties_by_name(tmp_path):
    rng = np.random.default_rng(2)
    g = _shape_gaussians("sphere", 500, rng)
    path = tmp_path / "shuffled.ply"
    _write(path, g, rng=np.random.default_rng(3), sh_degree=3, normals=True)
    names = read_header(path).properties("vertex")
    assert names[:3] != ("x", "y", "z")  # the order really is shuffled
    back = S.read_inria_ply(path)
    assert np.allclose(back["centers"], g["centers"], atol=1e-6)
    assert np.allclose(back["scales"], g["scales"], rtol=1e-5)
    assert np.allclose(np.abs((back["rotations"] * g["rotations"]).sum(axis=1)), 1.0, atol=1e-6)
    assert np.allclose(back["opacity"], g["opacity"], atol=1e-6)
    assert np.allclose(back["colors"], g["colors"], atol=1e-6)
    assert np.allclose(back["normals"], 0.0)


def test_gaussian_normals_take_the_shortest_axis():
    q = np.array([[1.0, 0, 0, 0], [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]])  # identity, 90 deg about z
    scales = np.array([[1.0, 2.0, 0.1], [0.1, 2.0, 1.0]])
    n = S.gaussian_normals(scales, q)
    assert np.allclose(np.abs(n), [[0, 0, 1], [0, 1, 0]], atol=1e-12)


def test_filters_drop_transparent_gaussians_and_floaters(tmp_path):
    rng = np.random.default_rng(4)
    g = _shape_gaussians("sphere", 5000, rng)
    faint = rng.choice(5000, 400, replace=False)
    g["opacity"][faint] = 0.02
    floater = 30  # a small dense cluster far away: 30 / 5030 < floater_ratio = 0.01
    far = np.array([8.0, 0.0, 0.0]) + rng.normal(scale=0.05, size=(floater, 3))
    for key, extra in (("centers", far), ("scales", np.full((floater, 3), 0.02)),
                       ("rotations", np.tile([1.0, 0, 0, 0], (floater, 1))),
                       ("opacity", np.full(floater, 0.9)), ("colors", np.full((floater, 3), 0.5))):
        g[key] = np.concatenate([g[key], extra])
    path = tmp_path / "floaters.ply"
    _write(path, g)
    cloud = pointcvx.load(path, normalize=False)
    assert cloud.info["dropped_low_opacity"] == 400
    assert cloud.info["dropped_floaters"] >= floater
    assert np.linalg.norm(cloud.points, axis=1).max() < 1.5
    assert len(cloud) >= 4600 - floater - 200  # few good Gaussians go
    with pytest.raises(InputError, match="no Gaussian is left"):
        pointcvx.load(path, min_opacity=0.99)


def test_gaussians_larger_than_the_splat_are_dropped_with_a_warning(tmp_path, caplog):
    # A log-scale of 80 is a Gaussian e^80 units across: no surface, and its size would reach the
    # weights and the samples. Those larger than the centres' bounding-box diagonal are dropped.
    rng = np.random.default_rng(12)
    g = _shape_gaussians("sphere", 2000, rng)
    g["scales"][:30, 0] = np.exp(80.0)
    path = tmp_path / "huge.ply"
    _write(path, g)
    with caplog.at_level("WARNING", logger="pointcvx"):
        cloud = pointcvx.load(path, normalize=False, samples_per_gaussian=2)
    assert cloud.info["dropped_huge_scales"] == 30
    assert "larger than the whole splat" in caplog.text
    assert np.abs(cloud.points).max() < 1.5 and cloud.weights.max() < 1.0
    g["scales"][:, 0] = np.exp(80.0)
    _write(path, g)
    with pytest.raises(InputError, match="larger than the splat"):
        pointcvx.load(path)
    # the dev captures have no Gaussian anywhere near that size: nothing of theirs is dropped
    for name in ("biker.ply", "scene_tile_full_sh.ply"):
        decoded = S.read_inria_ply(SPLATS / name)
        finite = S.finite_mask(decoded)
        assert S.scale_mask({k: v[finite] for k, v in decoded.items()}).all()


def test_compressed_ply_with_random_chunks_and_body_loads_or_is_an_input_error(tmp_path):
    # Random chunk ranges (log-scales in the hundreds) once made the mixture covariances
    # infinite: numpy's eigh failed to converge (LinAlgError) on most of these.
    g = _shape_gaussians("sphere", 600, np.random.default_rng(13))
    src = tmp_path / "ok.compressed.ply"
    compressed_ply = load_tool("hostile_corpus").compressed_ply
    src.write_bytes(compressed_ply(g))
    data = src.read_bytes()
    start = data.index(b"end_header") + 11
    for seed in range(6):
        rng = np.random.default_rng(seed)
        chunk = rng.normal(scale=float(rng.choice([1, 10, 100, 400])), size=(3, 12)).astype("<f4")
        path = tmp_path / f"random{seed}.compressed.ply"
        path.write_bytes(data[:start] + chunk.tobytes() + rng.bytes(len(data) - start - chunk.nbytes))
        try:
            cloud = pointcvx.load(path, n_points=1000)
        except InputError:
            continue
        assert np.isfinite(cloud.points).all() and np.isfinite(cloud.normals).all()


def test_spz_gzip_bomb_is_refused_before_inflating(tmp_path):
    # A valid SPZ header for 300 Gaussians, then 3 GiB of gzip'd zeros (3 MB on disk): the reader
    # inflates what 300 Gaussians need (and a little slack), sees more coming, and stops.
    import tracemalloc

    bombs = load_tool("hostile_corpus")
    g = _shape_gaussians("sphere", 300, np.random.default_rng(14))
    S.write_spz(tmp_path / "v3.spz", g["centers"], g["scales"], g["rotations"], g["opacity"], g["colors"])
    header = gzip.decompress((tmp_path / "v3.spz").read_bytes())[:16]
    bomb = tmp_path / "bomb.spz"
    bomb.write_bytes(bombs.gzip_of_zeros(header, 3 << 30))
    assert bomb.stat().st_size < 4 << 20
    tracemalloc.start()
    try:
        with pytest.raises(InputError, match=r"bomb\.spz: corrupted SPZ: its gzip stream inflates past"):
            pointcvx.load(bomb)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 64 << 20
    # a header declaring more Gaussians than its gzip stream could ever inflate to: refused at once
    big = header[:8] + struct.pack("<I", 10**8) + header[12:]
    (tmp_path / "count.spz").write_bytes(gzip.compress(big + bytes(1000)))
    with pytest.raises(InputError, match="declares 100000000 Gaussians"):
        pointcvx.load(tmp_path / "count.spz")


def test_ply_splat_declaring_far_more_rows_than_it_holds(tmp_path):
    g = _shape_gaussians("sphere", 50, np.random.default_rng(15))
    path = tmp_path / "ok.ply"
    _write(path, g)
    data = path.read_bytes().replace(b"element vertex 50", b"element vertex 1000000000000", 1)
    (tmp_path / "many.ply").write_bytes(data)
    with pytest.raises(InputError, match="declares 1000000000000 vertices, needing at least"):
        S.read_inria_ply(tmp_path / "many.ply")


# -------------------------------------------------------------------- formats, round trips
def test_dot_splat_round_trip(tmp_path):
    rng = np.random.default_rng(5)
    g = _shape_gaussians("sphere", 2000, rng)
    path = tmp_path / "ball.splat"
    S.write_dot_splat(path, g["centers"], g["scales"], g["rotations"], g["opacity"], g["colors"])
    back = S.read_dot_splat(path)
    assert np.allclose(back["centers"], g["centers"], atol=1e-6)
    assert np.allclose(back["scales"], g["scales"], rtol=1e-6)
    assert np.abs(back["opacity"] - g["opacity"]).max() <= 0.5 / 255 + 1e-9
    assert np.abs(back["colors"] - g["colors"]).max() <= 0.5 / 255 + 1e-6
    assert np.abs((back["rotations"] * g["rotations"]).sum(axis=1)).min() > 0.99
    cloud = pointcvx.load(path, normalize=False)
    assert cloud.info["format_detail"].startswith("antimatter15")
    assert (np.einsum("ij,ij->i", cloud.normals, _truth_normals("sphere", cloud.points)) > 0).mean() > 0.99


@pytest.mark.parametrize("version", [2, 3])
def test_legacy_spz_round_trip(tmp_path, version):
    rng = np.random.default_rng(6)
    g = _shape_gaussians("sphere", 2000, rng)
    path = tmp_path / f"v{version}.spz"
    S.write_spz(path, g["centers"], g["scales"], g["rotations"], g["opacity"], g["colors"], version=version)
    back = S.read_spz(path)
    assert np.abs(back["centers"] - g["centers"]).max() <= 2.0**-13 + 1e-9  # half the 2^-12 step
    assert np.abs(np.log(back["scales"]) - np.log(g["scales"])).max() <= 1 / 32 + 1e-9
    assert np.abs(back["opacity"] - g["opacity"]).max() <= 0.5 / 255 + 1e-9
    assert np.abs(back["colors"] - g["colors"]).max() < 0.005
    assert np.abs((back["rotations"] * g["rotations"]).sum(axis=1)).min() > (0.99 if version == 3 else 0.98)
    assert pointcvx.load(path).info["format_detail"].startswith(f"Niantic SPZ v{version}")


def test_spz_v4_coordinate_extension_is_honoured(tmp_path):
    # biker.spz with a coordinate-system extension record declaring RDF (the PLY axes) inserted
    # before its stream table: the positions must then come out unflipped.
    raw = bytearray((SPLATS / "biker.spz").read_bytes())
    record = np.array([S.SPZ_COORDINATE_EXTENSION, 4, 6], dtype="<u4").tobytes()
    raw[14] |= 0x2  # flags: has extensions
    raw[16:20] = np.array([32 + len(record)], dtype="<u4").tobytes()  # tocByteOffset
    path = tmp_path / "rdf.spz"
    path.write_bytes(bytes(raw[:32]) + record + bytes(raw[32:]))
    declared = S.read_spz(path)
    truth = S.read_inria_ply(SPLATS / "biker.ply")
    assert np.allclose(declared["centers"], truth["centers"] * [1, -1, -1], atol=1e-6)


@pytest.mark.parametrize("axes", ["RUB", "LUF", "RFU", "LBD"])
def test_axis_conversion_keeps_covariances(axes):
    rng = np.random.default_rng(11)
    g = _shape_gaussians("sphere", 50, rng)
    g = {k: g[k] for k in ("centers", "scales", "rotations")}
    before = {k: v.copy() for k, v in g.items()}
    S.to_ply_axes(g, axes)
    m = S.axes_change(axes)
    assert np.allclose(g["centers"], before["centers"] @ m.T)

    def covariance(rotations, scales):
        r = S.quaternion_matrices(rotations)
        return np.einsum("nij,nj,nkj->nik", r, scales**2, r)

    want = m @ covariance(before["rotations"], before["scales"]) @ m.T
    assert np.allclose(covariance(g["rotations"], g["scales"]), want, atol=1e-12)


def test_samples_per_gaussian_is_seeded(tmp_path):
    rng = np.random.default_rng(8)
    g = _shape_gaussians("sphere", 1500, rng)
    path = tmp_path / "ball.ply"
    _write(path, g)
    a = pointcvx.load(path, samples_per_gaussian=4, seed=3, normalize=False)
    b = pointcvx.load(path, samples_per_gaussian=4, seed=3, normalize=False)
    c = pointcvx.load(path, samples_per_gaussian=4, seed=4, normalize=False)
    base = pointcvx.load(path, normalize=False)
    assert len(a) == 4 * len(base)
    for field in ("points", "normals", "colors", "weights"):
        assert np.array_equal(getattr(a, field), getattr(b, field)), field
    assert not np.array_equal(a.points, c.points)
    assert np.isclose(a.weights.sum(), base.weights.sum())
    radius = np.linalg.norm(a.points, axis=1)
    assert np.abs(radius - 1.0).max() < 0.1  # tangent-plane samples stay near the surface
    assert (np.einsum("ij,ij->i", a.normals, _truth_normals("sphere", a.points)) > 0).mean() > 0.99


# ------------------------------------------------------------------------ corrupted input
def _truncated(src, dst, fraction):
    data = src.read_bytes()
    dst.write_bytes(data[: int(len(data) * fraction)])
    return dst


def test_truncated_compressed_ply_raises(tmp_path):
    path = _truncated(SPLATS / "guitar.compressed.ply", tmp_path / "cut.compressed.ply", 0.6)
    with pytest.raises(InputError, match="cut.compressed.ply"):
        pointcvx.load(path)


def test_truncated_or_corrupted_spz_raises(tmp_path):
    path = _truncated(SPLATS / "biker.spz", tmp_path / "cut.spz", 0.7)
    with pytest.raises(InputError, match="truncated SPZ"):
        pointcvx.load(path)
    data = bytearray((SPLATS / "biker.spz").read_bytes())
    data[112:116] = b"XXXX"  # the first zstd frame's magic (header 32 + table 5 x 16 bytes)
    (tmp_path / "bad.spz").write_bytes(bytes(data))
    with pytest.raises(InputError, match="bad.spz"):
        pointcvx.load(tmp_path / "bad.spz")
    rng = np.random.default_rng(9)
    g = _shape_gaussians("sphere", 300, rng)
    S.write_spz(tmp_path / "v3.spz", g["centers"], g["scales"], g["rotations"], g["opacity"], g["colors"])
    raw = gzip.decompress((tmp_path / "v3.spz").read_bytes())
    (tmp_path / "short.spz").write_bytes(gzip.compress(raw[:-100]))  # complete gzip, short payload
    with pytest.raises(InputError, match="truncated SPZ"):
        pointcvx.load(tmp_path / "short.spz")
    _truncated(tmp_path / "v3.spz", tmp_path / "cutgz.spz", 0.5)  # cut gzip stream
    with pytest.raises(InputError, match="cutgz.spz"):
        S.read_spz(tmp_path / "cutgz.spz")


def test_truncated_dot_splat_raises(tmp_path):
    rng = np.random.default_rng(10)
    g = _shape_gaussians("sphere", 100, rng)
    S.write_dot_splat(tmp_path / "ok.splat", g["centers"], g["scales"], g["rotations"], g["opacity"],
                      g["colors"])
    path = tmp_path / "cut.splat"
    path.write_bytes((tmp_path / "ok.splat").read_bytes()[:-7])
    with pytest.raises(InputError, match="truncated .splat"):
        pointcvx.load(path)
    with pytest.raises(InputError, match="truncated .splat"):
        S.read_dot_splat(path)


def _signs_node_by_node(n, edges, relative, weights):
    """propagate_signs's signs as it used to find them: its node pairs deduplicated one by one,
    then each piece's BFS tree of the same graph walked node by node, sign[child] = sign[parent]
    * r in BFS order."""
    from scipy.sparse import csgraph

    from pointcvx.io.orient import sign_tree

    best = {}  # each node pair's most trusted relation: least weight, then first given
    for e, (a, b) in enumerate(edges.tolist()):
        if a != b:
            pair = (min(a, b), max(a, b))
            key = (1.0 if weights is None else weights[e] + 1e-9, e)
            best[pair] = min(best.get(pair, key), key)
    pairs = sorted(best)
    lo, hi = np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])
    w = np.array([best[p][0] for p in pairs])
    rel = np.where(relative[[best[p][1] for p in pairs]] < 0, -1.0, 1.0)
    tree, relm, labels = sign_tree(n, lo, hi, w, rel, spanning=weights is not None)
    sign = np.ones(n)
    for root in np.unique(labels, return_index=True)[1]:
        order, pred = csgraph.breadth_first_order(tree, int(root), directed=False)
        for child in order[1:]:
            r = np.sign(relm[child, pred[child]]) or 1.0
            sign[child] = sign[pred[child]] * r
    return sign, labels


@pytest.mark.parametrize("weighted", [True, False])
def test_sign_propagation_equals_the_walk_node_by_node(weighted):
    """propagate_signs gathers each node's sign along its tree path by pointer jumping and sorts
    the edges by one pair key: the same signs and pieces as the node-by-node walk, on a graph of
    several pieces (isolated nodes, repeated and self edges, tied weights included)."""
    from pointcvx.io.orient import propagate_signs

    rng = np.random.default_rng(5)
    n = 3000
    piece = rng.integers(0, 6, n)  # six pieces; edges only inside a piece
    piece[:5] = 6 + np.arange(5)  # five isolated nodes
    edges = []
    for p in range(6):
        nodes = np.flatnonzero(piece == p)
        edges.append(np.stack([np.repeat(nodes, 6), rng.choice(nodes, 6 * len(nodes))], axis=1))
    edges = np.concatenate(edges)
    edges = np.concatenate([edges, edges[:200, ::-1], np.stack([np.arange(5, 20)] * 2, axis=1)])
    relative = np.sign(rng.normal(size=len(edges)))
    weights = np.round(rng.random(len(edges)), 2) if weighted else None  # many ties
    sign, labels = propagate_signs(n, edges, relative, weights=weights)
    ref_sign, ref_labels = _signs_node_by_node(n, edges, relative, weights)
    np.testing.assert_array_equal(labels, ref_labels)
    np.testing.assert_array_equal(sign, ref_sign)
    assert len(np.unique(labels)) >= 11 and (sign < 0).any() and (sign > 0).any()
