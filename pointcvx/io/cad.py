"""CAD parts (STEP/STP, IGES/IGS) through gmsh's OpenCASCADE kernel.

The B-rep is imported with ``gmsh.model.occ.importShapes``, its surfaces meshed (dimension 2) with
an element size relative to the part's bounding-box diagonal plus curvature refinement, and the
triangles of every body merged into one ``trimesh.Trimesh`` (:func:`tessellate_cad`). That mesh is
then sampled like any other mesh (:func:`pointcvx.io.mesh.cloud_from_mesh`) with
``modality="cad"``.

gmsh is optional (``pip install 'pointcvx[cad]'``). By default every tessellation runs in a fresh
child process (:data:`ISOLATE`): gmsh and OpenCASCADE keep process-wide state (gmsh also resets the
process's locale from the environment), a crash in their native code would otherwise take the
caller's interpreter down, and in long-lived multi-threaded workers (Ray actors) the same STEP part
can come out tessellated in two different ways from run to run, which a fresh process never does.
In the process that meshes, gmsh is a process-wide singleton: every use here holds a lock, works
in its own model, silences gmsh and OpenCASCADE (which print straight to the process's
stdout), and finalises gmsh again unless the caller had initialised it.
"""

from __future__ import annotations

import contextlib
import ctypes
import itertools
import json
import logging
import os
import signal
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..errors import InputError, MissingExtraError, MissingLibraryError, OutputError, first_line
from ..syslibs import install_hint, missing_library
from .files import atomic_path, check_readable

log = logging.getLogger(__name__)

#: Curvature refinement: elements per 2*pi radians of curvature (gmsh Mesh.MeshSizeFromCurvature).
CURVATURE_ELEMENTS = 8
#: Smallest element, as a fraction of the target size (keeps tiny fillets from exploding).
MIN_SIZE_FRACTION = 0.2
#: Sewing tolerance for loose faces, as a fraction of the bounding-box diagonal.
SEW_TOLERANCE = 1e-4
#: gmsh meshing threads. More threads mesh surfaces in parallel but make the triangulation
#: differ from run to run; one keeps the same file giving the same cloud.
THREADS = 1
#: Tessellate in a fresh child process (see the module docstring); ``tessellate_cad(isolate=)``
#: overrides it per call. In-process meshing saves starting the child.
ISOLATE = True
_CHILD_INPUT_ERROR = 3  # the child's exit status for a file it could not tessellate

_EXTENSIONS = {".step": "step", ".stp": "step", ".p21": "step", ".iges": "iges", ".igs": "iges"}
_NAMES = {"step": "STEP", "iges": "IGES"}
_LOCK = threading.RLock()
_MODEL_IDS = itertools.count()


def import_gmsh():
    """The ``gmsh`` module; :class:`MissingExtraError` naming the ``cad`` extra if it is not
    installed, :class:`MissingLibraryError` naming the system package if its wheel cannot load."""
    try:
        import gmsh
    except (ImportError, OSError) as exc:  # OSError: the wheel's shared libraries failed to load
        log.debug("gmsh unavailable: %s", exc)
        library = missing_library(exc)
        if library is not None:  # installed, but a system library it links is missing
            raise MissingLibraryError("STEP/IGES input (gmsh)", library, install_hint(library)) from None
        raise MissingExtraError("STEP/IGES input", "cad", "gmsh") from None
    return gmsh


# ------------------------------------------------------------------------------------ gmsh plumbing
def _flush_c_stdio() -> None:
    with contextlib.suppress(OSError, AttributeError, TypeError, ValueError):
        ctypes.CDLL(None).fflush(None)


@contextlib.contextmanager
def captured_output() -> Iterator[list[str]]:
    """Send the process's stdout and stderr file descriptors to a temporary file meanwhile.

    OpenCASCADE writes its reader errors straight to file descriptor 1, past Python. Yields a list
    that holds the captured text once the block exits. If the descriptors cannot be duplicated
    (no stdout at all), nothing is redirected.
    """
    captured: list[str] = []
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(AttributeError, OSError, ValueError):
            stream.flush()
    try:
        saved = (os.dup(1), os.dup(2))
    except OSError:
        yield captured
        return
    with tempfile.TemporaryFile() as sink:
        try:
            os.dup2(sink.fileno(), 1)
            os.dup2(sink.fileno(), 2)
            yield captured
        finally:
            _flush_c_stdio()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
            sink.seek(0)
            captured.append(sink.read(1 << 20).decode("utf-8", errors="replace"))


