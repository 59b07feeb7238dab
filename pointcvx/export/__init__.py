"""Writers for decompositions: OBJ, STL, GLB/GLTF, URDF, MJCF, USD (text) and a JSON report.

Small functions over plain arrays; :func:`plan` lays out the files of one format and
:func:`write_files` writes them all or none. Everything is in the input's units.

Layouts (``NAME`` is the output's stem). A path with a format's suffix names a single file, or,
for a multi-file output, the folder ``NAME_FORMAT/`` beside it, so that two formats of one input
never share a folder; a path without suffix, or an existing folder, names the folder itself:

- ``obj``: one ``NAME.obj`` with an ``o hull_NNN`` object per hull; a folder (or ``per_hull``):
  one ``hull_NNN.obj`` per hull in it (``NAME_obj/`` for ``NAME.obj`` with ``per_hull``).
- ``stl``: one ``hull_NNN.stl`` per hull in the folder ``NAME_stl/``.
- ``glb`` / ``gltf``: one scene file, one node ``hull_NNN`` per hull (buffers embedded in GLTF;
  coordinates written as they are, whatever the viewer's up axis).
- ``urdf``: the folder ``NAME_urdf/`` with ``NAME.urdf`` (one link ``NAME``, a ``<collision>``
  per hull, the input mesh as ``<visual>``), ``NAME_collision_N.obj`` per hull and ``NAME.obj``,
  the input mesh (only for mesh and CAD inputs; otherwise the hulls are the visuals too).
- ``mjcf``: the folder ``NAME_mjcf/`` with ``NAME.xml`` in obj2mjcf's layout (a mesh asset per
  file, one body ``NAME`` holding a visual geom of class ``visual``, group 2, contype/conaffinity
  0, and a collision geom of class ``collision``, group 3, per hull) and the same OBJ files as URDF.
- ``usda``: one ``NAME.usda`` (or ``NAME.usd``; text either way), Z up, 1 unit = 1 m: a rigid body
  Xform ``NAME`` (mass from the hulls at ``density``), the input mesh as the Mesh ``visual`` where
  it is a mesh, and an Xform ``collision`` with one guide-purpose Mesh ``hull_NNN`` per hull,
  each a PhysX/UsdPhysics collider with ``physics:approximation = "convexHull"``.
- ``json``: a report: per hull vertex and face counts, volume, added volume, concavity, points;
  totals; parameters; seed; timings.

A single file is written to a hidden temporary beside it and renamed onto it. A multi-file output
is a folder pointcvx owns alone, with a manifest ``.pointcvx.json`` of its files; it is written
hidden beside its place and renamed into it in one step, so it appears whole or not at all, even
under kill -9, and ``overwrite`` replaces a previous output whole (no stale ``hull_NNN`` left).
It is refused in a folder holding files pointcvx did not write, and it never deletes such files
(:mod:`pointcvx.io.outputs`).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import OutputError
from .layout import EXTENSIONS, FOLDER_FORMATS, FORMATS, SUFFIXES, format_for, main_file, output_folder
from .meshes import mesh_obj_text, obj_text, scene_bytes, stl_bytes
from .report import report, report_text
from .robots import (
    Body,
    StaticBox,
    Support,
    mass_properties,
    mjcf_scene_text,
    mjcf_text,
    robot_hulls,
    up_rotation,
    urdf_scene_text,
    urdf_text,
)
from .usd import usd_identifier, usd_mesh_lines, usda_scene_text, usda_text
from .write import write_files

__all__ = ["EXTENSIONS", "FOLDER_FORMATS", "FORMATS", "SUFFIXES", "export_decomposition", "format_for",
           "main_file", "mass_properties", "mesh_obj_text", "mjcf_text", "obj_text", "output_folder",
           "plan", "report", "report_text", "robot_hulls", "scene_bytes", "stl_bytes", "urdf_text",
           "usd_identifier", "usd_mesh_lines", "usda_text", "visual_mesh", "write_files"]


def visual_mesh(result) -> tuple[np.ndarray, np.ndarray] | None:
    """The input mesh in input units ((v, 3) float, (f, 3) int), if the input was a mesh."""
    mesh = result.cloud.mesh
    if mesh is None or len(getattr(mesh, "faces", ())) == 0:
        return None
    return result.cloud.normalization.inverse(np.asarray(mesh.vertices)), np.asarray(mesh.faces)


#: Names of the ``up`` choices of the robot formats (or a (3,) direction).
UP_CHOICES = ("auto", "x", "y", "z", "-x", "-y", "-z")


def up_direction(up, result) -> np.ndarray:
    """(3,) float: the input's up direction for the robot formats: ``up`` as an axis name
    ("z", "-y", ...) or a (3,) direction, or "auto": what isolation detected (the support plane's
    normal, ``cloud.info["up"]``), else +z."""
    if isinstance(up, str):
        if up == "auto":
            found = result.cloud.info.get("up")
            return np.asarray(found if found is not None else (0.0, 0.0, 1.0), dtype=np.float64)
        if up.lstrip("+-") not in ("x", "y", "z") or up.count("-") + up.count("+") > 1:
            raise OutputError(f"up must be one of {', '.join(UP_CHOICES)} or a direction, got {up!r}")
        v = np.zeros(3)
        v["xyz".index(up[-1])] = -1.0 if up.startswith("-") else 1.0
        return v
    v = np.asarray(up, dtype=np.float64).reshape(-1)
    if v.shape != (3,) or not np.isfinite(v).all() or not np.linalg.norm(v) > 0:
        raise OutputError(f"up must be an axis name or a non-zero (3,) direction, got {up!r}")
    return v / np.linalg.norm(v)


def hull_names(result) -> list[str]:
    """Object names of the hulls: ``hull_NNN``, or in a scene ``object_KK_hull_NNN``."""
    if not result.objects:
        return [f"hull_{i:03d}" for i in range(len(result.hulls))]
    names = [f"hull_{i:03d}" for i in range(len(result.hulls))]
    for obj in result.objects:
        for i in obj["hulls"]:
            names[i] = f"{obj['name']}_hull_{i:03d}"
    return names


def scene_support(result) -> Support | None:
    """The scene's support plane as a :class:`~pointcvx.export.robots.Support` (input units): the
    point under the objects' centre, and a box twice as wide as all of them, or None."""
    plane = result.support
    if not plane or not result.objects:
        return None
    normal = np.asarray(plane["normal"], dtype=np.float64)
    lo = np.min([o["bounds"][0] for o in result.objects], axis=0)
    hi = np.max([o["bounds"][1] for o in result.objects], axis=0)
    centre = (lo + hi) / 2
    point = centre - (centre @ normal - float(plane["offset"])) * normal
    return Support(normal, point, 2.0 * float(np.linalg.norm(hi - lo)))


