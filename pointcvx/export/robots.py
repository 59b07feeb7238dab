"""Robot formats: URDF and MJCF (obj2mjcf's layout) of one object or of a scene (a body per object
on a static support), the rotation that makes the input's up +z, the hulls' mass properties, and
flat hulls grown to thin slabs so engines accept them."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)


def mass_properties(hulls, density: float = 1000.0) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, (3,) centre of mass and (3, 3) inertia about it of the solid hulls at ``density``.

    ``hulls``: ((v, 3) float, (f, 3) int) pairs; overlaps are counted once per hull, as a physics
    engine summing its collision geoms would.
    """
    import trimesh

    meshes = [(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)) for v, f in hulls if len(f)]
    if not meshes:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    triangles = np.concatenate([v[f] for v, f in meshes])
    props = trimesh.triangles.mass_properties(triangles, density=density, skip_inertia=False)
    if not props["volume"] > 0:
        return 0.0, np.concatenate([v for v, _ in meshes]).mean(axis=0), np.zeros((3, 3))
    return float(props["mass"]), np.asarray(props["center_mass"]), np.asarray(props["inertia"])


def robot_hulls(hulls, thickness: float = 1e-3) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Hull index -> ((v, 3) float, (f, 3) int) solids a simulator accepts: flat hulls (zero
    volume; MuJoCo refuses coplanar meshes) grow to a slab ``thickness`` x the largest hull
    extent thick on both sides, which still contains them; hulls without faces (a segment, a point)
    are left out.

    ``hulls``: ((v, 3) float, (f, 3) int) pairs.
    """
    from ..decomposition.hull import convex_hull

    pairs = [(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)) for v, f in hulls]
    size = max((float(np.ptp(v, axis=0).max()) for v, _ in pairs if len(v)), default=1.0)
    out = {}
    for i, (v, f) in enumerate(pairs):
        if len(f) == 0:
            log.warning("hull %d has no faces (a segment or a point): left out of the robot file", i)
            continue
        centred = v - v.mean(axis=0)
        extent = float(np.ptp(v, axis=0).max())
        normal = np.linalg.svd(centred, full_matrices=False)[2][-1]
        if float(np.abs(centred @ normal).max()) > 1e-6 * extent:
            out[i] = (v, f)
            continue
        half = 0.5 * thickness * size * normal
        slab = convex_hull(np.concatenate([v + half, v - half]))
        out[i] = (slab.vertices, slab.faces)
    return out


def fmt_number(x: float) -> str:
    return f"{float(x):.9g}"


# ------------------------------------------------------------------------------ orientation
def up_rotation(up) -> np.ndarray:
    """(3, 3) float: the smallest rotation taking the (3,) direction ``up`` to +z (the gravity
    convention of MuJoCo, URDF tools and USD's Z up). Hull coordinates stay in the input's frame;
    the writers put this rotation on bodies and geometry frames."""
    u = np.asarray(up, dtype=np.float64).reshape(3)
    u = u / np.linalg.norm(u)
    z = np.array([0.0, 0.0, 1.0])
    c = float(u @ z)
    if c > 1 - 1e-12:
        return np.eye(3)
    if c < -1 + 1e-12:  # upside down: half a turn about x
        return np.diag([1.0, -1.0, -1.0])
    axis = np.cross(u, z)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + k + k @ k / (1 + c)


def quaternion(rotation: np.ndarray) -> np.ndarray:
    """(4,) float (w, x, y, z) unit quaternion of a (3, 3) rotation matrix, w >= 0."""
    m = np.asarray(rotation, dtype=np.float64)
    w = np.sqrt(max(0.0, 1.0 + m[0, 0] + m[1, 1] + m[2, 2])) / 2
    x = np.copysign(np.sqrt(max(0.0, 1.0 + m[0, 0] - m[1, 1] - m[2, 2])) / 2, m[2, 1] - m[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1.0 - m[0, 0] + m[1, 1] - m[2, 2])) / 2, m[0, 2] - m[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1.0 - m[0, 0] - m[1, 1] + m[2, 2])) / 2, m[1, 0] - m[0, 1])
    q = np.array([w, x, y, z])
    return q / np.linalg.norm(q)


def rpy(rotation: np.ndarray) -> np.ndarray:
    """(3,) float (roll, pitch, yaw) of a (3, 3) rotation, URDF's convention R = Rz Ry Rx."""
    m = np.asarray(rotation, dtype=np.float64)
    pitch = float(np.arcsin(np.clip(-m[2, 0], -1.0, 1.0)))
    if abs(m[2, 0]) < 1 - 1e-9:
        return np.array([np.arctan2(m[2, 1], m[2, 2]), pitch, np.arctan2(m[1, 0], m[0, 0])])
    return np.array([np.arctan2(-m[1, 2], m[1, 1]), pitch, 0.0])  # gimbal lock: yaw folded into roll


def _vec(v) -> str:
    return " ".join(fmt_number(c) for c in np.asarray(v, dtype=np.float64).reshape(-1))


# ------------------------------------------------------------------------------ bodies
@dataclass
class Body:
    """One rigid body of a robot file: its mesh files (paths relative to the robot file) and mass
    properties (input units: ``center`` (3,), ``inertia`` (3, 3) about it)."""

    name: str
    collision: list[str]
    visual: list[str]
    mass: float = 0.0
    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    inertia: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    #: A scene's object held by something out of view (resting on nothing, or not standing
    #: where it rests): it does not move.
    static: bool = False


@dataclass
class Support:
    """The static plane a scene stands on: (3,) unit ``normal`` (pointing to the objects), a (3,)
    ``point`` on it and the ``size`` of the box that stands for it where a format has no infinite
    plane (URDF, USD), in input units."""

    normal: np.ndarray
    point: np.ndarray
    size: float

    def box(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """((3,) centre, (3, 3) rotation whose z axis is the normal, (3,) full extents) of a thin
        box whose top face is the plane."""
        z = np.asarray(self.normal, dtype=np.float64)
        r = up_rotation(z).T  # takes +z to the normal
        thick = 0.02 * self.size
        return self.point - 0.5 * thick * z, r, np.array([self.size, self.size, thick])


@dataclass
class StaticBox:
    """A static box of a scene (a depth frame's wall), input units: (3,) ``centre``, (3, 3)
    ``frame`` (its columns the box's axes, the third the wall's normal) and (3,) full
    ``extents``."""

    centre: np.ndarray
    frame: np.ndarray
    extents: np.ndarray

    def box(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.centre, self.frame, self.extents


def _urdf_box(name: str, box, rotation: np.ndarray) -> list[str]:
    """A ``<collision>`` element of a static box (``box.box()``: centre, frame, extents)."""
    centre, frame, extents = box.box()
    return [f'    <collision name="{name}">',
            f'      <origin xyz="{_vec(rotation @ centre)}" rpy="{_vec(rpy(rotation @ frame))}"/>',
            f'      <geometry><box size="{_vec(extents)}"/></geometry>', "    </collision>"]


def _urdf_link(name: str, body: Body, rotation: np.ndarray, q) -> list[str]:
    i = body.inertia
    origin = f'<origin xyz="0 0 0" rpy="{_vec(rpy(rotation))}"/>'
    lines = [f"  <link name={q(name)}>", "    <inertial>",
             f'      <origin xyz="{_vec(rotation @ body.center)}" rpy="{_vec(rpy(rotation))}"/>',
             f'      <mass value="{fmt_number(body.mass)}"/>',
             f'      <inertia ixx="{fmt_number(i[0, 0])}" ixy="{fmt_number(i[0, 1])}" '
             f'ixz="{fmt_number(i[0, 2])}" iyy="{fmt_number(i[1, 1])}" iyz="{fmt_number(i[1, 2])}" '
             f'izz="{fmt_number(i[2, 2])}"/>',
             "    </inertial>"]
    for f in body.visual:
        lines += ["    <visual>", f"      {origin}", f"      <geometry><mesh filename={q(f)}/></geometry>",
                  "    </visual>"]
    for k, f in enumerate(body.collision):
        lines += [f'    <collision name="hull_{k:03d}">', f"      {origin}",
                  f"      <geometry><mesh filename={q(f)}/></geometry>", "    </collision>"]
    return lines + ["  </link>"]


def urdf_text(name: str, collision_files: list[str], visual_files: list[str], mass: float,
              center: np.ndarray, inertia: np.ndarray, rotation: np.ndarray | None = None) -> str:
    """A URDF with one link ``name``: a ``<visual>`` per visual mesh file, a ``<collision>`` per
    hull mesh file (paths relative to the URDF), and the inertial of ``mass`` at (3,) ``center``
    with (3, 3) ``inertia`` about it; every frame turned by ``rotation`` ((3, 3), default none:
    see :func:`up_rotation`)."""
    from xml.sax.saxutils import quoteattr as q  # here: it imports urllib.request (~50 ms)

    body = Body(name, collision_files, visual_files, mass, np.asarray(center), np.asarray(inertia))
    rot = np.eye(3) if rotation is None else np.asarray(rotation)
    lines = ['<?xml version="1.0"?>', f"<robot name={q(name)}>", *_urdf_link(name, body, rot, q), "</robot>"]
    return "\n".join(lines) + "\n"


def urdf_scene_text(name: str, bodies: list[Body], rotation: np.ndarray, support: Support | None,
                    walls: tuple = ()) -> str:
    """A URDF of a scene: a root link ``name`` (holding the support plane and each of ``walls``
    (:class:`StaticBox`) as box collisions) and one link per body, fixed to it (a captured scene
    is the robot's environment)."""
    from xml.sax.saxutils import quoteattr as q

    lines = ['<?xml version="1.0"?>', f"<robot name={q(name)}>", f"  <link name={q(name)}>"]
    if support is not None:
        lines += _urdf_box("support", support, rotation)
    for k, wall in enumerate(walls):
        lines += _urdf_box(f"wall_{k:02d}", wall, rotation)
    lines.append("  </link>")
    for body in bodies:
        lines += _urdf_link(body.name, body, rotation, q)
        lines += [f"  <joint name={q(body.name + '_fixed')} type=\"fixed\">", f"    <parent link={q(name)}/>",
                  f"    <child link={q(body.name)}/>", '    <origin xyz="0 0 0" rpy="0 0 0"/>', "  </joint>"]
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def _mjcf_head(name: str, density: float, q) -> list[str]:
    return [f"<mujoco model={q(name)}>", '  <compiler angle="radian"/>',
            "  <default>",
            '    <default class="visual">',
            '      <geom group="2" type="mesh" contype="0" conaffinity="0" density="0"/>',
            "    </default>",
            '    <default class="collision">',
            f'      <geom group="3" type="mesh" density="{fmt_number(density)}"/>',
            "    </default>",
            "  </default>",
            "  <asset>"]


def _mjcf_assets(bodies: list[Body], q) -> list[str]:
    lines, seen = [], set()
    for body in bodies:
        for f in body.visual:
            if f not in body.collision and f not in seen:  # the input mesh: maybe open, so shell inertia
                lines.append(f'    <mesh name={q(Path(f).stem)} file={q(f)} inertia="shell"/>')
                seen.add(f)
        for f in body.collision:
            if f not in seen:
                lines.append(f"    <mesh name={q(Path(f).stem)} file={q(f)}/>")
                seen.add(f)
    return lines


def _mjcf_body(body: Body, free_joint: bool, rotation: np.ndarray, q, indent: str = "    ") -> list[str]:
    """A ``<body>`` turned by ``rotation``, its frame at ``body.center`` (the geoms shifted back
    by it; a body without mass properties stays at the origin), so the body's position is where
    the object is, and a small turn of an object far from the origin does not read as a large
    move of its frame."""
    turn = "" if np.allclose(rotation, np.eye(3)) else f' quat="{_vec(quaternion(rotation))}"'
    place, shift = "", ""
    if np.any(body.center):
        place, shift = f' pos="{_vec(rotation @ body.center)}"', f' pos="{_vec(-np.asarray(body.center))}"'
    lines = [f"{indent}<body name={q(body.name)}{place}{turn}>"]
    if free_joint:
        lines.append(f"{indent}  <freejoint name={q(body.name + '_free')}/>")
    for f in body.visual:
        lines.append(f'{indent}  <geom mesh={q(Path(f).stem)} class="visual"{shift}/>')
    for f in body.collision:
        stem = q(Path(f).stem)
        lines.append(f'{indent}  <geom name={stem} mesh={stem} class="collision"{shift}/>')
    return lines + [f"{indent}</body>"]


def mjcf_text(name: str, collision_files: list[str], visual_files: list[str],
              free_joint: bool = True, density: float = 1000.0, rotation: np.ndarray | None = None) -> str:
    """An MJCF model in obj2mjcf's layout: a mesh asset per file, one body ``name`` with visual
    geoms (class ``visual``: group 2, no contacts, no mass) and a collision geom per hull (class
    ``collision``: group 3, mass from ``density``); a free joint unless ``free_joint`` is False;
    the body turned by ``rotation`` ((3, 3), default none: see :func:`up_rotation`). Paths are
    relative to the MJCF file."""
    from xml.sax.saxutils import quoteattr as q

    body = Body(name, collision_files, visual_files)
    rot = np.eye(3) if rotation is None else np.asarray(rotation)
    lines = [*_mjcf_head(name, density, q), *_mjcf_assets([body], q), "  </asset>", "  <worldbody>",
             *_mjcf_body(body, free_joint, rot, q), "  </worldbody>", "</mujoco>"]
    return "\n".join(lines) + "\n"


def mjcf_scene_text(name: str, bodies: list[Body], rotation: np.ndarray, support: Support | None,
                    free_joint: bool = True, density: float = 1000.0, walls: tuple = ()) -> str:
    """An MJCF model of a scene: the support as a static plane geom, each of ``walls``
    (:class:`StaticBox`) as a static box geom, and one body per object (free unless
    ``free_joint`` is False or the body is ``static``, its frame at the object's centre of
    mass), all turned by ``rotation`` so the scene's up is +z."""
    from xml.sax.saxutils import quoteattr as q

    lines = [*_mjcf_head(name, density, q), *_mjcf_assets(bodies, q), "  </asset>", "  <worldbody>"]
    if support is not None:
        normal = rotation @ support.normal
        plane = quaternion(up_rotation(normal).T)
        lines.append(f'    <geom name="support" type="plane" size="{_vec([support.size / 2] * 2)} 1" '
                     f'pos="{_vec(rotation @ support.point)}" quat="{_vec(plane)}"/>')
    for k, wall in enumerate(walls):
        centre, frame, extents = wall.box()
        lines.append(f'    <geom name="wall_{k:02d}" type="box" size="{_vec(np.asarray(extents) / 2)}" '
                     f'pos="{_vec(rotation @ centre)}" quat="{_vec(quaternion(rotation @ frame))}"/>')
    for body in bodies:
        lines += _mjcf_body(body, free_joint and not body.static, rotation, q)
    lines += ["  </worldbody>", "</mujoco>"]
    return "\n".join(lines) + "\n"