_SESSION_OPTIONS = ("General.Terminal", "General.Verbosity", "General.NumThreads",
                    "Mesh.MeshSizeMax", "Mesh.MeshSizeMin", "Mesh.MeshSizeFromCurvature",
                    "Mesh.LcIntegrationPrecision")


@contextlib.contextmanager
def gmsh_session(gmsh) -> Iterator[None]:
    """A private, quiet gmsh model; gmsh is finalised afterwards unless it was already running.

    When the caller had gmsh initialised, the options touched here are restored and the caller's
    current model is made current again.
    """
    with _LOCK:
        owned = not gmsh.isInitialized()
        if owned:
            gmsh.initialize(readConfigFiles=False, interruptible=False)
        saved: dict[str, float] = {}
        previous = None
        try:
            if not owned:
                saved = {name: gmsh.option.getNumber(name) for name in _SESSION_OPTIONS}
                with contextlib.suppress(Exception):  # gmsh raises bare Exception; none current
                    previous = gmsh.model.getCurrent()
            gmsh.option.setNumber("General.Terminal", 0)
            gmsh.option.setNumber("General.Verbosity", 1)
            gmsh.model.add(f"pointcvx-{next(_MODEL_IDS)}")
            gmsh.logger.start()
            yield
        finally:
            if owned:
                gmsh.finalize()
            else:
                with contextlib.suppress(Exception):
                    gmsh.logger.stop()
                    gmsh.model.remove()
                for name, value in saved.items():
                    gmsh.option.setNumber(name, value)
                if previous:
                    with contextlib.suppress(Exception):
                        gmsh.model.setCurrent(previous)


class _GmshFailure(Exception):
    """Internal: gmsh failed inside a session; turned into InputError once output is captured."""

    def __init__(self, what: str, detail: str):
        super().__init__(what)
        self.what, self.detail = what, detail


def _gmsh_detail(gmsh, exc: Exception) -> str:
    with contextlib.suppress(Exception):  # gmsh's API raises plain Exception
        last = gmsh.logger.getLastError()
        if last:
            return str(last)
    return first_line(exc)


def _occ_error(output: list[str]) -> str:
    """The first error line OpenCASCADE printed (e.g. the STEP parser's syntax error), or ''."""
    for line in "".join(output).splitlines():
        text = line.replace("\x1b[31;1m", "").replace("\x1b[0m", "").strip(" *")
        if "ERR" in text:
            return text.split(":", 1)[1].strip(" *") if ":" in text else text
    return ""


def cad_format(path: str | os.PathLike) -> str:
    """``step`` or ``iges`` from the extension, else from the content (:func:`sniff.detect`)."""
    p = Path(path)
    fmt = _EXTENSIONS.get(p.suffix.lower())
    if fmt is None:
        from .sniff import detect

        fmt = detect(p).format
        if fmt not in _NAMES:
            raise InputError(f"{p}: not a STEP or IGES file (detected {fmt})")
    return fmt


# ------------------------------------------------------------------------------------ tessellation
def _surface_triangles(gmsh) -> tuple[np.ndarray, np.ndarray, int, int]:
    """(v, 3) float vertices and (f, 3) int triangles of every meshed surface of the current model,
    plus how many surfaces were meshed and how many came out empty."""
    node_tags, coords, _ = gmsh.model.mesh.getNodes()
    node_tags = np.asarray(node_tags, dtype=np.int64)
    vertices = np.asarray(coords, dtype=np.float64).reshape(-1, 3)
    lookup = np.full(int(node_tags.max()) + 1 if len(node_tags) else 1, -1, dtype=np.int64)
    lookup[node_tags] = np.arange(len(node_tags))
    blocks = []
    empty = 0
    surfaces = gmsh.model.getEntities(2)
    for _, tag in sorted(surfaces):
        types, _, nodes = gmsh.model.mesh.getElements(2, tag)
        tri = [np.asarray(n, dtype=np.int64).reshape(-1, 3)
               for t, n in zip(types, nodes, strict=True) if t == 2]
        if not tri or not sum(len(t) for t in tri):
            empty += 1
            continue
        blocks.extend(tri)
    if not blocks:
        return vertices, np.zeros((0, 3), dtype=np.int64), 0, empty
    faces = lookup[np.vstack(blocks)]
    if (faces < 0).any():  # pragma: no cover - gmsh always returns the nodes of its elements
        raise InputError("gmsh returned triangles on unknown nodes")
    return vertices, faces, len(surfaces) - empty, empty


