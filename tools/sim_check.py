"""MuJoCo (or Newton) step time and behaviour of a decomposition against simpler collision geometry.

    python tools/sim_check.py [SHAPE] [--engine mujoco|newton] [--points 4000] [--balls 9]
                              [--seconds 2] [--repeat 5] [--coacd] [--json OUT.json] [--worlds 1]

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

``--engine newton`` (``pip install newton``: Newton and Warp, run on Warp's CPU device) builds the
same scenes in Newton with XPBD (10 iterations) and Newton's default collision pipeline, 2 ms
steps, the body's mass properties taken from the decomposition for every variant (the input mesh
may be open), the drop tilted 0.1 rad instead of 0.3 (at 0.3 a mug tips over onto its side with
some variants and not others, and the timings would compare different scenes), and variants:

- ``pointcvx``: one convex-mesh shape per hull (``add_shape_convex_hull``);
- ``pointcvx newton``: the same hulls capped at 64 vertices (``limit_hulls("newton")``);
- ``original mesh``: the input as ONE triangle-mesh shape (``add_shape_mesh``): Newton collides
  with the concave mesh itself, so this is the real-shape baseline of the paper's comparison;
- ``single convex hull``: the decomposition recut to one hull (what MuJoCo makes of a mesh);
- ``coacd`` as above.

With ``--worlds N`` every scene is simulated N times at once, one world per copy (as Newton is
used for reinforcement learning); contacts and results are then for all worlds and the first one.

Printed per variant and scene: the median over ``--repeat`` runs (after one warm-up run that
compiles Warp's kernels) of the CPU time per step (collision + solver) and of the collision
pipeline alone (the stepping thread's CPU time: Warp's CPU kernels run on it), the wall time per
step, mean contacts per step, balls inside, and for ``drop`` whether the body ends at rest and
upright; a reference row (one ball resting on the ground: Newton's fixed cost per step on the
CPU, spent in Python launching kernels one by one); then the ratios original mesh / pointcvx,
per step, in collision, and in collision above the reference's.
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


def ball_grid(bounds: np.ndarray, top: float, balls: int) -> np.ndarray:
    """(balls, 3) float: starting centres of the falling balls, a square grid over the middle
    quarter of the object's (2, 3) ``bounds``, each a little higher than the one before, above
    ``top``."""
    side = int(np.ceil(np.sqrt(balls)))
    centre = bounds.mean(axis=0)
    span = 0.25 * (bounds[1] - bounds[0]).min()
    out = np.empty((balls, 3))
    for k in range(balls):
        i, j = divmod(k, side)
        offset = (np.array([i, j]) - (side - 1) / 2) * (span / max(side - 1, 1))
        out[k] = [centre[0] + offset[0], centre[1] + offset[1], top + 0.05 + 0.025 * k]
    return out


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
    for k, at in enumerate(ball_grid(bounds, top, balls)):
        ball = spec.worldbody.add_body(name=f"ball_{k}", pos=at.tolist())
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


def shape_and_decompositions(args):
    """What both engines simulate: the shape (a ``trimesh.Trimesh``), its (2, 3) bounds,
    pointcvx's decomposition (bundled model, seed 0) and its wall time in seconds, and with
    ``--coacd`` CoACD's parts as ((v, 3), (f, 3)) pairs (else None)."""
    import trimesh

    import pointcvx

    mesh = trimesh.load(args.shape, force="mesh")
    t = time.perf_counter()
    result = pointcvx.decompose(args.shape, features="model", n_points=args.points, seed=0)
    decompose_s = time.perf_counter() - t
    coacd_parts = None
    if args.coacd:
        import coacd

        coacd.set_log_level("error")
        parts = coacd.run_coacd(coacd.Mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)), seed=0)
        coacd_parts = [(np.asarray(v), np.asarray(f)) for v, f in parts]
    return mesh, np.asarray(mesh.bounds), result, decompose_s, coacd_parts


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("shape", nargs="?", default=str(MUG))
    ap.add_argument("--engine", choices=("mujoco", "newton"), default="mujoco")
    ap.add_argument("--points", type=int, default=4000)
    ap.add_argument("--balls", type=int, default=9)
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--coacd", action="store_true", help="add CoACD's hulls ([baselines] extra)")
    ap.add_argument("--json", metavar="OUT", help="also write the numbers as JSON")
    ap.add_argument("--worlds", type=int, default=1,
                    help="Newton: simulate this many copies of each scene at once, one world each")
    args = ap.parse_args(argv)

    if args.engine == "newton":
        return newton_main(args)
    import mujoco

    mesh, bounds, result, decompose_s, coacd_parts = shape_and_decompositions(args)
    top = float(bounds[1, 2])
    limited = result.limit_hulls("physx-gpu")
    variants = {
        f"pointcvx ({len(result)} hulls)": [(h.vertices, h.faces) for h in result.hulls],
        f"pointcvx physx-gpu ({len(limited)} hulls)": [(h.vertices, h.faces) for h in limited.hulls],
        "original mesh (1 geom)": [(np.asarray(mesh.vertices), np.asarray(mesh.faces))],
    }
    if coacd_parts is not None:
        variants[f"coacd ({len(coacd_parts)} hulls)"] = coacd_parts
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


