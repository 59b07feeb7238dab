"""Training data: watertight shapes, surface samples, convexity triplets and SDF supervision.

Sources are the real-shape corpus ``../shared/data/train/random_urdfs`` (500 OBJ files, each one
object made of several convex parts, merged on reading) and procedural solids
(:func:`pointcvx.training.shapes.random_solid`). For each shape :func:`prepare_shape`

1. normalises it to 0.9 of [-1, 1]^3 and makes it watertight (:func:`pointcvx.solid.
   watertight_mesh`, mesh2sdf-style marching cubes; the release uses 256^3, we default to 128^3),
   normalising again (marching cubes moves the bounds by a fraction of a voxel);
2. samples ``n_points`` oriented surface points (area-weighted, face normals);
3. samples triplets (:func:`pointcvx.features.pairs.sample_triplets`) on a pool of them;
4. samples SDF supervision: near-surface points (surface samples plus Gaussian offsets) and
   uniform points in [-1, 1]^3, signed distance negative inside, clipped at ``sdf_clip``.

:func:`prepare_dataset` writes one compressed ``.npz`` per shape (resumable, with a
``manifest.json``) and :class:`TripletDataset` reads them back with on-the-fly augmentation.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..features.pairs import sample_triplets
from ..io.files import atomic_path
from ..io.mesh import read_mesh, sample_surface
from ..solid import Solid, watertight_mesh
from .augment import AugmentConfig, augment_sample
from .shapes import normalize_mesh, random_solid

log = logging.getLogger(__name__)

#: The real-shape training corpus (beside the project checkout).
DEFAULT_URDF_ROOT = Path(__file__).resolve().parents[3] / "shared" / "data" / "train" / "random_urdfs"
#: Keys of a prepared sample, in file order.
KEYS = ("points", "normals", "pool", "pool_normals", "anchor", "positive", "negative", "sdf_points", "sdf")
MANIFEST = "manifest.json"


def training_meshes(root: str | os.PathLike | None = None) -> list[Path]:
    """Sorted OBJ paths of the real-shape corpus: one file per object (its convex parts are
    ``o`` groups of that file, merged by :func:`load_training_mesh`)."""
    root = Path(root) if root is not None else DEFAULT_URDF_ROOT
    if not root.is_dir():
        raise FileNotFoundError(f"training mesh folder not found: {root}")
    return sorted(p for p in root.iterdir() if p.suffix.lower() == ".obj" and p.is_file())


def load_training_mesh(path: str | os.PathLike):
    """``trimesh.Trimesh`` of one corpus OBJ, all parts concatenated (raises InputError)."""
    return read_mesh(path, "obj")


def sdf_samples(solid: Solid, surface: np.ndarray, rng: np.random.Generator, n_near: int, n_uniform: int,
                sigmas: tuple[float, ...] = (0.005, 0.02), clip: float = 0.05,
                bound: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """SDF supervision: (s, 3) float32 points and (s,) float32 signed distances (negative inside,
    clipped to +-``clip``). ``n_near`` points are random ``surface`` (m, 3) samples offset by
    Gaussians of the std ``sigmas`` (equal shares), ``n_uniform`` are uniform in
    [-bound, bound]^3. Sign by :meth:`Solid.contains`, magnitude by :meth:`Solid.distance`."""
    parts = []
    if n_near > 0:
        base = surface[rng.integers(0, len(surface), size=n_near)]
        sigma = np.asarray(sigmas, dtype=np.float64)[rng.integers(0, len(sigmas), size=n_near)]
        parts.append(base + rng.normal(size=(n_near, 3)) * sigma[:, None])
    if n_uniform > 0:
        parts.append(rng.uniform(-bound, bound, size=(n_uniform, 3)))
    pts = np.concatenate(parts, axis=0) if parts else np.zeros((0, 3))
    if len(pts) == 0:
        return pts.astype(np.float32), np.zeros(0, dtype=np.float32)
    dist = np.minimum(solid.distance(pts), clip)
    sdf = np.where(solid.contains(pts), -dist, dist)
    return pts.astype(np.float32), sdf.astype(np.float32)


def closed_surface(mesh: Any, resolution: int = 128, watertight: bool = True):
    """The closed, outward-wound ``trimesh.Trimesh`` that :func:`prepare_shape` samples: ``mesh``
    normalised to 0.9 of [-1, 1]^3, made watertight at ``resolution`` (unless ``watertight`` is
    False: the mesh is closed already) and normalised again. Deterministic."""
    import trimesh

    mesh = normalize_mesh(trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=False))
    if watertight:
        mesh = normalize_mesh(watertight_mesh(mesh, resolution))
    return mesh


def prepare_shape(
    mesh: Any,
    *,
    seed: int = 0,
    n_points: int = 20000,
    resolution: int = 128,
    pool_size: int | None = None,
    n_anchors: int = 512,
    n_candidates: int = 512,
    n_hard: int = 128,
    n_uniform: int = 128,
    power: float = 1.0,
    n_sdf_near: int = 8192,
    n_sdf_uniform: int = 4096,
    sdf_clip: float = 0.05,
    watertight: bool = True,
) -> dict[str, np.ndarray]:
    """One training sample from any triangle mesh (module docstring).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Any triangles (open, multi-part, any winding) when ``watertight``; with
        ``watertight=False`` it must already be closed and outward-wound (procedural solids).
    seed : int
        Seeds every random draw (surface samples, triplets, SDF points).
    n_points : int
        Input surface samples (release: 100k).
    resolution : int
        Watertight grid resolution (release: 256).
    pool_size : int, optional
        Triplet pool: a random subset of the input samples (default: all of them).
    n_anchors, n_candidates, n_hard, n_uniform, power
        Triplet settings (release: 1024, 1024, 256, 256, 1), smaller defaults for CPU.
    n_sdf_near, n_sdf_uniform, sdf_clip
        SDF supervision counts and clipping (release: 0.05).

    Returns
    -------
    dict
        ``points`` (n, 3) float32, ``normals`` (n, 3) float32 unit, ``pool`` (m, 3) float32,
        ``pool_normals`` (m, 3) float32, ``anchor`` (a,) int64 into ``pool``, ``positive``
        (a, 3) float32, ``negative`` (a, k) int64 into ``pool``, ``sdf_points`` (s, 3) float32,
        ``sdf`` (s,) float32. ``a`` may be below ``n_anchors`` (anchors without a positive or a
        negative are dropped) and is 0 for a convex shape.
    """
    ss = np.random.SeedSequence(int(seed))
    s_surface, s_pool, s_trip, s_sdf = (int(s.generate_state(1)[0]) for s in ss.spawn(4))
    mesh = closed_surface(mesh, resolution, watertight)
    solid = Solid.from_trimesh(mesh)
    if not solid.volume > 0:
        raise ValueError(f"the solid has no positive volume ({solid.volume:.3g})")
    points, face = sample_surface(mesh, n_points, seed=s_surface)
    normals = np.asarray(mesh.face_normals, dtype=np.float64)[face]
    if pool_size is not None and pool_size < n_points:
        keep = np.sort(np.random.default_rng(s_pool).choice(n_points, pool_size, replace=False))
        pool, pool_normals = points[keep], normals[keep]
    else:
        pool, pool_normals = points, normals
    trip = sample_triplets(solid, pool, pool_normals, n_anchors=n_anchors, n_candidates=n_candidates,
                           n_hard=n_hard, n_uniform=n_uniform, power=power, seed=s_trip)
    sdf_points, sdf = sdf_samples(solid, points, np.random.default_rng(s_sdf), n_sdf_near, n_sdf_uniform,
                                  clip=sdf_clip)
    return {
        "points": points.astype(np.float32),
        "normals": normals.astype(np.float32),
        "pool": pool.astype(np.float32),
        "pool_normals": pool_normals.astype(np.float32),
        "anchor": trip.anchor.astype(np.int64),
        "positive": np.asarray(trip.positive, dtype=np.float32).reshape(-1, 3),
        "negative": trip.negative.astype(np.int64).reshape(len(trip.anchor), n_hard + n_uniform),
        "sdf_points": sdf_points,
        "sdf": sdf,
    }


# ---------------------------------------------------------------------------------- datasets
def compact_arrays(sample: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """About a third of the bytes of ``sample``: float arrays as float16 (about 1e-3 relative,
    under the input noise the augmentation adds), index arrays in the smallest unsigned type
    that holds them, and ``pool``/``pool_normals`` dropped when they equal the input points
    (:func:`load_sample` restores them). For moving training sets to remote machines."""
    out = {}
    for key, value in sample.items():
        a = np.asarray(value)
        if np.issubdtype(a.dtype, np.floating):
            a = a.astype(np.float16)
        elif np.issubdtype(a.dtype, np.integer) and a.size and a.min() >= 0:
            a = a.astype(np.uint16 if a.max() < 1 << 16 else np.uint32)
        out[key] = a
    for key, same in (("pool", "points"), ("pool_normals", "normals")):
        if key in sample and same in sample and np.array_equal(sample[key], sample[same]):
            del out[key]
    return out


def save_sample(path: str | os.PathLike, sample: dict[str, np.ndarray], compact: bool = False) -> None:
    """Write ``sample`` as a compressed ``.npz`` atomically (temp file in the same folder, then
    ``os.replace``), so an interrupted run never leaves a half-written file under ``path``.
    ``compact`` stores :func:`compact_arrays` of it."""
    path = Path(path)
    if compact:
        sample = compact_arrays(sample)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, **sample)


def load_sample(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The arrays of one ``.npz`` sample: floats as float32, indices as int64, and ``pool`` /
    ``pool_normals`` restored from the input points where a compact file left them out."""
    with np.load(path) as data:
        out = {}
        for key in data.files:
            a = data[key]
            if np.issubdtype(a.dtype, np.floating):
                a = a.astype(np.float32, copy=False)
            elif np.issubdtype(a.dtype, np.integer):
                a = a.astype(np.int64, copy=False)
            out[key] = a
    for key, same in (("pool", "points"), ("pool_normals", "normals")):
        if key not in out and same in out:
            out[key] = out[same].copy()
    return out


