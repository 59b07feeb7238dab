"""MuJoCo step time and behaviour of a decomposition against simpler collision geometry.

    python tools/sim_check.py [SHAPE] [--points 4000] [--balls 9] [--seconds 2] [--repeat 5]
                              [--coacd] [--json OUT.json]

SHAPE (default ``../shared/data/dev/objects/mug.obj``, in metres) is decomposed once with the
bundled model (seed 0) and written with pointcvx's MJCF export. Each collision variant is then
simulated in two scenes, with MuJoCo's default 2 ms step:

- ``drop``: the object, free, falls tilted from 1.5 x its height onto a floor and settles;
- ``balls``: the object is fixed and a grid of 1 cm balls falls onto its top; a ball counts as
  inside when it ends below the object's top and within its bounding box (for a cup: in the cup).

Variants:

- ``pointcvx``: the decomposition's hulls, one collision geom each;
- ``pointcvx physx-gpu``: the same hulls capped at 64 vertices / 64 triangles;
- ``original mesh``: the input mesh as ONE mesh geom. MuJoCo collides with the convex hull of a
  mesh geom, so this is the cost and the behaviour of a single convex hull (a cup gets a lid),
  not of the real shape: the cheap baseline, not an equivalent one;
- ``coacd`` (with ``--coacd`` and the [baselines] extra): CoACD's hulls at its default threshold,
  the meaningful comparison for the cost of a decomposition of the same shape.

Printed: per variant and scene, the mean wall time of ``mj_step`` (best of ``--repeat`` runs,
single thread), mean contacts per step, and balls inside.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MUG = ROOT.parent / "shared" / "data" / "dev" / "objects" / "mug.obj"
BALL = 0.01


def write_mjcf(folder: Path, name: str, hulls) -> Path:
    """An MJCF (pointcvx's writers) with one collision geom per ((v, 3), (f, 3)) hull."""
    from pointcvx.export import mesh_obj_text, mjcf_text, write_files

    collision = [f"{name}_collision_{i}.obj" for i in range(len(hulls))]
    files = {folder / f: mesh_obj_text(v, fc) for f, (v, fc) in zip(collision, hulls, strict=True)}
    main = folder / f"{name}.xml"
    files[main] = mjcf_text(name, collision, collision, free_joint=True)
    write_files(files, overwrite=True)
    return main


def scene(xml: Path, name: str, kind: str, top: float, bounds: np.ndarray, balls: int):
    """A compiled model: the object in ``xml`` plus a floor, and for ``balls`` a grid of balls."""
    import mujoco

    spec = mujoco.MjSpec.from_file(str(xml))
    for mesh in spec.meshes:  # mass from the convex hull MuJoCo collides with (the raw mesh is open)
        mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_CONVEX
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[2.0, 2.0, 0.01])
    body = spec.body(name)
    if kind == "drop":
        tilt = 0.3
        body.pos = [0.0, 0.0, 1.5 * top]
        body.quat = [np.cos(tilt / 2), np.sin(tilt / 2), 0.0, 0.0]
        return spec.compile()
    spec.delete(spec.joint(f"{name}_free"))  # fixed
    side = int(np.ceil(np.sqrt(balls)))
    centre = bounds.mean(axis=0)
    span = 0.25 * (bounds[1] - bounds[0]).min()
    for k in range(balls):
        i, j = divmod(k, side)
        offset = (np.array([i, j]) - (side - 1) / 2) * (span / max(side - 1, 1))
        ball = spec.worldbody.add_body(name=f"ball_{k}", pos=[centre[0] + offset[0],
                                                            centre[1] + offset[1],
                                                            top + 0.05 + 0.025 * k])
        ball.add_freejoint()
        ball.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[BALL, 0, 0], density=1000.0)
    return spec.compile()


