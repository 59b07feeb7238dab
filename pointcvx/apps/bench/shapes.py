"""Finding a benchmark's shapes: the shape files of each dataset, each with a unique name
(:class:`ShapeEntry`)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ...errors import InputError
from ..common import SHAPE_SUFFIXES


@dataclass
class ShapeEntry:
    """One shape of a dataset: its file, the dataset's name, its category (parent folder name)
    and a name unique within the benchmark (used for hull files)."""

    path: str
    dataset: str
    category: str
    shape: str


def find_shapes(datasets: Sequence[str | os.PathLike], limit: int | None = None,
                exclude: str | os.PathLike | None = None) -> list[ShapeEntry]:
    """The shape files of ``datasets`` (folders, searched recursively in sorted order, or files),
    at most ``limit`` per dataset. Hidden files and folders, and anything under ``exclude`` (the
    output folder), are left out.

    Raises
    ------
    InputError
        A dataset path that does not exist, or a folder without any shape file.
    """
    if not datasets:
        raise InputError("no dataset given: pass a folder of shapes or a shape file")
    if limit is not None and limit < 1:
        raise InputError(f"limit must be at least 1, got {limit}")
    entries: list[ShapeEntry] = []
    seen: set[Path] = set()
    names: set[str] = set()
    for d in datasets:
        root = Path(d)
        if not root.exists():
            raise InputError(f"{root}: no such file or folder")
        if root.is_dir():
            name = root.resolve().name
            skip = Path(exclude).resolve() if exclude is not None else None
            files = sorted(p for p in root.rglob("*") if p.is_file() and _is_shape_file(p, root)
                           and (skip is None or not p.resolve().is_relative_to(skip)))
            if not files:
                raise InputError(f"{root}: no shape file in this folder (looked for "
                                 f"{', '.join(sorted(SHAPE_SUFFIXES))})")
        else:
            name = root.resolve().parent.name
            files = [root]
        taken = 0
        for p in files:
            if p.resolve() in seen:
                continue
            if limit is not None and taken >= limit:
                break
            seen.add(p.resolve())
            category = p.resolve().parent.name
            shape = _unique_name(p, category, name, names)
            names.add(shape)
            entries.append(ShapeEntry(str(p), name, category, shape))
            taken += 1
    return entries


def _is_shape_file(p: Path, root: Path) -> bool:
    """Whether ``p`` (under folder ``root``) is a shape: a known suffix, no hidden part."""
    hidden = any(part.startswith(".") for part in p.relative_to(root).parts)
    return not hidden and p.suffix.lower() in SHAPE_SUFFIXES


def _unique_name(p: Path, category: str, dataset: str, taken: set[str]) -> str:
    """The first of the file's stem, then longer names (category, suffix, dataset), then
    ``stem-2``, ``stem-3``... not in ``taken``."""
    for name in (p.stem, f"{category}-{p.stem}", f"{category}-{p.name}", f"{dataset}-{category}-{p.name}"):
        if name not in taken:
            return name
    i = 2
    while f"{p.stem}-{i}" in taken:
        i += 1
    return f"{p.stem}-{i}"