# ------------------------------------------------------------------------------------------ Newton
NEWTON_DT, NEWTON_ITERATIONS = 0.002, 10
NEWTON_TILT = 0.1  # radians: at MuJoCo's 0.3 the mug tips over in XPBD for some variants, not others


def newton_worlds(builder, worlds: int):
    """A finalized CPU model: ``worlds`` copies of ``builder``, each its own world, and the ground."""
    import newton

    root = newton.ModelBuilder()  # z up
    root.replicate(builder, worlds)  # all at the origin: separate worlds do not collide
    root.add_ground_plane()
    return root.finalize(device="cpu")


def newton_model(hulls, kind: str, top: float, bounds: np.ndarray, balls: int, mass_props,
                 triangle_mesh: bool = False, worlds: int = 1):
    """A finalized Newton model (CPU): the ground, the object (free for ``drop``, tilted by only
    ``NEWTON_TILT``; fixed for ``balls``) with one convex shape per ((v, 3), (f, 3)) hull, or one
    triangle-mesh shape for ``triangle_mesh``, and for ``balls`` a grid of 1 cm balls as in
    :func:`scene`; ``worlds`` copies of that, each its own world."""
    import newton
    import warp as wp

    builder = newton.ModelBuilder()
    if kind == "drop":
        tilt = wp.quat_from_axis_angle(wp.vec3(1.0, 0.0, 0.0), NEWTON_TILT)
        mass, com, inertia = mass_props
        body = builder.add_body(xform=wp.transform(wp.vec3(0.0, 0.0, 1.5 * top), tilt), mass=mass,
                                com=wp.vec3(*com), inertia=wp.mat33(*np.ravel(inertia)), lock_inertia=True,
                                label="object")
    else:
        body = -1  # static
    cfg = newton.ModelBuilder.ShapeConfig(density=0.0)  # mass as given above
    add = builder.add_shape_mesh if triangle_mesh else builder.add_shape_convex_hull
    for v, f in hulls:
        shape = newton.Mesh(np.asarray(v, np.float32), np.asarray(f, np.int32).ravel(), compute_inertia=False,
                            maxhullvert=0)
        add(body, mesh=shape, cfg=cfg)
    if kind == "balls":
        for k, at in enumerate(ball_grid(bounds, top, balls)):
            ball = builder.add_body(xform=wp.transform(wp.vec3(*at), wp.quat_identity()), label=f"ball_{k}")
            builder.add_shape_sphere(ball, radius=BALL)
    return newton_worlds(builder, worlds)


def newton_reference_model(worlds: int = 1):
    """Newton's fixed cost per step on this machine: the ground and one 1 cm ball resting on it
    (in each of ``worlds`` worlds)."""
    import newton
    import warp as wp

    builder = newton.ModelBuilder()
    ball = builder.add_body(xform=wp.transform(wp.vec3(0.0, 0.0, BALL), wp.quat_identity()), label="ball")
    builder.add_shape_sphere(ball, radius=BALL)
    return newton_worlds(builder, worlds)


def newton_run(model, seconds: float) -> tuple[float, float, float, np.ndarray, np.ndarray, float]:
    """(CPU seconds per step, of which collision, mean contacts per step, final body_q, body_qd,
    wall seconds per step). Warp runs CPU kernels synchronously on the calling thread, so that
    thread's CPU time is the cost of a step, and less disturbed than wall time by other processes."""
    import newton

    solver = newton.solvers.SolverXPBD(model, iterations=NEWTON_ITERATIONS)
    pipeline = newton.CollisionPipeline(model)
    contacts = pipeline.contacts()
    state, nxt, control = model.state(), model.state(), model.control()
    steps = int(round(seconds / NEWTON_DT))
    collide = total = wall = 0.0
    count = 0
    for _ in range(steps):
        w0, t0 = time.perf_counter(), time.thread_time()
        state.clear_forces()
        pipeline.collide(state, contacts)
        t1 = time.thread_time()
        solver.step(state, nxt, control, contacts, NEWTON_DT)
        t2, w2 = time.thread_time(), time.perf_counter()
        state, nxt = nxt, state
        collide += t1 - t0
        total += t2 - t0
        wall += w2 - w0
        count += int(contacts.rigid_contact_count.numpy()[0])
    return (total / steps, collide / steps, count / steps, state.body_q.numpy(), state.body_qd.numpy(),
            wall / steps)


