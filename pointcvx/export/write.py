"""Writing an export: one file through a temporary renamed onto it, or a multi-file output as a
folder written whole or not at all (:mod:`pointcvx.io.outputs`)."""

from __future__ import annotations

import logging
import os
from pathlib import Path

from ..errors import OutputError
from ..io.files import atomic_path
from ..io.outputs import check_ancestors, make_folders, remove_made, write_folder

log = logging.getLogger(__name__)

def write_files(files: dict[Path, str | bytes], overwrite: bool = False,
                protect: list[str | os.PathLike] = (), folder: str | os.PathLike | None = None,
                about: dict | None = None) -> list[Path]:
    """Write every file or none: (path -> text, written as UTF-8, or bytes); return the paths.

    ``folder``: the files are the multi-file output this folder holds, written whole or not at all
    and replacing a previous output whole with ``overwrite``
    (:func:`pointcvx.io.outputs.write_folder`; ``about``: more entries for its manifest); default:
    the folder holding them all when there are several. One file (no ``folder``): written through
    a temporary renamed onto it. Missing parent folders are made. Refuses
    (:class:`OutputError`) before writing anything what would overwrite a ``protect`` path (the
    input), an existing output without ``overwrite``, or files pointcvx did not write.
    """
    paths = list(files)
    if folder is None and len(paths) > 1:
        folder = os.path.commonpath([os.path.abspath(Path(p).parent) for p in paths])
    if folder is not None:
        root = Path(os.path.abspath(folder))
        inside = {}
        for p, data in files.items():
            rel = os.path.relpath(os.path.abspath(p), root)
            if rel.startswith(".."):
                raise OutputError(f"{p}: outside the output folder {folder}")
            inside[rel] = data
        write_folder(root, inside, overwrite=overwrite, protect=protect, about=about)
        log.debug("wrote %d files into %s", len(paths), root)
        return paths
    if not paths:
        return []
    (path,) = map(Path, paths)
    data = files[paths[0]]
    guarded = [Path(p) for p in protect if p is not None and Path(p).exists()]
    if path.exists() and any(os.path.samefile(path, g) for g in guarded):
        raise OutputError(f"{path}: refusing to overwrite the input file")
    if path.is_dir():
        raise OutputError(f"{path}: is a folder")
    if path.exists() and not overwrite:
        raise OutputError(f"{path}: exists; pass overwrite to replace it")
    check_ancestors(path.parents, path.parent)
    made = make_folders(path.parent)
    try:
        with atomic_path(path, overwrite=True) as tmp:
            if isinstance(data, bytes):
                tmp.write_bytes(data)
            else:
                tmp.write_text(data, encoding="utf-8")
    except BaseException as exc:
        remove_made(made)
        if isinstance(exc, OSError) and not isinstance(exc, OutputError):
            raise OutputError(f"{path}: cannot write ({exc.strerror or exc}); nothing was written") from None
        raise
    log.debug("wrote %s", path)
    return paths