def _write_json(path: Path, obj: Any) -> None:
    with atomic_path(path) as tmp, open(tmp, "w") as f:
        json.dump(obj, f, indent=1, sort_keys=True)


def item_seed(seed: int, index: int, source: str) -> int:
    """A 32-bit seed for item ``index`` of ``source`` ('procedural' or 'urdf') under ``seed``."""
    tag = 0 if source == "procedural" else 1
    return int(np.random.SeedSequence([int(seed), tag, int(index)]).generate_state(1)[0])


def dataset_items(n_procedural: int, use_urdfs: bool = True, seed: int = 0,
                  urdf_root: str | os.PathLike | None = None,
                  max_urdfs: int | None = None) -> list[dict[str, Any]]:
    """The work list: dicts with ``name``, ``source`` ('procedural' or the OBJ path), ``seed``."""
    items = [{"name": f"proc_{i:05d}", "source": "procedural", "seed": item_seed(seed, i, "procedural")}
             for i in range(int(n_procedural))]
    if use_urdfs:
        paths = training_meshes(urdf_root)
        if max_urdfs is not None:
            paths = paths[: int(max_urdfs)]
        items += [{"name": f"urdf_{p.stem}", "source": str(p), "seed": item_seed(seed, i, "urdf")}
                  for i, p in enumerate(paths)]
    return items


