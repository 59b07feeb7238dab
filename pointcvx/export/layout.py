"""Output formats and where each one's files go: suffixes, the folder a multi-file output owns,
the file a person opens."""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import OutputError

FORMATS = ("obj", "stl", "glb", "gltf", "urdf", "mjcf", "usda", "json")
SUFFIXES = {".obj": "obj", ".stl": "stl", ".glb": "glb", ".gltf": "gltf", ".urdf": "urdf",
            ".xml": "mjcf", ".mjcf": "mjcf", ".usda": "usda", ".usd": "usda", ".json": "json"}
EXTENSIONS = {"obj": ".obj", "stl": ".stl", "glb": ".glb", "gltf": ".gltf", "urdf": ".urdf",
              "mjcf": ".xml", "usda": ".usda", "json": ".json"}
FOLDER_FORMATS = ("stl", "urdf", "mjcf")


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


def folder_of(target: Path, format: str) -> Path:
    """The folder a multi-file ``format`` at ``target`` owns: ``NAME_FORMAT/`` beside a path with
    a format suffix, else ``target`` itself."""
    if target.suffix.lower() in SUFFIXES and not target.is_dir():
        return target.with_name(f"{target.stem}_{format}")
    return target


def main_file(path: str | os.PathLike, format: str, per_hull: bool = False) -> Path | None:
    """The file a person opens (the URDF, the MJCF, the single scene), or None for per-hull files."""
    target = Path(path)
    if format in ("urdf", "mjcf"):
        folder = folder_of(target, format)
        name = target.stem if folder != target else folder.name
        return folder / f"{name}{EXTENSIONS[format]}"
    if format == "stl" or (format == "obj" and (per_hull or target.is_dir() or not target.suffix)):
        return None
    if target.is_dir():
        return target / f"hulls{EXTENSIONS[format]}"
    return target


def output_folder(path: str | os.PathLike, format: str, per_hull: bool = False) -> Path | None:
    """The folder a multi-file output (per-hull OBJ or STL files, URDF, MJCF) at ``path`` owns and
    replaces whole (see the layouts), or None where ``format`` writes one file."""
    target = Path(path)
    if format in ("urdf", "mjcf") or main_file(target, format, per_hull) is None:
        return folder_of(target, format)
    return None
