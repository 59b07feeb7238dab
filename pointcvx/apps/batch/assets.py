"""The assets of a batch: shape files found in folders, glob patterns and manifest files, each
with a stable id and a seed derived from it."""

from __future__ import annotations

import contextlib
import glob
import hashlib
import json
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ...errors import InputError
from ..common import SHAPE_SUFFIXES

MANIFEST_SUFFIXES = frozenset({".txt", ".lst", ".list", ".json"})
"""An input file with one of these suffixes is a manifest (a list of assets), not a shape."""


@dataclass(frozen=True)
class Asset:
    """One shape of a batch: its stable ``id`` (a relative POSIX path without suffix, also the
    name of its outputs under ``OUTDIR/hulls``) and its file ``path`` (absolute)."""

    id: str
    path: str


def asset_seed(seed: int, asset_id: str) -> int:
    """The seed of asset ``asset_id`` in a batch seeded ``seed``: a 31-bit integer from SHA-256,
    the same on every machine, whatever the worker count or order."""
    digest = hashlib.sha256(f"{int(seed)}/{asset_id}".encode()).digest()
    return int.from_bytes(digest[:4], "little") & 0x7FFFFFFF


def _is_glob(text: str) -> bool:
    return any(c in text for c in "*?[")


def _glob_base(pattern: str) -> Path:
    parts = Path(pattern).parts
    fixed = []
    for part in parts:
        if _is_glob(part):
            break
        fixed.append(part)
    return Path(*fixed) if fixed else Path(".")


def _clean_id(text: str) -> str:
    """``text`` as an asset id: ``/``-joined parts of ``A-Za-z0-9._-``, none empty, ``..`` or
    hidden."""
    parts = []
    for comp in re.split(r"[\\/]+", text):
        comp = re.sub(r"[^A-Za-z0-9._-]+", "_", comp).strip()
        if comp in ("", ".", ".."):
            continue
        if comp.startswith("."):
            comp = "_" + comp[1:]
        parts.append(comp)
    return "/".join(parts) or "asset"


def _rel_id(path: Path, base: Path | None) -> str:
    """``path`` relative to ``base`` when under it, else its folder's name and its name (e.g.
    ``objects/mug``), without the suffix."""
    rel = None
    if base is not None:
        with contextlib.suppress(ValueError):
            rel = path.resolve().relative_to(base.resolve())
    if rel is None:
        rel = Path(*path.absolute().parts[-2:])
    return _clean_id(rel.with_suffix("").as_posix() if rel.suffix else rel.as_posix())


def _scan_folder(root: Path, exclude: Path | None) -> list[Path]:
    """The shape files under ``root``, sorted, outside hidden folders and ``exclude``."""
    out = []
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root)
        if any(part.startswith(".") for part in rel.parts) or p.suffix.lower() not in SHAPE_SUFFIXES:
            continue
        if exclude is not None and p.resolve().is_relative_to(exclude):
            continue
        if p.is_file():
            out.append(p)
    return out


