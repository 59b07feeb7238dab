"""Generate the bundled sample inputs in ``io/``, one per modality, from code (no outside data).

    python tools/make_samples.py [OUTDIR]

Every sample is a view of the same procedural solid, a mug (a hollow cylinder with a bottom and a
torus handle), so they can be compared with each other:

- ``mug.obj``: a watertight mesh from marching cubes of the mug's signed distance.
- ``mug_splat.ply``: a synthetic 3D Gaussian splat in the INRIA layout (SH degree 1), flat
  Gaussians on the surface plus low-opacity noise and a small floater cluster to be filtered.
- ``mug_scan.ply`` and ``mug_scan.xyz``: a partial, noisy scan without normals from two
  viewpoints, with a few outliers.
- ``bracket.step``: a CAD part (an L-bracket with a hole and a boss) built with gmsh/OpenCASCADE.

Same script, same files (everything is seeded).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

SEED = 20261122


def mug_sdf(p: np.ndarray) -> np.ndarray:
    """(n,) float signed distance (negative inside) of the mug at (n, 3) points ``p``."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    r = np.hypot(x, y)

    def capped_cylinder(radius, z0, z1):
        dr, dz = r - radius, np.maximum(z0 - z, z - z1)
        outside = np.hypot(np.maximum(dr, 0), np.maximum(dz, 0))
        return outside + np.minimum(np.maximum(dr, dz), 0)

    body = np.maximum(capped_cylinder(0.40, -0.5, 0.5), -capped_cylinder(0.32, -0.4, 0.6))
    # Handle: a torus in the xz-plane, centred beside the body.
    q = np.stack([np.hypot(x - 0.45, z) - 0.22, y], axis=1)
    handle = np.linalg.norm(q, axis=1) - 0.06
    return np.minimum(body, handle)