def tessellate_cad(path: str | os.PathLike, mesh_size: float = 0.01, fmt: str | None = None,
                   isolate: bool | None = None):
    """Triangulate every surface of a STEP or IGES file into one ``trimesh.Trimesh``.

    Parameters
    ----------
    path : str or PathLike
    mesh_size : float
        Target element size as a fraction of the bounding-box diagonal; curved faces are refined
        further (``CURVATURE_ELEMENTS`` per turn), down to ``MIN_SIZE_FRACTION`` of it.
    fmt : str, optional
        ``step`` or ``iges``; guessed from the extension, then the content, when omitted.
    isolate : bool, optional
        Mesh in a fresh child process (default :data:`ISOLATE`): the same file always gives the
        same mesh, the caller's process state (locale, a gmsh session of its own) is untouched,
        and a crash of gmsh or OpenCASCADE becomes an :class:`InputError`.

    Returns
    -------
    trimesh.Trimesh
        In the file's units (OpenCASCADE converts STEP lengths to millimetres). All bodies are
        merged and coincident vertices welded; ``mesh.metadata["cad"]`` holds ``bodies``,
        ``surfaces``, ``surfaces_failed``, ``triangles``, ``mesh_size`` (absolute) and ``healed``.

    Raises
    ------
    InputError
        Unreadable or corrupted file, or one without any surface.
    MissingExtraError
        gmsh is not installed.
    """
    import trimesh

    p = check_readable(path)
    if not 0.0 < mesh_size <= 1.0:
        raise InputError(f"mesh_size must be in (0, 1], got {mesh_size}")
    fmt = fmt or cad_format(p)
    if fmt not in _NAMES:
        raise InputError(f"{p}: {fmt!r} is not a CAD format (expected step or iges)")
    name = _NAMES[fmt]
    gmsh = import_gmsh()
    if ISOLATE if isolate is None else isolate:
        vertices, faces, counts, text = _tessellate_in_child(p, fmt, mesh_size)
    else:
        vertices, faces, counts, text = _tessellate_here(gmsh, p, fmt, mesh_size)
    if text.strip():
        log.debug("%s: gmsh/OpenCASCADE output:\n%s", p, text[:4000])
    if len(faces) == 0:
        raise InputError(f"{p}: meshing the {name} produced no triangles ({counts['surfaces']} surfaces)")
    if counts["surfaces_failed"]:
        log.warning("%s: %d of %d surfaces could not be meshed; the part may have holes", p,
                    counts["surfaces_failed"], counts["surfaces"])
    mesh = trimesh.Trimesh(vertices, faces, process=True)
    mesh.metadata["cad"] = {**counts, "triangles": len(mesh.faces)}
    log.debug("%s: %d bodies, %d surfaces -> %d triangles (element size %.4g)", p, counts["bodies"],
              counts["surfaces"], len(mesh.faces), counts["mesh_size"])
    return mesh


def _tessellate_here(gmsh, p: Path, fmt: str, mesh_size: float):
    """Mesh in this process: (v, 3) vertices, (f, 3) faces, counts and gmsh's printed output."""
    try:
        # The lock also covers the descriptor redirection, which is process-wide.
        with _LOCK, captured_output() as output, gmsh_session(gmsh):
            vertices, faces, counts = _tessellate_in_session(gmsh, p, fmt, mesh_size)
    except _GmshFailure as fail:
        raise InputError(f"{p}: {fail.what} ({_occ_error(output) or fail.detail})") from None
    return vertices, faces, counts, output[0] if output else ""


def _child_command(p: Path, fmt: str, mesh_size: float, out: Path) -> list[str]:
    return [sys.executable, "-m", "pointcvx.io._cad_child", str(p), fmt, repr(float(mesh_size)), str(out)]