def scene_walls(result) -> list[StaticBox]:
    """A depth frame's walls (``result.cloud.info["isolation"]["walls"]``) as static boxes, input
    units: each box's face is the wall's face (the rectangle on its plane that holds its points,
    :func:`pointcvx.scene.isolate.wall_face`), and the box is as thick as the wall's band (at
    least 1 % of its width), behind the face."""
    if not result.objects:
        return []
    return wall_boxes(result.cloud.info.get("isolation", {}).get("walls", []))


def wall_boxes(walls: list[dict]) -> list[StaticBox]:
    """Static boxes of the walls of an isolation report (:func:`scene_walls`)."""
    boxes = []
    for wall in walls:
        normal = np.asarray(wall["normal"], dtype=np.float64)
        axes = np.asarray(wall["face"]["axes"], dtype=np.float64)
        frame = np.column_stack([axes[0], axes[1], normal])  # the box's axes: the face's, the normal
        size = np.asarray(wall["face"]["extents"], dtype=np.float64)
        face = np.asarray(wall["face"]["center"], dtype=np.float64)
        thick = max(2.0 * float(wall["tolerance"]), 0.01 * float(max(size.max(), 1e-9)))
        boxes.append(StaticBox(face - 0.5 * thick * normal, frame, np.array([*size, thick])))
    return boxes