def newton_main(args) -> int:
    import newton
    import warp as wp

    from pointcvx.export import mass_properties

    wp.config.quiet = True
    wp.config.enable_backward = False  # no gradients: nearly half the compile time
    wp.init()
    mesh, bounds, result, decompose_s, coacd_parts = shape_and_decompositions(args)
    top = float(bounds[1, 2])
    limited = result.limit_hulls("newton")
    single = result.recut(max_hulls=1)
    pairs = [(h.vertices, h.faces) for h in result.hulls]
    mass_props = mass_properties(pairs)
    variants = {  # label: (hulls, as one triangle mesh)
        f"pointcvx ({len(result)} hulls)": (pairs, False),
        f"pointcvx newton ({len(limited)} hulls)": ([(h.vertices, h.faces) for h in limited.hulls], False),
        "original mesh (triangle mesh)": ([(np.asarray(mesh.vertices), np.asarray(mesh.faces))], True),
        "single convex hull": ([(h.vertices, h.faces) for h in single.hulls], False),
    }
    if coacd_parts is not None:
        variants[f"coacd ({len(coacd_parts)} hulls)"] = (coacd_parts, False)
    models = {}
    t = time.perf_counter()
    for label, (hulls, triangles) in variants.items():
        for kind in ("drop", "balls"):
            model = newton_model(hulls, kind, top, bounds, args.balls, mass_props, triangles, args.worlds)
            newton_run(model, 0.1)  # warm-up: Warp compiles (or loads) its kernels on first use
            models[label, kind] = model
    reference = "reference: 1 ball on the ground"
    models[reference, "-"] = newton_reference_model(args.worlds)
    newton_run(models[reference, "-"], 0.1)
    setup_s = time.perf_counter() - t
    runs: dict[tuple[str, str], list] = {key: [] for key in models}
    for _ in range(args.repeat):  # interleaved, so load changes hit every variant alike
        for key, model in models.items():
            runs[key].append(newton_run(model, args.seconds))
    rows = []
    for (label, kind), results in runs.items():
        step, collide, contacts = (float(np.median([r[i] for r in results])) for i in range(3))
        body_q, body_qd = results[-1][3], results[-1][4]
        wall = float(np.median([r[5] for r in results]))
        row = {"variant": label, "scene": kind, "step_us": round(step * 1e6, 1),
               "collide_us": round(collide * 1e6, 1), "wall_us": round(wall * 1e6, 1),
               "contacts": round(contacts, 1)}
        if kind == "-":
            pass
        elif kind == "balls":
            p = body_q[:args.balls, :3]  # the first world's
            inside = (p[:, 2] < top - BALL) & np.all(p[:, :2] > bounds[0, :2], axis=1) \
                & np.all(p[:, :2] < bounds[1, :2], axis=1)
            row["balls_inside"] = f"{int(inside.sum())}/{args.balls}"
        else:
            x, y = body_q[0, 3:5]  # the first world's; quaternion xyzw: body z has world z 1 - 2(x^2 + y^2)
            row["tilt_deg"] = round(float(np.degrees(np.arccos(np.clip(1 - 2 * (x * x + y * y), -1, 1)))), 1)
            row["at_rest"] = bool(np.abs(body_qd[0]).max() < 1e-2)
        rows.append(row)
    print(f"{Path(args.shape).name}: decomposed in {decompose_s:.1f} s; Newton {newton.__version__}, "
          f"Warp {wp.__version__} on the CPU, XPBD {NEWTON_ITERATIONS} iterations, timestep "
          f"{NEWTON_DT * 1e3:g} ms, {args.worlds} world(s), median of {args.repeat}; models built, kernels "
          f"loaded in {setup_s:.0f} s")
    print("CPU time of the stepping thread, us per step (collision + solver), of which collision; wall time")
    print(f"{'variant':<34} {'scene':<6} {'us/step':>8} {'collide':>8} {'wall':>8} {'contacts':>9}  result")
    for r in rows:
        rest = "at rest" if r.get("at_rest") else "moving"
        extra = r.get("balls_inside") or (f"{rest}, tilt {r['tilt_deg']:g} deg" if "tilt_deg" in r else "")
        print(f"{r['variant']:<34} {r['scene']:<6} {r['step_us']:>8.1f} {r['collide_us']:>8.1f} "
              f"{r['wall_us']:>8.1f} {r['contacts']:>9.1f}  {extra}")
    ours, raw = next(iter(variants)), "original mesh (triangle mesh)"
    step = {(r["variant"], r["scene"]): r for r in rows}
    ratios = {}
    base = step[reference, "-"]
    for kind in ("drop", "balls"):
        a, b = step[raw, kind], step[ours, kind]
        above = (a["collide_us"] - base["collide_us"]) / max(b["collide_us"] - base["collide_us"], 1e-9)
        ratios[kind] = {"step": round(a["step_us"] / b["step_us"], 2),
                        "collide": round(a["collide_us"] / b["collide_us"], 2),
                        "collide_above_reference": round(above, 2)}
        print(f"original mesh / pointcvx, {kind}: {ratios[kind]['step']:.2f}x per step, "
              f"{ratios[kind]['collide']:.2f}x in collision, "
              f"{ratios[kind]['collide_above_reference']:.2f}x in collision above the reference's")
    if args.json:
        Path(args.json).write_text(json.dumps({"shape": args.shape, "engine": "newton", "worlds": args.worlds,
                                               "rows": rows, "ratios": ratios}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