def mug_mesh(resolution: int = 72):
    """The mug as a watertight, outward-wound ``trimesh.Trimesh`` (marching cubes)."""
    import trimesh
    from skimage.measure import marching_cubes

    lo, hi = -0.8, 0.8
    axis = np.linspace(lo, hi, resolution)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
    sdf = mug_sdf(grid).reshape(resolution, resolution, resolution)
    step = (hi - lo) / (resolution - 1)
    verts, faces, _, _ = marching_cubes(sdf, level=0.0, spacing=(step, step, step))
    mesh = trimesh.Trimesh(verts + lo, faces, process=True)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def quaternion_from_normal(normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n, 4) w,x,y,z quaternions rotating the local z axis onto (n, 3) ``normals``, with a random
    twist about it."""
    from scipy.spatial.transform import Rotation

    z = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    helper = np.where(np.abs(z[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    twist = rng.uniform(0, 2 * np.pi, len(z))[:, None]
    x, y = np.cos(twist) * x + np.sin(twist) * y, -np.sin(twist) * x + np.cos(twist) * y
    xyzw = Rotation.from_matrix(np.stack([x, y, z], axis=2)).as_quat()
    q = xyzw[:, [3, 0, 1, 2]]
    q[rng.random(len(q)) < 0.5] *= -1  # q and -q are the same rotation; files contain both
    return q


def make_splat(mesh, path: Path, rng: np.random.Generator, n: int = 14000,
               depth_noise: float = 0.0, floater_at=(0.75, 0.75, 0.75),
               subsurface: float = 0.0) -> None:
    """Write a synthetic INRIA splat of ``mesh``: ``n`` flat Gaussians on its surface (centres
    moved along their normal by N(0, ``depth_noise``), as the centres of a trained splat
    scatter about the surface), faint Gaussians everywhere and a small floater cluster at
    ``floater_at`` (which must lie off the shape). ``subsurface`` adds that fraction of ``n``
    opaque, randomly turned Gaussians 0.03-0.08 under the surface where the solid is that
    thick, as trained splats keep a layer of Gaussians under their surface."""
    from pointcvx.io.splat import write_inria_ply

    points, face = mesh.sample(n, return_index=True, seed=int(rng.integers(1 << 31)))
    normals = mesh.face_normals[face]
    if depth_noise > 0:
        points = points + normals * rng.normal(0.0, depth_noise, (n, 1))
    size = rng.uniform(0.008, 0.02, n)
    scales = np.stack([size, size * rng.uniform(0.6, 1.0, n), size * 0.08], axis=1)
    rotations = quaternion_from_normal(normals, rng)
    opacity = rng.uniform(0.6, 0.99, n)
    colors = np.clip(0.5 + 0.4 * points[:, [2, 0, 1]] + rng.normal(0, 0.03, (n, 3)), 0, 1)
    if subsurface > 0:
        from pointcvx.solid import Solid

        m = int(round(subsurface * n))
        base, bface = mesh.sample(4 * m, return_index=True, seed=int(rng.integers(1 << 31)))
        depth = rng.uniform(0.03, 0.08, len(base))
        under = base - mesh.face_normals[bface] * depth[:, None]
        solid = Solid.from_trimesh(mesh)
        ok = np.flatnonzero(solid.contains(under) & (solid.distance(under) > 0.9 * depth))[:m]
        under = under[ok]
        k = len(under)
        turn = rng.normal(size=(k, 3))
        turn /= np.linalg.norm(turn, axis=1, keepdims=True)
        sub_size = rng.uniform(0.01, 0.025, k)
        points = np.concatenate([points, under])
        scales = np.concatenate([scales, np.stack([sub_size, sub_size * rng.uniform(0.5, 1.0, k),
                                                   sub_size * rng.uniform(0.2, 0.6, k)], axis=1)])
        rotations = np.concatenate([rotations, quaternion_from_normal(turn, rng)])
        opacity = np.concatenate([opacity, rng.uniform(0.6, 0.99, k)])
        colors = np.concatenate([colors, np.full((k, 3), 0.4)])
    # Noise to filter: faint Gaussians everywhere, and a small dense floater far from the mug.
    n_faint, n_float = 600, 90
    faint = rng.uniform(-0.7, 0.7, (n_faint, 3))
    floater = np.asarray(floater_at, dtype=np.float64) + rng.normal(0, 0.01, (n_float, 3))
    extra = np.concatenate([faint, floater])
    centers = np.concatenate([points, extra])
    scales = np.concatenate([scales, np.full((len(extra), 3), 0.01)])
    rotations = np.concatenate([rotations, np.tile([[1.0, 0, 0, 0]], (len(extra), 1))])
    opacity = np.concatenate([opacity, rng.uniform(0.005, 0.05, n_faint), np.full(n_float, 0.8)])
    colors = np.concatenate([colors, np.full((len(extra), 3), 0.5)])
    order = rng.permutation(len(centers))
    write_inria_ply(path, centers[order], scales[order], rotations[order], opacity[order],
                    colors[order], sh_degree=1, rng=rng)


def make_scan(mesh, rng: np.random.Generator) -> np.ndarray:
    """(m, 3) float: a partial scan of ``mesh`` from two viewpoints, noisy, with outliers."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                        o3d.core.Tensor(mesh.faces.astype(np.uint32)))
    views = []
    for eye in ([2.5, -1.5, 1.2], [-1.0, -2.5, 1.8]):
        rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(
            fov_deg=35.0, center=[0.0, 0.0, 0.0], eye=eye, up=[0.0, 0.0, 1.0],
            width_px=120, height_px=120)
        hit = scene.cast_rays(rays)
        t = hit["t_hit"].numpy().ravel()
        r = rays.numpy().reshape(-1, 6)
        ok = np.isfinite(t)
        views.append(r[ok, :3] + r[ok, 3:] * t[ok, None])
    pts = np.concatenate(views)
    pts += rng.normal(0, 0.004, pts.shape)
    outliers = rng.uniform(-0.8, 0.8, (len(pts) // 150, 3))
    return np.concatenate([pts, outliers])


def main(outdir: str = "io") -> None:
    from pointcvx.io.cad import write_step_sample
    from pointcvx.io.ply import write_cloud_ply

    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(SEED)
    mesh = mug_mesh()
    mesh.export(out / "mug.obj", digits=5)
    make_splat(mesh, out / "mug_splat.ply", rng)
    scan = make_scan(mesh, rng)
    write_cloud_ply(out / "mug_scan.ply", scan)
    np.savetxt(out / "mug_scan.xyz", scan[::3], fmt="%.5f")
    write_step_sample(out / "bracket.step")
    for f in sorted(out.iterdir()):
        if f.suffix != ".md":
            print(f"{f}: {f.stat().st_size / 1e6:.2f} MB")


if __name__ == "__main__":
    main(*sys.argv[1:])
