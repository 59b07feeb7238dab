"""Small file helpers: readable inputs, writable outputs, atomic writes with the user's umask."""

from __future__ import annotations

import contextlib
import errno
import os
import stat
from collections.abc import Iterator
from pathlib import Path

from ..errors import InputError, OutputError

_SPECIAL = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
            (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def check_readable(path: str | os.PathLike) -> Path:
    """The path as a :class:`Path`, or :class:`InputError` if it is missing, a folder, not a
    regular file (a FIFO or a device, which could block or never end) or empty."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise InputError(f"{p}: a loop of symbolic links") from None
        if isinstance(exc, FileNotFoundError) or exc.errno == errno.ENOTDIR:
            raise InputError(f"{p}: no such file") from None
        raise InputError(f"{p}: cannot read ({exc.strerror})") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(f"{p}: is a directory, not a file")
    if not stat.S_ISREG(st.st_mode):
        kind = next((name for test, name in _SPECIAL if test(st.st_mode)), "a special file")
        raise InputError(f"{p}: not a regular file but {kind}; pass a file")
    if st.st_size == 0:
        raise InputError(f"{p}: the file is empty")
    if not os.access(p, os.R_OK):
        raise InputError(f"{p}: permission denied")
    return p


def check_writable(output: str | os.PathLike, inputs: list[str | os.PathLike] = (),
                   overwrite: bool = False) -> Path:
    """``output`` as a :class:`Path`; :class:`OutputError` if it is one of ``inputs``, exists
    without ``overwrite``, or its folder does not exist."""
    out = Path(output)
    for src in inputs:
        if out.exists() and Path(src).exists() and os.path.samefile(out, src):
            raise OutputError(f"{out}: refusing to overwrite the input file")
    if out.exists() and not overwrite:
        raise OutputError(f"{out}: exists; pass --overwrite to replace it")
    if not out.parent.exists() and str(out.parent):
        raise OutputError(f"{out.parent}: output directory does not exist")
    return out


def current_umask() -> int:
    """The process's umask (read from /proc where it can be, which changes nothing)."""
    with contextlib.suppress(OSError, ValueError):
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    mask = os.umask(0o022)  # elsewhere: set and restore (process-wide, for an instant)
    os.umask(mask)
    return mask


def user_file_mode() -> int:
    """The mode ``open()`` gives a new file: 0o666 less the umask (mkstemp's are 0o600)."""
    return 0o666 & ~current_umask()


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, overwrite: bool = True) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; move it onto ``path`` only if the block succeeds.

    A failure leaves any existing file untouched and no partial output behind. With
    ``overwrite=False`` an existing ``path`` raises :class:`OutputError` before anything runs.
    The file gets the mode a plain ``open()`` would give it (the user's umask), not mkstemp's 0600.
    Its hidden name carries this process's id, so the next write into the folder removes what a
    killed run left (:func:`~pointcvx.io.outputs.clean_leftovers`).
    """
    from .outputs import clean_leftovers, temp_name

    target = Path(path)
    if target.exists() and not overwrite:
        raise OutputError(f"{target}: exists (pass overwrite to replace it)")
    parent = target.parent if str(target.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(f"{parent}: output directory does not exist")
    clean_leftovers(parent)
    for _ in range(100):
        tmp_path = parent / temp_name("file", target.name)
        try:  # 0o666 less the umask, as open() makes it
            os.close(os.open(tmp_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            break
        except FileExistsError:
            continue
    else:
        raise OutputError(f"{parent}: cannot make a temporary file beside {target.name}")
    try:
        yield tmp_path
        os.replace(tmp_path, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp_path.unlink()
        raise


def file_digest(path: str | os.PathLike, length: int = 16) -> str:
    """The first ``length`` hex digits of the SHA-256 of a file's content."""
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()[:length]