def _prepare_item(item: dict[str, Any], out_dir: str, shape_kwargs: dict[str, Any],
                  compact: bool = False) -> dict[str, Any]:
    """Prepare and write one item; returns its manifest entry (never raises for bad inputs)."""
    start = time.perf_counter()
    entry = {"name": item["name"], "source": item["source"], "seed": item["seed"]}
    try:
        if item["source"] == "procedural":
            mesh = random_solid(np.random.default_rng(item["seed"]))
            kwargs = {"watertight": False, **shape_kwargs}
        else:
            mesh = load_training_mesh(item["source"])
            kwargs = dict(shape_kwargs)
        sample = prepare_shape(mesh, seed=item["seed"], **kwargs)
        save_sample(Path(out_dir) / f"{item['name']}.npz", sample, compact=compact)
        entry.update(ok=True, error=None, anchors=int(len(sample["anchor"])))
    except (ValueError, RuntimeError, OSError, IndexError, MemoryError) as exc:  # InputError is a ValueError
        log.warning("prepare %s failed: %s", item["name"], exc)
        entry.update(ok=False, error=f"{type(exc).__name__}: {exc}")
    entry["seconds"] = round(time.perf_counter() - start, 3)
    return entry


def prepare_dataset(
    out_dir: str | os.PathLike,
    n_procedural: int,
    use_urdfs: bool = True,
    seed: int = 0,
    jobs: int = 1,
    progress: Callable[[int, int, dict[str, Any]], None] | None = None,
    urdf_root: str | os.PathLike | None = None,
    max_urdfs: int | None = None,
    compact: bool = False,
    **shape_kwargs: Any,
) -> dict[str, dict[str, Any]]:
    """Prepare ``n_procedural`` procedural shapes and (with ``use_urdfs``) the corpus meshes into
    ``out_dir``, one ``<name>.npz`` each, plus ``manifest.json`` mapping name -> entry (``name``,
    ``source``, ``seed``, ``ok``, ``error``, ``seconds``, ``anchors``).

    Resumable: items whose ``.npz`` exists are skipped (failed ones are tried again). A failing
    input is recorded with ``ok: false`` and its error; the others go on. ``jobs`` > 1 uses a
    process pool. ``progress(done, total, entry)`` is called after each item. ``compact`` writes
    :func:`compact_arrays` files (about a third of the bytes). Extra keyword arguments go to
    :func:`prepare_shape`. Returns the manifest.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    manifest_path = out / MANIFEST
    manifest: dict[str, dict[str, Any]] = {}
    if manifest_path.exists():
        try:
            manifest = json.loads(manifest_path.read_text())
        except (json.JSONDecodeError, OSError) as exc:
            log.warning("ignoring unreadable %s: %s", manifest_path, exc)
    items = dataset_items(n_procedural, use_urdfs, seed, urdf_root, max_urdfs)
    todo = []
    for item in items:
        if (out / f"{item['name']}.npz").exists():
            manifest.setdefault(item["name"], {**item, "ok": True, "error": None})
        else:
            todo.append(item)
    log.info("prepare_dataset: %d items, %d to do, %d already written", len(items), len(todo),
             len(items) - len(todo))
    total = len(todo)

    def record(i: int, entry: dict[str, Any]) -> None:
        manifest[entry["name"]] = entry
        _write_json(manifest_path, manifest)
        if progress is not None:
            progress(i + 1, total, entry)

    if jobs <= 1 or total <= 1:
        for i, item in enumerate(todo):
            record(i, _prepare_item(item, str(out), shape_kwargs, compact))
    else:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(max_workers=jobs, mp_context=mp.get_context("spawn")) as pool:
            futures = [pool.submit(_prepare_item, item, str(out), shape_kwargs, compact) for item in todo]
            for i, fut in enumerate(as_completed(futures)):
                record(i, fut.result())
    _write_json(manifest_path, manifest)
    return manifest


class TripletDataset:
    """The prepared ``.npz`` samples of a folder, augmented on the fly.

    ``dataset[i]`` is a dict of numpy arrays (keys as :func:`prepare_shape`); with ``augment``
    the input cloud is corrupted and everything rotated (:func:`augment_sample`) with a
    generator seeded by ``(seed, epoch, i)``: deterministic, different each epoch
    (:meth:`set_epoch`).
    """

    def __init__(self, folder: str | os.PathLike, augment: bool = True, seed: int = 0,
                 config: AugmentConfig | None = None, min_anchors: int = 1):
        self.folder = Path(folder)
        self.augment = augment
        self.seed = int(seed)
        self.config = config or AugmentConfig()
        self.epoch = 0
        files = sorted(self.folder.glob("*.npz"))
        if min_anchors > 0:
            manifest_path = self.folder / MANIFEST
            if manifest_path.exists():
                manifest = json.loads(manifest_path.read_text())
                files = [f for f in files
                         if manifest.get(f.stem, {}).get("anchors", min_anchors) >= min_anchors]
        self.files = files

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return len(self.files)

    def __getitem__(self, i: int) -> dict[str, np.ndarray]:
        return self.item(i, self.epoch)

    def item(self, i: int, epoch: int) -> dict[str, np.ndarray]:
        """Item ``i`` as augmented in pass ``epoch`` over the data: the same arrays for the same
        ``(seed, epoch, i)``, in any process, a different augmentation in every pass."""
        if not -len(self) <= i < len(self):
            raise IndexError(i)
        sample = load_sample(self.files[i])
        if self.augment:
            rng = np.random.default_rng([self.seed, int(epoch), int(i) % len(self)])
            sample = augment_sample(sample, rng, self.config)
        return sample