def plan(result, path: str | os.PathLike, format: str | None = None, per_hull: bool = False,
         free_joint: bool = True, density: float = 1000.0, up="auto") -> dict[Path, str | bytes]:
    """Every file of ``result`` in ``format`` at ``path``, main file first: path -> content.
    ``up`` (robot formats): the input's up direction, turned to +z (:func:`up_direction`)."""
    fmt = format_for(path, format)
    target = Path(path)
    pairs = [(h.vertices, h.faces) for h in result.hulls]
    names = hull_names(result)
    main = main_file(target, fmt, per_hull)
    if fmt in ("obj", "stl") and main is None:
        folder = output_folder(target, fmt, per_hull)
        ext = EXTENSIONS[fmt]
        return {folder / f"{n}{ext}": stl_bytes(v, f) if fmt == "stl" else obj_text([(v, f)], [n])
                for n, (v, f) in zip(names, pairs, strict=True)}
    if fmt == "obj":
        return {main: obj_text(pairs, names)}
    if fmt in ("glb", "gltf"):
        return {main: scene_bytes(pairs, fmt, names)}
    if fmt == "json":
        return {main: report_text(result)}
    rotation = up_rotation(up_direction(up, result))
    solids = robot_hulls(pairs)
    groups = result.objects or [{"name": None, "hulls": list(range(len(pairs)))}]
    if fmt == "usda":  # colliders as the robot formats have them: flat hulls grown to thin slabs
        if not result.objects:
            mass, center, _ = mass_properties(list(solids.values()), density)
            return {main: usda_text(usd_identifier(main.stem), solids, visual_mesh(result), mass, center,
                                    rotation=rotation)}
        bodies = []
        for obj in groups:
            mine = {i: solids[i] for i in obj["hulls"] if i in solids}
            mass, center, _ = mass_properties(list(mine.values()), density)
            bodies.append((obj["name"], mine, mass, center, bool(obj.get("static"))))
        return {main: usda_scene_text(usd_identifier(main.stem), bodies, rotation, scene_support(result),
                                      walls=scene_walls(result))}
    name = main.stem
    files: dict[Path, str | bytes] = {main: ""}
    bodies = []
    for obj in groups:
        prefix = name if obj["name"] is None else f"{name}_{obj['name']}"
        mine = [i for i in obj["hulls"] if i in solids]
        collision = [f"{prefix}_collision_{k}.obj" for k in range(len(mine))] if obj["name"] else \
            [f"{name}_collision_{i}.obj" for i in mine]
        for f, i in zip(collision, mine, strict=True):
            files[main.parent / f] = mesh_obj_text(*solids[i], Path(f).stem)
        mass, center, inertia = mass_properties([solids[i] for i in mine], density)
        bodies.append(Body(obj["name"] or name, collision, list(collision), mass, center, inertia,
                           static=bool(obj.get("static"))))
    if result.objects:
        support = scene_support(result)
        if fmt == "urdf":
            files[main] = urdf_scene_text(name, bodies, rotation, support, walls=scene_walls(result))
        else:
            files[main] = mjcf_scene_text(name, bodies, rotation, support, free_joint=free_joint,
                                          density=density, walls=scene_walls(result))
        return files
    body = bodies[0]
    shown = visual_mesh(result)
    if shown is not None:
        body.visual = [f"{name}.obj"]
        files[main.parent / body.visual[0]] = mesh_obj_text(*shown, name=name)
    if fmt == "urdf":
        files[main] = urdf_text(name, body.collision, body.visual, body.mass, body.center, body.inertia,
                                rotation=rotation)
    else:
        files[main] = mjcf_text(name, body.collision, body.visual, free_joint=free_joint, density=density,
                                rotation=rotation)
    return files


def export_decomposition(result, path: str | os.PathLike, format: str | None = None,
                         overwrite: bool = False, per_hull: bool = False, free_joint: bool = True,
                         density: float = 1000.0, up="auto") -> list[Path]:
    """Write ``result`` (see the module's layouts); return the files written, main file first.
    Never writes onto the input file, nor replaces a folder holding it."""
    fmt = format_for(path, format)
    files = plan(result, path, fmt, per_hull=per_hull, free_joint=free_joint, density=density, up=up)
    folder = output_folder(path, fmt, per_hull)
    main = main_file(path, fmt, per_hull)
    about = {"format": fmt, "main": main.name if main is not None else None}
    return write_files(files, overwrite=overwrite, protect=[result.cloud.info.get("source")],
                       folder=folder, about=about if folder is not None else None)