def _tessellate_in_child(p: Path, fmt: str, mesh_size: float):
    """Mesh in a fresh ``python -m pointcvx.io._cad_child`` process (same results as
    :func:`_tessellate_here` there); the child is killed if this call is interrupted."""
    name = _NAMES[fmt]
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[2])  # import this very pointcvx in the child
    env["PYTHONPATH"] = os.pathsep.join([root, *([env["PYTHONPATH"]] if env.get("PYTHONPATH") else [])])
    with tempfile.TemporaryDirectory(prefix="pointcvx-cad-") as tmp:
        out = Path(tmp) / "mesh.npz"
        proc = subprocess.Popen(_child_command(p, fmt, mesh_size, out), stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
        try:
            while True:  # short waits, so that an interrupt (Ctrl-C, a batch timeout) gets through
                try:
                    _, err = proc.communicate(timeout=0.2)
                    break
                except subprocess.TimeoutExpired:
                    continue
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        code = proc.returncode
        if code == 0 and out.is_file():
            with np.load(out) as data:
                meta = json.loads(str(data["meta"]))
                return data["vertices"], data["faces"], meta["counts"], meta["output"]
        if code == _CHILD_INPUT_ERROR and out.with_suffix(".json").is_file():
            raise InputError(json.loads(out.with_suffix(".json").read_text())["error"])
    if code < 0:
        with contextlib.suppress(ValueError):
            code = signal.Signals(-code).name
        raise InputError(f"{p}: gmsh/OpenCASCADE crashed reading the {name} ({code})")
    last = err.decode("utf-8", errors="replace").strip().splitlines()[-1:] or [f"exit status {code}"]
    raise InputError(f"{p}: tessellating the {name} failed ({last[0]})")


def child_main(argv: list[str]) -> int:
    """``python -m pointcvx.io._cad_child PATH FMT MESH_SIZE OUT.npz``: mesh in this process and
    write the arrays (or, for a file that cannot be meshed, ``OUT.json`` with the error)."""
    src, fmt, size, out = argv
    _exit_with_parent()
    try:
        vertices, faces, counts, text = _tessellate_here(import_gmsh(), Path(src), fmt, float(size))
    except InputError as exc:
        Path(out).with_suffix(".json").write_text(json.dumps({"error": str(exc)}))
        return _CHILD_INPUT_ERROR
    meta = json.dumps({"counts": counts, "output": text[:100_000]})
    np.savez(out, vertices=vertices, faces=faces, meta=np.array(meta))
    return 0


def _exit_with_parent(interval: float = 0.5) -> None:
    """Exit this process if its parent dies (a batch worker killed mid-asset)."""
    parent = os.getppid()

    def watch() -> None:
        while True:
            threading.Event().wait(interval)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="pointcvx-cad-parent-watch", daemon=True).start()


def _tessellate_in_session(gmsh, p: Path, fmt: str, mesh_size: float):
    """Import and mesh inside :func:`gmsh_session`; (v, 3) vertices, (f, 3) faces and counts."""
    name = _NAMES[fmt]
    try:
        gmsh.model.occ.importShapes(str(p), highestDimOnly=False, format=fmt)
        gmsh.model.occ.synchronize()
    except Exception as exc:  # gmsh raises plain Exception for every failure
        raise _GmshFailure(f"corrupted or unreadable {name}", _gmsh_detail(gmsh, exc)) from None
    bodies = len(gmsh.model.getEntities(3))
    surfaces = len(gmsh.model.getEntities(2))
    if surfaces == 0:
        curves = len(gmsh.model.getEntities(1))
        raise InputError(f"{p}: the {name} holds no solid or surface ({curves} curves only)")
    box = np.asarray(gmsh.model.getBoundingBox(-1, -1), dtype=np.float64)
    diag = float(np.linalg.norm(box[3:] - box[:3]))
    if not np.isfinite(diag) or diag <= 0.0:
        raise InputError(f"{p}: the {name} geometry has no extent")
    healed = False
    if bodies == 0 and surfaces > 1:
        # Loose faces (typical of IGES) are meshed each on its own, leaving cracks along shared
        # edges; sewing them first (into solids where they close) gives a conforming mesh.
        try:
            gmsh.model.occ.healShapes(tolerance=SEW_TOLERANCE * diag)
            gmsh.model.occ.synchronize()
            healed = True
        except Exception as exc:  # gmsh raises plain Exception; the unsewn faces still mesh
            log.debug("%s: sewing the faces failed (%s)", p, _gmsh_detail(gmsh, exc))
        bodies = len(gmsh.model.getEntities(3))
        surfaces = len(gmsh.model.getEntities(2))
    size = mesh_size * diag
    gmsh.option.setNumber("General.NumThreads", THREADS)
    gmsh.option.setNumber("Mesh.MeshSizeMax", size)
    gmsh.option.setNumber("Mesh.MeshSizeMin", size * MIN_SIZE_FRACTION)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", CURVATURE_ELEMENTS)
    # Integrating the curvature size field along B-spline curves to gmsh's default 1e-9 takes
    # seconds on some parts; 1e-5 gives the same nodes within a few per mille, much faster.
    gmsh.option.setNumber("Mesh.LcIntegrationPrecision", 1e-5)
    try:
        gmsh.model.mesh.generate(2)
    except Exception as first:  # plain Exception again; retry once on healed shapes
        log.debug("%s: meshing failed (%s); healing the shapes and retrying", p, first)
        try:
            gmsh.model.mesh.clear()
            gmsh.model.occ.healShapes(tolerance=SEW_TOLERANCE * diag)
            gmsh.model.occ.synchronize()
            gmsh.model.mesh.generate(2)
            healed = True
        except Exception as exc:
            raise _GmshFailure(f"meshing the {name} failed", _gmsh_detail(gmsh, exc)) from None
    vertices, faces, _, failed = _surface_triangles(gmsh)
    counts = {"bodies": bodies, "surfaces": surfaces, "surfaces_failed": failed,
              "mesh_size": size, "healed": healed}
    return vertices, faces, counts