def read_manifest_file(path: str | os.PathLike) -> list[tuple[str, str | None]]:
    """The entries of a manifest file: (path or pattern as written, id or None).

    ``.json``: a list of strings or of ``{"path": ..., "id": ...}`` objects; anything else:
    text, one entry per line, blank lines and ``#`` comments skipped.

    Raises
    ------
    InputError
        Unreadable, not text, bad JSON, or no entry.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{p}: not a manifest (not UTF-8 text)") from None
    except OSError as exc:
        raise InputError(f"{p}: cannot read the manifest ({exc.strerror or exc})") from None
    entries: list[tuple[str, str | None]] = []
    if p.suffix.lower() == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputError(f"{p}: not a JSON manifest ({exc.msg} at line {exc.lineno})") from None
        except RecursionError:
            raise InputError(f"{p}: not a JSON manifest (nested too deeply)") from None
        if not isinstance(data, list):
            raise InputError(f"{p}: a JSON manifest must be a list of paths or of "
                             "{\"path\": ..., \"id\": ...} objects")
        for i, item in enumerate(data):
            if isinstance(item, str) and item.strip():
                entries.append((item.strip(), None))
            elif isinstance(item, dict) and isinstance(item.get("path"), str) and item["path"].strip():
                ident = item.get("id")
                if ident is not None and (not isinstance(ident, str) or not ident.strip()):
                    raise InputError(f"{p}: entry {i}: 'id' must be a non-empty string")
                entries.append((item["path"].strip(), ident.strip() if ident else None))
            else:
                raise InputError(f"{p}: entry {i} is neither a path nor an object with a 'path'")
    else:
        if "\x00" in text:
            raise InputError(f"{p}: not a manifest (binary content)")
        for line in text.splitlines():
            line = line.strip()
            if line and not line.startswith("#"):
                entries.append((line, None))
    if not entries:
        raise InputError(f"{p}: the manifest lists no asset")
    return entries


def _expand(spec: str, base: Path | None, exclude: Path | None, in_manifest: bool
            ) -> list[tuple[Path, str]]:
    """(file, candidate id) pairs of one input or manifest entry."""
    p = Path(spec)
    if base is not None and not p.is_absolute():
        p = base / p
    if p.is_dir():
        files = _scan_folder(p, exclude)
        if not files and not in_manifest:
            raise InputError(f"{p}: no shape file in this folder (looked for "
                             f"{', '.join(sorted(SHAPE_SUFFIXES))})")
        return [(f, _rel_id(f, p)) for f in files]
    if p.is_file():
        if not in_manifest and p.suffix.lower() in MANIFEST_SUFFIXES:
            out = []
            for entry, ident in read_manifest_file(p):
                found = _expand(entry, p.parent, exclude, True)
                if ident is not None:
                    found = [(f, _clean_id(ident) if len(found) == 1 else f"{_clean_id(ident)}/{i}")
                             for f, i in found]
                out += found
            if not out:
                raise InputError(f"{p}: the manifest's entries match no file")
            return out
        return [(p, _rel_id(p, base) if in_manifest else _clean_id(p.stem))]
    text = str(p)
    if _is_glob(text):
        root = _glob_base(text)
        files = [Path(f) for f in sorted(glob.glob(text, recursive=True))
                 if Path(f).is_file() and Path(f).suffix.lower() in SHAPE_SUFFIXES
                 and (exclude is None or not Path(f).resolve().is_relative_to(exclude))]
        if not files and not in_manifest:
            raise InputError(f"{spec}: no shape file matches this pattern")
        return [(f, _rel_id(f, root)) for f in files]
    if in_manifest:  # a listed file that is missing: the asset fails, the batch goes on
        return [(p, _rel_id(p, base))]
    raise InputError(f"{spec}: no such file, folder or pattern")


def find_assets(inputs: Sequence[str | os.PathLike], exclude: str | os.PathLike | None = None
                ) -> list[Asset]:
    """The assets of ``inputs`` (folders, globs, files, manifest files), in order, each file once.

    Ids: a folder's files are named by their path relative to it, a glob's by their path relative
    to its fixed prefix, a manifest's entries by their ``id`` or their path relative to the
    manifest's folder (outside it: their folder's name and their name, e.g. ``objects/mug``), a
    file given directly by its stem; always without the suffix and with characters
    other than ``A-Za-z0-9._-/`` replaced by ``_``. A clash (case-insensitive) renames the later
    asset ``<id>_<ext>`` then ``<id>-2``, ``<id>-3``... Anything under ``exclude`` (the output
    folder) is left out of folders and globs. A manifest may list files that do not exist (the
    asset fails when it runs); a missing command-line input is an error.

    Raises
    ------
    InputError
        A missing input, an empty folder, a glob matching nothing, an unreadable manifest, or no
        asset at all.
    """
    if not inputs:
        raise InputError("no input given: pass folders, files, glob patterns or a manifest file")
    skip = Path(exclude).resolve() if exclude is not None else None
    assets: list[Asset] = []
    seen_paths: set[Path] = set()
    taken: set[str] = set()
    for spec in inputs:
        for path, ident in _expand(str(spec), None, skip, False):
            key = path.resolve()
            if key in seen_paths:
                continue
            seen_paths.add(key)
            unique = ident
            if unique.casefold() in taken:
                ext = path.suffix.lstrip(".").lower()
                unique = f"{ident}_{_clean_id(ext)}" if ext else ident
                i = 2
                while unique.casefold() in taken:
                    unique = f"{ident}-{i}"
                    i += 1
            taken.add(unique.casefold())
            assets.append(Asset(unique, str(path.absolute())))
    if not assets:
        raise InputError("no asset found in the inputs")
    return assets
