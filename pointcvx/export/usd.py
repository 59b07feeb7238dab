"""USD text layers: a rigid body with a convex-hull collider Mesh per hull (UsdPhysics/PhysX)."""

from __future__ import annotations

import logging
import re

import numpy as np

from .robots import fmt_number, quaternion

log = logging.getLogger(__name__)

def usd_identifier(name: str) -> str:
    """``name`` as a USD prim name: ASCII letters, digits and ``_``, not starting with a digit."""
    ident = re.sub(r"[^A-Za-z0-9_]", "_", str(name))
    return ident if ident and not ident[0].isdigit() else f"_{ident}"


def _usd_tuples(values: np.ndarray, digits: int = 17) -> str:
    """``[(x, y, z), ...]`` of (n, 3) float ``values`` at ``digits`` significant digits."""
    rows = np.asarray(values, dtype=np.float64).reshape(-1, 3)
    return "[" + ", ".join(f"({x:.{digits}g}, {y:.{digits}g}, {z:.{digits}g})" for x, y, z in rows) + "]"


def _usd_ints(values: np.ndarray) -> str:
    return "[" + ", ".join(str(int(i)) for i in np.asarray(values, dtype=np.int64).ravel()) + "]"


def usd_mesh_lines(name: str, vertices: np.ndarray, faces: np.ndarray, indent: str = "",
                   collider: bool = False, digits: int = 17) -> list[str]:
    """The lines of a ``def Mesh`` prim ``name`` of (v, 3) float ``vertices`` and (f, 3) int
    ``faces`` (wound outward: USD's default right-handed orientation), with its ``extent`` and no
    subdivision. ``collider``: a guide-purpose convex-hull collider (``PhysicsCollisionAPI``,
    ``PhysicsMeshCollisionAPI``, ``physics:approximation = "convexHull"``). Coordinates are written
    at ``digits`` significant digits (17: every float64 exactly; USD readers store ``point3f``)."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    i2 = indent + "    "
    if collider:
        lines = [f'{indent}def Mesh "{name}" (',
                 f'{i2}prepend apiSchemas = ["PhysicsCollisionAPI", "PhysicsMeshCollisionAPI"]',
                 f"{indent})"]
    else:
        lines = [f'{indent}def Mesh "{name}"']
    lines.append(f"{indent}{{")
    if len(v):
        lines.append(f"{i2}float3[] extent = {_usd_tuples(np.stack([v.min(axis=0), v.max(axis=0)]), digits)}")
    lines += [f"{i2}int[] faceVertexCounts = {_usd_ints(np.full(len(f), 3))}",
              f"{i2}int[] faceVertexIndices = {_usd_ints(f)}",
              f"{i2}point3f[] points = {_usd_tuples(v, digits)}",
              f'{i2}uniform token subdivisionScheme = "none"']
    if collider:
        lines += [f'{i2}uniform token physics:approximation = "convexHull"',
                  f'{i2}uniform token purpose = "guide"']
    lines.append(f"{indent}}}")
    return lines


def _collision_lines(hulls, indent: str, digits: int) -> list[str]:
    """The Xform ``collision`` holding a collider Mesh ``hull_NNN`` per hull with faces."""
    lines = [f'{indent}def Xform "collision"', f"{indent}{{"]
    first = True
    for i, (v, f) in (hulls.items() if isinstance(hulls, dict) else enumerate(hulls)):
        if len(f) == 0:
            log.warning("hull %d has no faces (a segment or a point): left out of the USD file", i)
            continue
        if not first:
            lines.append("")
        lines += usd_mesh_lines(f"hull_{i:03d}", v, f, indent=indent + "    ", collider=True, digits=digits)
        first = False
    return lines + [f"{indent}}}"]


def _orient_lines(rotation: np.ndarray | None, indent: str) -> list[str]:
    """An ``xformOp:orient`` turning a prim by a (3, 3) ``rotation`` (none for the identity)."""
    if rotation is None or np.allclose(rotation, np.eye(3)):
        return []
    w, x, y, z = quaternion(rotation)
    return [f"{indent}quatf xformOp:orient = ({fmt_number(w)}, {fmt_number(x)}, {fmt_number(y)}, "
            f"{fmt_number(z)})", f'{indent}uniform token[] xformOpOrder = ["xformOp:orient"]']


def _body_lines(name: str, hulls, visual, mass: float, center, digits: int, indent: str,
                static: bool = False) -> list[str]:
    """A rigid body Xform ``name`` (or, ``static``, a plain Xform of colliders: it does not move)."""
    i2 = indent + "    "
    if static:
        return [f'{indent}def Xform "{name}"', f"{indent}{{", *_collision_lines(hulls, i2, digits),
                f"{indent}}}"]
    lines = [f'{indent}def Xform "{name}" (',
             f'{i2}prepend apiSchemas = ["PhysicsRigidBodyAPI", "PhysicsMassAPI"]', f"{indent})",
             f"{indent}{{",
             f"{i2}float physics:mass = {fmt_number(mass)}"]
    if center is not None and mass > 0:
        lines.append(f"{i2}point3f physics:centerOfMass = ({', '.join(fmt_number(c) for c in center)})")
    if visual is not None:
        lines += ["", *usd_mesh_lines("visual", *visual, indent=i2, digits=digits)]
    return lines + ["", *_collision_lines(hulls, i2, digits), f"{indent}}}"]


def _layer_head(default: str, doc: str) -> list[str]:
    return ["#usda 1.0", "(", f'    defaultPrim = "{default}"', f'    doc = "{doc}"',
            "    metersPerUnit = 1", '    upAxis = "Z"', ")", ""]


def usda_text(name: str, hulls, visual: tuple[np.ndarray, np.ndarray] | None = None,
              mass: float = 0.0, center: np.ndarray | None = None, digits: int = 17,
              rotation: np.ndarray | None = None) -> str:
    """A USD text layer (Z up, ``metersPerUnit = 1``) whose default prim is the rigid body Xform
    ``name`` (a valid identifier, see :func:`usd_identifier`; ``PhysicsRigidBodyAPI`` and
    ``PhysicsMassAPI`` with ``mass`` at (3,) ``center``; the engine computes the inertia from the
    colliders), holding ``visual`` (((v, 3) float, (f, 3) int) or None) as the Mesh ``visual`` and
    the Xform ``collision`` with one collider Mesh ``hull_NNN`` per hull (see
    :func:`usd_mesh_lines`), turned by ``rotation`` ((3, 3), default none) so the input's up is Z.

    ``hulls``: a sequence of ((v, 3) float vertices, (f, 3) int faces) pairs, or a dict hull
    index -> pair (:func:`pointcvx.export.robots.robot_hulls`); hulls without faces (a segment, a
    point) are left out, their index unused.
    """
    lines = _layer_head(name, f"pointcvx convex decomposition: {len(hulls)} hulls")
    body = _body_lines(name, hulls, visual, mass, center, digits, "")
    turn = _orient_lines(rotation, "    ")
    if turn:  # after the prim's opening brace
        at = body.index("{") + 1
        body[at:at] = turn
    return "\n".join(lines + body) + "\n"


def _box_lines(name: str, box, digits: int) -> list[str]:
    """A static collider Xform ``name`` holding the box ``box.box()`` (centre, frame, extents)."""
    from ..decomposition.hull import convex_hull

    centre, frame, extents = box.box()
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    hull = convex_hull(centre + (corners * extents) @ np.asarray(frame).T)
    return ["", f'    def Xform "{name}"', "    {",
            *usd_mesh_lines("box", hull.vertices, hull.faces, indent="        ", collider=True,
                            digits=digits), "    }"]


def usda_scene_text(name: str, bodies: list[tuple[str, dict, float, np.ndarray, bool]], rotation: np.ndarray,
                    support, digits: int = 17, walls: tuple = ()) -> str:
    """A USD text layer of a scene: the default prim Xform ``name`` turned by ``rotation`` (the
    scene's up to Z) holding a rigid body Xform per object (``bodies``: (name, hull index ->
    ((v, 3), (f, 3)), mass, (3,) centre, static: an object held by something out of view is a
    plain Xform of colliders, which does not move) and, for ``support`` (a
    :class:`~pointcvx.export.robots.Support`), a static collider box ``support``, and one
    ``wall_NN`` for each of ``walls`` (:class:`~pointcvx.export.robots.StaticBox`)."""
    lines = [*_layer_head(name, f"pointcvx scene: {len(bodies)} objects"), f'def Xform "{name}"', "{",
             *_orient_lines(rotation, "    ")]
    if support is not None:
        lines += _box_lines("support", support, digits)
    for k, wall in enumerate(walls):
        lines += _box_lines(f"wall_{k:02d}", wall, digits)
    for body_name, hulls, mass, center, static in bodies:
        lines += ["", *_body_lines(usd_identifier(body_name), hulls, None, mass, center, digits, "    ",
                                   static=static)]
    lines.append("}")
    return "\n".join(lines) + "\n"

