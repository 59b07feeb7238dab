"""A real physics check in MuJoCo (the [sim] extra): the MJCF export of a real decomposition of a
real mug drops onto a floor and comes to rest standing, and a ball dropped into it stays inside,
which a single convex hull (what a simulator makes of the raw mesh) cannot do."""

from __future__ import annotations

import numpy as np
import pytest

import pointcvx
from conftest import DATA, collision_vertices

MUG = DATA / "dev" / "objects" / "mug.obj"  # 82 mm wide, 100 mm tall, metres, open top
RIM, INNER_RADIUS, BALL = 0.1, 0.0325, 0.01


@pytest.fixture(scope="module")
def mujoco():
    import mujoco

    return mujoco


@pytest.fixture(scope="module")
def mug():
    return pointcvx.decompose(MUG, features="model", n_points=4000, seed=0)


def _scene(mujoco, xml, body, pos, quat=(1.0, 0.0, 0.0, 0.0)):
    """The exported model with a floor added and its body placed at ``pos``."""
    spec = mujoco.MjSpec.from_file(str(xml))
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1.0, 1.0, 0.01])
    spec.body(body).pos = list(pos)
    spec.body(body).quat = list(quat)
    return spec


def test_dropped_mug_comes_to_rest_standing_on_the_floor(mujoco, mug, tmp_path):
    xml = mug.export(tmp_path / "mug.xml")[0]
    tilt = 0.3  # radians about x: it lands on its rim edge first
    spec = _scene(mujoco, xml, "mug", (0.0, 0.0, 0.15), (np.cos(tilt / 2), np.sin(tilt / 2), 0, 0))
    model = spec.compile()
    data = mujoco.MjData(model)
    assert model.body_mass[model.body("mug").id] == pytest.approx(
        1000.0 * sum(h.volume for h in mug.hulls), rel=1e-4)
    heights = []
    for _ in range(int(3.0 / model.opt.timestep)):
        mujoco.mj_step(model, data)
        heights.append(collision_vertices(model, data)[:, 2].min())
    verts = collision_vertices(model, data)
    up = data.xmat[model.body("mug").id].reshape(3, 3)[:, 2]
    assert np.abs(data.qvel).max() < 1e-3  # at rest
    assert -1e-3 < verts[:, 2].min() < 1e-3  # on the floor: touching, not sunk
    assert min(heights) > -0.02  # never tunnelled through it (soft contacts give on impact)
    assert up[2] > 0.99  # standing on its base
    assert np.ptp(verts[:, 2]) == pytest.approx(RIM, abs=2e-3)
    assert data.ncon >= 3


def _drop_ball(mujoco, result, folder, name):
    """Where a 1 cm ball dropped over the middle of the fixed mug is after each second, and its
    final linear speed (a ball resting on a flat bottom may still roll slowly: MuJoCo has no
    rolling friction by default, so its angular velocity says nothing about settling)."""
    xml = result.export(folder / f"{name}.xml", free_joint=False)[0]
    spec = _scene(mujoco, xml, name, (0.0, 0.0, 0.0))
    ball = spec.worldbody.add_body(name="ball", pos=[0.0, 0.0, 0.15])
    ball.add_freejoint()
    ball.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[BALL, 0, 0], density=1000.0)
    model = spec.compile()
    data = mujoco.MjData(model)
    steps = int(1.0 / model.opt.timestep)
    track = []
    for _ in range(3):
        for _ in range(steps):
            mujoco.mj_step(model, data)
        track.append(data.body("ball").xpos.copy())
    return np.array(track), float(np.linalg.norm(data.qvel[:3]))


def _inside(p) -> bool:
    return bool(np.hypot(p[0], p[1]) < INNER_RADIUS - 0.5 * BALL and BALL / 2 < p[2] < RIM - BALL)


def test_ball_stays_in_the_mug_with_pointcvx_hulls_not_with_one_convex_hull(mujoco, mug, tmp_path):
    assert len(mug) > 8
    track, speed = _drop_ball(mujoco, mug, tmp_path, "hulls")
    assert all(_inside(p) for p in track), track  # fell in and stayed in
    assert speed < 1e-2 and track[-1][2] < 0.03  # settled on the bottom
    # the same shape as one convex hull (MuJoCo's own treatment of a mesh geom): a lid on the cup
    single = mug.recut(max_hulls=1)
    assert len(single) == 1
    track, speed = _drop_ball(mujoco, single, tmp_path, "single")
    assert not any(_inside(p) for p in track)
    assert track[-1][2] == pytest.approx(RIM + BALL, abs=2e-3)  # resting on the lid


def test_engine_limited_hulls_keep_the_cavity(mujoco, mug, tmp_path):
    limited = mug.limit_hulls("physx-gpu")
    assert max(len(h.vertices) for h in limited.hulls) <= 64
    track, _ = _drop_ball(mujoco, limited, tmp_path, "limited")
    assert all(_inside(p) for p in track), track