def load_cad_file(path: str | os.PathLike, fmt: str, opts):
    """Tessellate a STEP/IGES file and sample it into an oriented cloud (``modality="cad"``).

    ``opts`` is a :class:`pointcvx.options.LoadOptions`: ``cad_mesh_size`` sets the
    tessellation, ``n_points`` (or ``mesh_points``), ``seed`` and ``orient_rays`` the sampling.
    """
    from .mesh import cloud_from_mesh

    mesh = tessellate_cad(path, mesh_size=opts.cad_mesh_size, fmt=fmt)
    info = {"source": str(path), **mesh.metadata["cad"]}
    n_points = opts.n_points if opts.n_points is not None else opts.mesh_points
    return cloud_from_mesh(mesh, n_points=n_points, seed=opts.seed, orient_rays=opts.orient_rays,
                           modality="cad", info=info)


# ------------------------------------------------------------------------------------ sample part
def write_step_sample(path: str | os.PathLike) -> Path:
    """Write a small non-convex mechanical part as STEP: an L-bracket (60 x 40 x 50 mm) with a
    through hole in each leg, a cylindrical boss on the base and a triangular gusset, fused into
    one solid. Written atomically; returns the path."""
    gmsh = import_gmsh()
    target = Path(path)
    with atomic_path(target) as tmp, _LOCK, captured_output(), gmsh_session(gmsh):
        occ = gmsh.model.occ
        base = occ.addBox(0, 0, 0, 60, 40, 8)
        wall = occ.addBox(0, 0, 0, 8, 40, 50)
        boss = occ.addCylinder(44, 20, 8, 0, 0, 10, 7)
        gusset_face = occ.addPlaneSurface([occ.addCurveLoop([
            occ.addLine(p1, p2) for p1, p2 in _closed(
                [occ.addPoint(8, 17, 8), occ.addPoint(30, 17, 8), occ.addPoint(8, 17, 40)])
        ])])
        gusset = occ.extrude([(2, gusset_face)], 0, 6, 0)
        gusset_vol = [t for d, t in gusset if d == 3]
        body, _ = occ.fuse([(3, base)], [(3, wall), (3, boss)] + [(3, t) for t in gusset_vol])
        hole_base = occ.addCylinder(44, 20, -1, 0, 0, 20, 3.5)
        hole_wall = occ.addCylinder(-1, 10, 36, 10, 0, 0, 4)
        hole_wall2 = occ.addCylinder(-1, 30, 36, 10, 0, 0, 4)
        occ.cut(body, [(3, hole_base), (3, hole_wall), (3, hole_wall2)])
        occ.synchronize()
        try:
            gmsh.write(str(tmp))
        except Exception as exc:  # gmsh raises plain Exception
            raise OutputError(f"{target}: writing the STEP failed ({_gmsh_detail(gmsh, exc)})") from None
    return target


def _closed(tags: list[int]) -> list[tuple[int, int]]:
    return [(tags[i], tags[(i + 1) % len(tags)]) for i in range(len(tags))]
