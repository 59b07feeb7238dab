"""Writers for decompositions: OBJ, STL, GLB/GLTF, URDF, MJCF, USD (text) and a JSON report.

Small functions over plain arrays; :func:`export_decomposition` lays out the files of one format
and :func:`write_files` writes them all or none. Everything is in the input's units.

Layouts (``NAME`` is the output's stem):

- ``obj``: one ``NAME.obj`` with an ``o hull_NNN`` object per hull; a folder (or ``per_hull``):
  one ``hull_NNN.obj`` per hull.
- ``stl``: one ``hull_NNN.stl`` per hull in the folder ``NAME/``.
- ``glb`` / ``gltf``: one scene file, one node ``hull_NNN`` per hull (buffers embedded in GLTF;
  coordinates written as they are, whatever the viewer's up axis).
- ``urdf``: the folder ``NAME/`` with ``NAME.urdf`` (one link ``NAME``, a ``<collision>`` per hull,
  the input mesh as ``<visual>``), ``NAME_collision_N.obj`` per hull and ``NAME.obj``, the input
  mesh (only for mesh and CAD inputs; otherwise the hulls are the visuals too).
- ``mjcf``: the folder ``NAME/`` with ``NAME.xml`` in obj2mjcf's layout (a mesh asset per file, one
  body ``NAME`` holding a visual geom of class ``visual``, group 2, contype/conaffinity 0, and a
  collision geom of class ``collision``, group 3, per hull) and the same OBJ files as URDF.
- ``usda``: one ``NAME.usda`` (or ``NAME.usd``; text either way), Z up, 1 unit = 1 m: a rigid body
  Xform ``NAME`` (mass from the hulls at ``density``), the input mesh as the Mesh ``visual`` where
  it is a mesh, and an Xform ``collision`` with one guide-purpose Mesh ``hull_NNN`` per hull,
  each a PhysX/UsdPhysics collider with ``physics:approximation = "convexHull"``.
- ``json``: a report: per hull vertex and face counts, volume, added volume, concavity, points;
  totals; parameters; seed; timings.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np

from .errors import OutputError
from .io.files import atomic_path

log = logging.getLogger(__name__)

FORMATS = ("obj", "stl", "glb", "gltf", "urdf", "mjcf", "usda", "json")
SUFFIXES = {".obj": "obj", ".stl": "stl", ".glb": "glb", ".gltf": "gltf", ".urdf": "urdf",
            ".xml": "mjcf", ".mjcf": "mjcf", ".usda": "usda", ".usd": "usda", ".json": "json"}
EXTENSIONS = {"obj": ".obj", "stl": ".stl", "glb": ".glb", "gltf": ".gltf", "urdf": ".urdf",
              "mjcf": ".xml", "usda": ".usda", "json": ".json"}
FOLDER_FORMATS = ("stl", "urdf", "mjcf")


# ------------------------------------------------------------------------------ format and layout
def format_for(path: str | os.PathLike, format: str | None = None) -> str:
    """The output format: ``format`` if given (checked against ``path``'s suffix), else from the
    suffix; a folder or a path without a suffix means per-hull OBJ files."""
    target = Path(path)
    suffix = target.suffix.lower()
    if format is not None:
        fmt = str(format).lower()
        if fmt not in FORMATS:
            raise OutputError(f"unknown output format {format!r}; expected one of {', '.join(FORMATS)}")
        if suffix in SUFFIXES and SUFFIXES[suffix] != fmt and not target.is_dir():
            raise OutputError(f"{target}: the suffix {suffix} does not match the format {fmt!r}")
        return fmt
    if target.is_dir() or suffix == "":
        return "obj"
    if suffix not in SUFFIXES:
        raise OutputError(f"{target}: unsupported output format {suffix!r} (use one of "
                          f"{', '.join(sorted(SUFFIXES))}, or a folder for one file per hull)")
    return SUFFIXES[suffix]


def output_folder(path: str | os.PathLike, format: str) -> Path:
    """The folder a folder format writes into: ``path`` without its format suffix."""
    target = Path(path)
    if target.suffix.lower() in SUFFIXES and not target.is_dir():
        return target.with_suffix("")
    return target


def main_file(path: str | os.PathLike, format: str, per_hull: bool = False) -> Path | None:
    """The file a person opens (the URDF, the MJCF, the single scene), or None for per-hull files."""
    target = Path(path)
    if format in ("urdf", "mjcf"):
        folder = output_folder(target, format)
        return folder / f"{folder.name}{EXTENSIONS[format]}"
    if format == "stl" or (format == "obj" and (per_hull or target.is_dir() or not target.suffix)):
        return None
    if target.is_dir():
        return target / f"hulls{EXTENSIONS[format]}"
    return target


# ------------------------------------------------------------------------------ mesh writers
def obj_text(hulls, names: list[str] | None = None, digits: int = 17, header: bool = True) -> str:
    """Wavefront OBJ text with one ``o`` object per hull (1-based global indices).

    ``hulls``: a sequence of ((v, 3) float vertices, (f, 3) int faces) pairs; ``names``: the
    objects' names (default ``hull_NNN``); ``digits``: significant digits of the coordinates (the
    default 17 keeps every float64 exactly, so a hull read back still contains what it contained).
    """
    names = names if names is not None else [f"hull_{i:03d}" for i in range(len(hulls))]
    lines = ["# pointcvx convex decomposition", f"# hulls {len(hulls)}"] if header else []
    offset = 1
    for name, (vertices, faces) in zip(names, hulls, strict=True):
        lines.append(f"o {name}")
        lines.extend(f"v {x:.{digits}g} {y:.{digits}g} {z:.{digits}g}"
                     for x, y, z in np.asarray(vertices, dtype=np.float64))
        lines.extend(f"f {a + offset} {b + offset} {c + offset}"
                     for a, b, c in np.asarray(faces, dtype=np.int64))
        offset += len(vertices)
    return "\n".join(lines) + "\n"


def mesh_obj_text(vertices: np.ndarray, faces: np.ndarray, name: str = "mesh") -> str:
    """OBJ text of one mesh, (v, 3) float ``vertices`` and (f, 3) int ``faces``, at full float
    precision (17 digits) and without the decomposition header."""
    return obj_text([(vertices, faces)], names=[name], header=False)


def stl_bytes(vertices: np.ndarray, faces: np.ndarray, name: str = "pointcvx") -> bytes:
    """Binary STL of (v, 3) float ``vertices`` and (f, 3) int ``faces`` (float32, as STL stores)."""
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
    record = np.dtype([("normal", "<f4", 3), ("tri", "<f4", (3, 3)), ("attr", "<u2")])
    data = np.zeros(len(tri), dtype=record)
    data["normal"], data["tri"] = normal, tri
    header = name.encode("ascii", "replace")[:80].ljust(80, b" ")
    return header + np.uint32(len(tri)).tobytes() + data.tobytes()


def scene_bytes(hulls, file_type: str = "glb") -> bytes:
    """A GLB or GLTF (buffers embedded) scene with one node ``hull_NNN`` per hull.

    ``hulls``: a sequence of ((v, 3) float vertices, (f, 3) int faces) pairs.
    """
    import trimesh

    scene = trimesh.Scene()
    for i, (vertices, faces) in enumerate(hulls):
        mesh = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(faces), process=False)
        scene.add_geometry(mesh, node_name=f"hull_{i:03d}", geom_name=f"hull_{i:03d}")
    if file_type == "glb":
        return scene.export(file_type="glb")
    files = trimesh.exchange.gltf.export_gltf(scene, embed_buffers=True)
    return files["model.gltf"]


# ------------------------------------------------------------------------------ robot formats
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
    from .decomposition.hull import convex_hull

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


def _fmt(x: float) -> str:
    return f"{float(x):.9g}"


def urdf_text(name: str, collision_files: list[str], visual_files: list[str], mass: float,
              center: np.ndarray, inertia: np.ndarray) -> str:
    """A URDF with one link ``name``: a ``<visual>`` per visual mesh file, a ``<collision>`` per
    hull mesh file (paths relative to the URDF), and the inertial of ``mass`` at (3,) ``center``
    with (3, 3) ``inertia`` about it."""
    q = quoteattr
    i = inertia
    lines = ['<?xml version="1.0"?>', f"<robot name={q(name)}>", f"  <link name={q(name)}>",
             "    <inertial>",
             f'      <origin xyz="{" ".join(_fmt(c) for c in center)}" rpy="0 0 0"/>',
             f'      <mass value="{_fmt(mass)}"/>',
             f'      <inertia ixx="{_fmt(i[0, 0])}" ixy="{_fmt(i[0, 1])}" ixz="{_fmt(i[0, 2])}" '
             f'iyy="{_fmt(i[1, 1])}" iyz="{_fmt(i[1, 2])}" izz="{_fmt(i[2, 2])}"/>',
             "    </inertial>"]
    for f in visual_files:
        lines += ["    <visual>", '      <origin xyz="0 0 0" rpy="0 0 0"/>',
                  f"      <geometry><mesh filename={q(f)}/></geometry>", "    </visual>"]
    for k, f in enumerate(collision_files):
        lines += [f'    <collision name="hull_{k:03d}">', '      <origin xyz="0 0 0" rpy="0 0 0"/>',
                  f"      <geometry><mesh filename={q(f)}/></geometry>", "    </collision>"]
    lines += ["  </link>", "</robot>"]
    return "\n".join(lines) + "\n"


def mjcf_text(name: str, collision_files: list[str], visual_files: list[str],
              free_joint: bool = True, density: float = 1000.0) -> str:
    """An MJCF model in obj2mjcf's layout: a mesh asset per file, one body ``name`` with visual
    geoms (class ``visual``: group 2, no contacts, no mass) and a collision geom per hull (class
    ``collision``: group 3, mass from ``density``); a free joint unless ``free_joint`` is False.
    Paths are relative to the MJCF file."""
    q = quoteattr
    lines = [f"<mujoco model={q(name)}>", '  <compiler angle="radian"/>',
             "  <default>",
             '    <default class="visual">',
             '      <geom group="2" type="mesh" contype="0" conaffinity="0" density="0"/>',
             "    </default>",
             '    <default class="collision">',
             f'      <geom group="3" type="mesh" density="{_fmt(density)}"/>',
             "    </default>",
             "  </default>",
             "  <asset>"]
    visual_names = [Path(f).stem for f in visual_files]
    for f, n in zip(visual_files, visual_names, strict=True):
        if f not in collision_files:  # the input mesh: a surface, maybe open, so shell inertia
            lines.append(f'    <mesh name={q(n)} file={q(f)} inertia="shell"/>')
    for f in collision_files:
        lines.append(f"    <mesh name={q(Path(f).stem)} file={q(f)}/>")
    lines += ["  </asset>", "  <worldbody>", f"    <body name={q(name)}>"]
    if free_joint:
        lines.append(f"      <freejoint name={q(name + '_free')}/>")
    for n in visual_names:
        lines.append(f'      <geom mesh={q(n)} class="visual"/>')
    for f in collision_files:
        lines.append(f'      <geom name={q(Path(f).stem)} mesh={q(Path(f).stem)} class="collision"/>')
    lines += ["    </body>", "  </worldbody>", "</mujoco>"]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------ USD
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


def usda_text(name: str, hulls, visual: tuple[np.ndarray, np.ndarray] | None = None,
              mass: float = 0.0, center: np.ndarray | None = None, digits: int = 17) -> str:
    """A USD text layer (Z up, ``metersPerUnit = 1``) whose default prim is the rigid body Xform
    ``name`` (a valid identifier, see :func:`usd_identifier`; ``PhysicsRigidBodyAPI`` and
    ``PhysicsMassAPI`` with ``mass`` at (3,) ``center``; the engine computes the inertia from the
    colliders), holding ``visual`` (((v, 3) float, (f, 3) int) or None) as the Mesh ``visual`` and
    the Xform ``collision`` with one collider Mesh ``hull_NNN`` per hull (see
    :func:`usd_mesh_lines`).

    ``hulls``: a sequence of ((v, 3) float vertices, (f, 3) int faces) pairs, or a dict hull
    index -> pair (:func:`robot_hulls`); hulls without faces (a segment, a point) are left out,
    their index unused.
    """
    lines = ["#usda 1.0", "(", f'    defaultPrim = "{name}"',
             f'    doc = "pointcvx convex decomposition: {len(hulls)} hulls"',
             "    metersPerUnit = 1", '    upAxis = "Z"', ")", "",
             f'def Xform "{name}" (', '    prepend apiSchemas = ["PhysicsRigidBodyAPI", "PhysicsMassAPI"]',
             ")", "{", f"    float physics:mass = {_fmt(mass)}"]
    if center is not None and mass > 0:
        lines.append(f"    point3f physics:centerOfMass = ({', '.join(_fmt(c) for c in center)})")
    if visual is not None:
        lines += ["", *usd_mesh_lines("visual", *visual, indent="    ", digits=digits)]
    lines += ["", '    def Xform "collision"', "    {"]
    first = True
    for i, (v, f) in (hulls.items() if isinstance(hulls, dict) else enumerate(hulls)):
        if len(f) == 0:
            log.warning("hull %d has no faces (a segment or a point): left out of the USD file", i)
            continue
        if not first:
            lines.append("")
        lines += usd_mesh_lines(f"hull_{i:03d}", v, f, indent="        ", collider=True, digits=digits)
        first = False
    lines += ["    }", "}"]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------ report
def report(result) -> dict[str, Any]:
    """The JSON report of a :class:`~pointcvx.result.Decomposition` (input units for volumes)."""
    from .version import __version__

    hulls = []
    for i, h in enumerate(result.hulls):
        volume = h.volume
        hulls.append({"name": f"hull_{i:03d}", "vertices": int(len(h.vertices)),
                      "faces": int(len(h.faces)), "volume": volume,
                      "added_volume": float(h.added_volume), "concavity": float(h.concavity),
                      "points": int(h.n_points)})
    volume = float(sum(h["volume"] for h in hulls))
    added = float(sum(h["added_volume"] for h in hulls))
    totals = {"hulls": len(hulls), "vertices": int(sum(h["vertices"] for h in hulls)),
              "faces": int(sum(h["faces"] for h in hulls)),
              "max_hull_vertices": int(max((h["vertices"] for h in hulls), default=0)),
              "volume": volume, "added_volume": added,
              "added_volume_ratio": added / (volume - added) if volume - added > 0 else 0.0,
              "max_concavity": float(result.max_concavity),
              "mean_concavity": float(result.concavity.mean()) if hulls else 0.0,
              "points": int(len(result.labels))}
    return {"pointcvx": __version__, "source": result.cloud.info.get("source"), "units": "input",
            "hulls": hulls, "totals": totals, "limits": result.params.get("hull_limits"),
            "parameters": {k: v for k, v in result.params.items() if k != "hull_limits"},
            "seed": result.seed, "timings": dict(result.timings)}


def report_text(result) -> str:
    return json.dumps(report(result), indent=2, default=str) + "\n"


# ------------------------------------------------------------------------------ writing
def visual_mesh(result) -> tuple[np.ndarray, np.ndarray] | None:
    """The input mesh in input units ((v, 3) float, (f, 3) int), if the input was a mesh."""
    mesh = result.cloud.mesh
    if mesh is None or len(getattr(mesh, "faces", ())) == 0:
        return None
    return result.cloud.normalization.inverse(np.asarray(mesh.vertices)), np.asarray(mesh.faces)


def plan(result, path: str | os.PathLike, format: str | None = None, per_hull: bool = False,
         free_joint: bool = True, density: float = 1000.0) -> dict[Path, str | bytes]:
    """Every file of ``result`` in ``format`` at ``path``, main file first: path -> content."""
    fmt = format_for(path, format)
    target = Path(path)
    pairs = [(h.vertices, h.faces) for h in result.hulls]
    if fmt in ("obj", "stl") and main_file(target, fmt, per_hull) is None:
        folder = output_folder(target, fmt)
        ext = EXTENSIONS[fmt]
        return {folder / f"hull_{i:03d}{ext}": stl_bytes(v, f) if fmt == "stl" else obj_text([(v, f)])
                for i, (v, f) in enumerate(pairs)}
    main = main_file(target, fmt, per_hull)
    if fmt == "obj":
        return {main: obj_text(pairs)}
    if fmt in ("glb", "gltf"):
        return {main: scene_bytes(pairs, fmt)}
    if fmt == "json":
        return {main: report_text(result)}
    if fmt == "usda":  # colliders as the robot formats have them: flat hulls grown to thin slabs
        solids = robot_hulls(pairs)
        mass, center, _ = mass_properties(list(solids.values()), density)
        return {main: usda_text(usd_identifier(main.stem), solids, visual_mesh(result), mass, center)}
    name = main.stem
    files: dict[Path, str | bytes] = {main: ""}
    solids = robot_hulls(pairs)
    collision = [f"{name}_collision_{i}.obj" for i in sorted(solids)]
    for f, (v, fc) in zip(collision, solids.values(), strict=True):
        files[main.parent / f] = mesh_obj_text(v, fc, Path(f).stem)
    pairs = list(solids.values())
    shown = visual_mesh(result)
    if shown is not None:
        visual = [f"{name}.obj"]
        files[main.parent / visual[0]] = mesh_obj_text(*shown, name=name)
    else:
        visual = list(collision)
    if fmt == "urdf":
        mass, center, inertia = mass_properties(pairs, density)
        files[main] = urdf_text(name, collision, visual, mass, center, inertia)
    else:
        files[main] = mjcf_text(name, collision, visual, free_joint=free_joint, density=density)
    return files


def write_files(files: dict[Path, str | bytes], overwrite: bool = False,
                protect: list[str | os.PathLike] = ()) -> list[Path]:
    """Write every file or none: (path -> text or bytes), folders made as needed.

    Refuses (:class:`OutputError`) before writing anything when a path is one of ``protect`` (the
    input), a folder, or exists without ``overwrite``. All files are written to temporary names
    first and renamed only once every one of them is complete.
    """
    paths = list(files)
    guarded = [Path(p) for p in protect if p is not None and Path(p).exists()]
    for p in paths:
        if p.exists() and any(os.path.samefile(p, g) for g in guarded):
            raise OutputError(f"{p}: refusing to overwrite the input file")
        if p.is_dir():
            raise OutputError(f"{p}: is a folder")
        if p.parent.exists() and not p.parent.is_dir():
            raise OutputError(f"{p.parent}: exists and is not a folder")
    clash = [p for p in paths if p.exists()] if not overwrite else []
    if clash:
        more = f" (and {len(clash) - 1} more)" if len(clash) > 1 else ""
        raise OutputError(f"{clash[0]}: exists{more}; pass overwrite to replace")
    made = []
    for folder in dict.fromkeys(p.parent for p in paths):
        if not folder.exists():
            missing = [folder, *[a for a in folder.parents if not a.exists()]]
            try:
                folder.mkdir(parents=True)
            except OSError as exc:
                raise OutputError(f"{folder}: cannot create the output folder ({exc.strerror})") from None
            made += missing
    current = None
    try:
        with contextlib.ExitStack() as stack:
            for current, data in files.items():
                tmp = stack.enter_context(atomic_path(current, overwrite=True))
                if isinstance(data, bytes):
                    tmp.write_bytes(data)
                else:
                    tmp.write_text(data)
            current = None  # the renames happen as the stack closes
    except BaseException as exc:
        for folder in sorted(made, key=lambda f: len(f.parts), reverse=True):
            with contextlib.suppress(OSError):
                folder.rmdir()
        if isinstance(exc, OSError) and not isinstance(exc, OutputError):
            where = current if current is not None else exc.filename or paths[0]
            raise OutputError(f"{where}: cannot write ({exc.strerror or exc}); nothing was written") from None
        raise
    log.debug("wrote %d files, first %s", len(paths), paths[0] if paths else None)
    return paths


def export_decomposition(result, path: str | os.PathLike, format: str | None = None,
                         overwrite: bool = False, per_hull: bool = False, free_joint: bool = True,
                         density: float = 1000.0) -> list[Path]:
    """Write ``result`` (see the module's layouts); return the files written, main file first.
    Never writes onto the input file."""
    files = plan(result, path, format, per_hull=per_hull, free_joint=free_joint, density=density)
    return write_files(files, overwrite=overwrite, protect=[result.cloud.info.get("source")])
