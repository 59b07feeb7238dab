"""Whole-or-nothing outputs: written hidden beside their place, then renamed into it in one step.

What a killed run leaves behind is cleaned up by the next run into the same folder.

A multi-file output (one file per hull, a URDF or an MJCF with its meshes) is a folder that
pointcvx owns alone, marked by the manifest :data:`MANIFEST` it writes into it: the files it
wrote. :func:`write_folder` writes one:

1. leftovers of killed runs in the parent folder are settled (:func:`clean_leftovers`): hidden
   ``.pointcvx-KIND.PID.HOST.*`` entries of this host whose process is gone are removed, except a
   previous output set aside by a run killed while replacing it, which is put back;
2. the target is checked (:func:`check_folder`): it may be absent or an empty folder, or, with
   ``overwrite``, a pointcvx output holding nothing but the files its manifest lists. Anything else
   is refused (:class:`~pointcvx.errors.OutputError`): there pointcvx cannot tell its files from
   the user's, and it deletes nothing it did not write;
3. every file, then the manifest, is written into a hidden folder ``.pointcvx-new.*`` beside the
   target, the target is checked again, and
4. the new folder takes the target's place in one step (:func:`replace_folder`): a rename where
   there was nothing (or an empty folder); over a previous output, an atomic swap of the two
   (Linux ``renameat2(RENAME_EXCHANGE)``), after which the old output, now under the hidden name,
   is deleted. Where the kernel or file system cannot swap, the old output is renamed aside
   (``.pointcvx-old.*``), the new one renamed in, the old one deleted; a kill between those two
   renames leaves no output visible, and the next run puts the old one back.

A reader therefore sees the previous output whole, the new one whole, or (only in that fallback,
only after a kill) none: never a mix, never a half-written file. Single files take the same path
through :func:`~pointcvx.io.files.atomic_path` (a ``.pointcvx-file.*`` temporary and
``os.replace``). Everything gets the user's umask (plain ``open`` and ``mkdir``). Nothing is
fsynced: this guards against killed processes, not against a power cut.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import re
import secrets
import shutil
import socket
import sys
import time
from pathlib import Path, PurePosixPath

from ..errors import OutputError
from ..version import __version__

log = logging.getLogger(__name__)

MANIFEST = ".pointcvx.json"
"""The manifest of a multi-file output, written last into its folder: ``{"pointcvx": version,
"name": the folder's name, "format", "main", "files": [paths relative to the folder]}``."""
TEMP_PREFIX = ".pointcvx-"
"""How every temporary entry pointcvx writes beside an output starts (then ``KIND.PID.HOST.``)."""
RESCAN_SECONDS = 60.0
"""A folder's leftovers are looked for at most this often per process (a batch writes thousands of
files into one folder; leftovers only come from runs killed before)."""

_TEMP = re.compile(r"^\.pointcvx-(new|old|file)\.(\d{1,10})\.([A-Za-z0-9-]*)\.")
_scanned: dict[str, float] = {}


# ------------------------------------------------------------------------------ temporary names
def host_tag() -> str:
    """This machine's name as it appears in temporary names (letters, digits, ``-``; at most 32)."""
    return re.sub(r"[^A-Za-z0-9-]", "", socket.gethostname())[:32]


def short_name(name: str, size: int = 48) -> str:
    """``name`` cut to about ``size`` bytes, its suffix kept (some writers go by the suffix)."""
    if len(name.encode()) <= size:
        return name
    stem, dot, suffix = name.rpartition(".")
    suffix = f".{suffix}"[:16] if dot and stem else ""
    return name.encode()[: size - len(suffix.encode())].decode("utf-8", "ignore") + suffix


def temp_name(kind: str, name: str, pid: int | None = None) -> str:
    """A fresh hidden name for a temporary ``kind`` (new, old, file) of the output ``name``:
    ``.pointcvx-KIND.PID.HOST.TOKEN.NAME`` (``NAME`` cut short), the process ``pid`` (default
    this one) telling the next run whether it is a leftover."""
    pid = os.getpid() if pid is None else pid
    return f"{TEMP_PREFIX}{kind}.{pid}.{host_tag()}.{secrets.token_hex(4)}.{short_name(name)}"


def _started(pid: int) -> tuple[str, float] | None:
    """(state letter, start time in seconds since the epoch) of process ``pid`` from /proc."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            fields = f.read().rsplit(b")", 1)[1].split()
        with open("/proc/stat", "rb") as f:
            boot = next(float(line.split()[1]) for line in f if line.startswith(b"btime"))
        return fields[0].decode(), boot + int(fields[19]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError, StopIteration):
        return None


def process_alive(pid: int, since: float | None = None) -> bool:
    """Whether process ``pid`` of this machine is still running (a zombie is not); ``since``: the
    time its temporary was last touched, so a process started after that is another one that got
    the same pid."""
    if pid == os.getpid() or os.name == "nt":  # (on Windows os.kill would end the process)
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # another user's process: alive
    except (OSError, OverflowError, ValueError):
        return False
    info = _started(pid) if sys.platform.startswith("linux") else None
    if info is None:
        return True
    state, started = info
    # a minute's slack: the clock may have been set forward since the temporary was touched
    return state != "Z" and not (since is not None and started > since + 60.0)


# ------------------------------------------------------------------------------ leftovers
def _settle(path: Path, kind: str) -> None:
    """Deal with the leftover ``path`` of a dead run: put back a set-aside output whose place is
    free, delete anything else."""
    if kind == "old":
        name = None
        with contextlib.suppress(OSError, ValueError, AttributeError):
            name = json.loads((path / MANIFEST).read_text(encoding="utf-8")).get("name")
        if not isinstance(name, str) or name in ("", ".", "..") or "/" in name or "\0" in name:
            name = path.name.split(".", 5)[-1]  # the (maybe shortened) name in the temporary's
        home = path.parent / name
        if not os.path.lexists(home):
            with contextlib.suppress(OSError):
                os.rename(path, home)
                log.warning("%s: put back the previous output a killed run had set aside", home)
                return
        elif not home.is_dir():
            return  # something else took the place: keep the old output hidden, never delete it
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(OSError):
            path.unlink()
    log.debug("%s: removed a leftover of a killed run", path)


def clean_leftovers(parent: str | os.PathLike, force: bool = False) -> None:
    """Settle the temporaries that runs killed on this machine left in the folder ``parent``
    (see the module's steps); at most every :data:`RESCAN_SECONDS` per folder unless ``force``."""
    key = os.path.abspath(parent)
    now = time.monotonic()
    if not force and now - _scanned.get(key, -RESCAN_SECONDS) < RESCAN_SECONDS:
        return
    _scanned[key] = now
    host = host_tag()
    try:
        entries = [e for e in os.scandir(key) if e.name.startswith(TEMP_PREFIX)]
    except OSError:
        return
    for e in entries:
        m = _TEMP.match(e.name)
        if m is None or m[3] != host:
            continue
        try:
            touched = e.stat(follow_symlinks=False).st_mtime
        except OSError:
            continue
        if not process_alive(int(m[2]), since=touched):
            _settle(Path(e.path), m[1])


# ------------------------------------------------------------------------------ checks
def read_manifest(folder: Path) -> list[str] | None:
    """The files the manifest of ``folder`` lists, or None without one; :class:`OutputError` if it
    is unreadable (then nobody can tell which files are pointcvx's)."""
    path = folder / MANIFEST
    if not path.is_file():
        return None
    try:
        files = json.loads(path.read_text(encoding="utf-8"))["files"]
        if not all(isinstance(f, str) for f in files):
            raise TypeError
    except (OSError, ValueError, KeyError, TypeError):
        raise OutputError(f"{path}: unreadable, so which files are pointcvx's is unknown; "
                          "remove the folder to replace it") from None
    return list(files)


def foreign_files(folder: Path, listed: list[str]) -> list[str]:
    """What ``folder`` holds beyond the ``listed`` files and the manifest (paths relative to it;
    folders end with ``/``)."""
    allowed = {MANIFEST, *listed}
    parents = {p.as_posix() for f in listed for p in PurePosixPath(f).parents}
    out = []
    for root, dirs, files in os.walk(folder):
        rel = Path(root).relative_to(folder)
        for d in dirs:
            name = (rel / d).as_posix()
            if name not in parents or (Path(root) / d).is_symlink():
                out.append(name + "/")
        dirs[:] = [d for d in dirs if (rel / d).as_posix() in parents]
        out += [(rel / f).as_posix() for f in files if (rel / f).as_posix() not in allowed]
    return sorted(out)


def _more(items: list[str]) -> str:
    return f"{items[0]} and {len(items) - 1} more" if len(items) > 1 else items[0]


def check_folder(folder: str | os.PathLike, overwrite: bool = False,
                 protect: list[str | os.PathLike] = (), flag: str = "overwrite") -> str:
    """Whether a multi-file output may be written at ``folder``: ``"absent"``, ``"empty"`` or
    ``"ours"`` (a pointcvx output, replaced with ``overwrite``), else :class:`OutputError` in one
    line: not a folder, a folder of files pointcvx did not write, a pointcvx output without
    ``overwrite`` (the message names ``flag``) or with files added since, one holding a
    ``protect`` path (the input)."""
    shown, target = Path(folder), Path(os.path.abspath(folder))  # messages name the path as given
    if target.parent == target:
        raise OutputError(f"{shown}: cannot be an output folder")
    check_ancestors(target.parents, shown)
    if not os.path.lexists(target):
        return "absent"
    if not target.is_dir():
        raise OutputError(f"{shown}: exists and is not a folder")
    try:
        entries = sorted(os.listdir(target))
    except OSError as exc:
        raise OutputError(f"{shown}: cannot read the folder ({exc.strerror})") from None
    if not entries:
        return "empty"
    listed = read_manifest(target)
    if listed is None:
        raise OutputError(f"{shown}: holds files pointcvx did not write ({_more(entries)}); a "
                          "multi-file output needs a folder of its own: name a new or empty one")
    if not overwrite:
        raise OutputError(f"{shown}: exists (a pointcvx output); pass {flag} to replace it")
    foreign = foreign_files(target, listed)
    if foreign:
        them = "them" if len(foreign) > 1 else "it"
        raise OutputError(f"{shown}: holds {_more(foreign)}, which pointcvx did not write; move "
                          f"{them} away to replace this output")
    for p in protect:
        if p is not None and Path(os.path.abspath(p)).is_relative_to(target):
            raise OutputError(f"{shown}: holds the input file {p}; refusing to replace it")
    return "ours"


# ------------------------------------------------------------------------------ writing
def _swap(a: Path, b: Path) -> bool:
    """Exchange the paths ``a`` and ``b`` in one step (Linux ``renameat2``); False where the
    kernel, the C library or the file system cannot."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    at_fdcwd, rename_exchange = -100, 2
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def replace_folder(new: str | os.PathLike, target: str | os.PathLike, exchange: bool = True) -> None:
    """Put the folder ``new`` in ``target``'s place in one step and delete what was there, which
    must be nothing, an empty folder or an output :func:`check_folder` accepted. ``exchange``:
    swap the two atomically where possible; False (or where the system cannot) renames the old
    one aside first (see the module's step 4)."""
    new, target = Path(new), Path(target)
    try:
        os.rename(new, target)  # nothing there, or an empty folder (which rename replaces)
        return
    except OSError as exc:
        if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST):
            raise
    if exchange and _swap(new, target):
        shutil.rmtree(new, ignore_errors=True)  # the previous output, now under the hidden name
        return
    aside = target.parent / temp_name("old", target.name)
    os.rename(target, aside)
    try:
        os.rename(new, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.rename(aside, target)
        raise
    shutil.rmtree(aside, ignore_errors=True)


def check_ancestors(ancestors, shown: str | os.PathLike) -> None:
    """:class:`OutputError` naming ``shown`` when the nearest existing path among ``ancestors``
    (a path's ``.parents``, nearest first) is not a folder: the output's folder cannot be made."""
    for above in ancestors:
        if os.path.lexists(above):
            if not above.is_dir():
                raise OutputError(f"{shown}: cannot create the output folder ({above} is not a folder)")
            return


def make_folders(folder: Path) -> list[Path]:
    """Make ``folder`` and its missing parents (the user's umask); the ones made, deepest first."""
    missing = [p for p in (folder, *folder.parents) if not os.path.lexists(p)]
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{folder}: cannot create the output folder ({exc.strerror})") from None
    return missing


def remove_made(folders: list[Path]) -> None:
    """Remove the ``folders`` a failed write made, deepest first, where they are still empty."""
    for f in sorted(folders, key=lambda p: len(p.parts), reverse=True):
        with contextlib.suppress(OSError):
            f.rmdir()


def write_folder(folder: str | os.PathLike, files: dict[str, str | bytes], overwrite: bool = False,
                 protect: list[str | os.PathLike] = (), about: dict | None = None) -> Path:
    """Write the output folder ``folder`` whole or not at all (the module's steps); return it.

    ``files``: path relative to the folder -> text (written as UTF-8) or bytes; ``about``: more
    entries for the manifest (format, main file). Missing parent folders are made (and removed
    again on failure). Raises :class:`OutputError` for the refusals of :func:`check_folder` and
    for a failed write, after which nothing is left behind.
    """
    target = Path(os.path.abspath(folder))
    if target.is_symlink():
        target = Path(os.path.realpath(target))  # the folder the link names
    names = {}
    for rel, data in files.items():
        p = PurePosixPath(Path(rel).as_posix())
        if p.is_absolute() or ".." in p.parts or not p.parts or p.as_posix() == MANIFEST:
            raise OutputError(f"{rel}: not a file name inside the output folder")
        names[p.as_posix()] = data
    check_folder(folder, overwrite, protect)
    made = make_folders(target.parent)
    tmp = None
    try:
        clean_leftovers(target.parent)
        check_folder(folder, overwrite, protect)
        tmp = target.parent / temp_name("new", target.name)
        os.mkdir(tmp)
        for rel, data in names.items():
            path = tmp / rel
            if "/" in rel:
                path.parent.mkdir(parents=True, exist_ok=True)
            if isinstance(data, bytes):
                path.write_bytes(data)
            else:
                path.write_text(data, encoding="utf-8")
        manifest = {"pointcvx": __version__, "name": target.name, **(about or {}), "files": list(names)}
        (tmp / MANIFEST).write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
        check_folder(folder, overwrite, protect)  # again: the user may have been busy meanwhile
        replace_folder(tmp, target)
    except BaseException as exc:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        remove_made(made)
        if isinstance(exc, OSError) and not isinstance(exc, OutputError):
            why = exc.strerror or exc
            raise OutputError(f"{folder}: cannot write ({why}); nothing was written") from None
        raise
    log.debug("wrote %s: %d files", target, len(names))
    return target