def run(model, seconds: float) -> tuple[float, float, object]:
    """(seconds per step, mean contacts per step, final data)."""
    import mujoco

    data = mujoco.MjData(model)
    steps = int(seconds / model.opt.timestep)
    contacts = 0
    start = time.perf_counter()
    for _ in range(steps):
        mujoco.mj_step(model, data)
        contacts += data.ncon
    return (time.perf_counter() - start) / steps, contacts / steps, data


def balls_inside(model, data, top: float, bounds: np.ndarray, balls: int) -> int:
    inside = 0
    for k in range(balls):
        p = data.body(f"ball_{k}").xpos
        inside += bool(p[2] < top - BALL and np.all(p[:2] > bounds[0, :2]) and np.all(p[:2] < bounds[1, :2]))
    return inside


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("shape", nargs="?", default=str(MUG))
    ap.add_argument("--points", type=int, default=4000)
    ap.add_argument("--balls", type=int, default=9)
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--coacd", action="store_true", help="add CoACD's hulls ([baselines] extra)")
    ap.add_argument("--json", metavar="OUT", help="also write the numbers as JSON")
    args = ap.parse_args(argv)

    import mujoco
    import trimesh

    import pointcvx

    mesh = trimesh.load(args.shape, force="mesh")
    bounds = np.asarray(mesh.bounds)
    top = float(bounds[1, 2])
    t = time.perf_counter()
    result = pointcvx.decompose(args.shape, features="model", n_points=args.points, seed=0)
    decompose_s = time.perf_counter() - t
    limited = result.limit_hulls("physx-gpu")
    variants = {
        f"pointcvx ({len(result)} hulls)": [(h.vertices, h.faces) for h in result.hulls],
        f"pointcvx physx-gpu ({len(limited)} hulls)": [(h.vertices, h.faces) for h in limited.hulls],
        "original mesh (1 geom)": [(np.asarray(mesh.vertices), np.asarray(mesh.faces))],
    }
    if args.coacd:
        import coacd

        coacd.set_log_level("error")
        parts = coacd.run_coacd(coacd.Mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)), seed=0)
        variants[f"coacd ({len(parts)} hulls)"] = [(np.asarray(v), np.asarray(f)) for v, f in parts]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        models = {}
        for i, (label, hulls) in enumerate(variants.items()):
            xml = write_mjcf(Path(tmp) / f"v{i}", f"v{i}", hulls)
            for kind in ("drop", "balls"):
                models[label, kind] = (f"v{i}", scene(xml, f"v{i}", kind, top, bounds, args.balls))
        best: dict[tuple[str, str], list] = {}
        for _ in range(args.repeat):  # interleaved, so load changes hit every variant alike
            for key, (_, model) in models.items():
                step, contacts, data = run(model, args.seconds)
                if key not in best or step < best[key][0]:
                    best[key] = [step, contacts, data]
        for (label, kind), (step, contacts, data) in best.items():
            model = models[label, kind][1]
            row = {"variant": label, "scene": kind, "step_us": round(step * 1e6, 2),
                   "contacts": round(contacts, 1)}
            if kind == "balls":
                row["balls_inside"] = f"{balls_inside(model, data, top, bounds, args.balls)}/{args.balls}"
            else:
                row["at_rest"] = bool(np.abs(data.qvel).max() < 1e-3)
            rows.append(row)
    print(f"{Path(args.shape).name}: decomposed in {decompose_s:.1f} s; MuJoCo {mujoco.__version__}, "
          f"timestep {models[next(iter(models))][1].opt.timestep * 1e3:g} ms, best of {args.repeat}")
    print(f"{'variant':<34} {'scene':<6} {'us/step':>8} {'contacts':>9}  result")
    for r in rows:
        extra = r.get("balls_inside", "at rest" if r.get("at_rest") else "moving")
        print(f"{r['variant']:<34} {r['scene']:<6} {r['step_us']:>8.1f} {r['contacts']:>9.1f}  {extra}")
    if args.json:
        Path(args.json).write_text(json.dumps({"shape": args.shape, "rows": rows}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
