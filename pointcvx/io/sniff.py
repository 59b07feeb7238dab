"""Decide what a file holds from its content (magic bytes, headers), the extension only breaking ties."""

from __future__ import annotations

import gzip
import os
import re
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError, UnknownFormatError
from .files import check_readable
from .ply import read_header

SPLAT_PLY_PROPS = {"scale_0", "rot_0", "opacity"}
COMPRESSED_SPLAT_PROPS = {"packed_position", "packed_rotation", "packed_scale"}


@dataclass(frozen=True)
class Detected:
    """Result of sniffing: ``format`` (e.g. ``ply-splat``) and the ``modality`` it loads as."""

    format: str
    modality: str


def _ply(path: Path) -> Detected:
    h = read_header(path)
    vprops = set(h.properties("vertex"))
    if COMPRESSED_SPLAT_PROPS <= vprops and "chunk" in h.elements:
        return Detected("ply-splat-compressed", "splat")
    if SPLAT_PLY_PROPS <= vprops:
        return Detected("ply-splat", "splat")
    if h.count("vertex") == 0:
        raise InputError(f"{path}: the PLY has no vertices")
    if h.count("face") > 0:
        return Detected("ply-mesh", "mesh")
    return Detected("ply-points", "scan")


_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|[-+]?(?:nan|inf)"
_NUM_ROW = re.compile(rf"^\s*(?:{_NUM})(?:[\s,;]+(?:{_NUM})){{2,}}\s*$", re.IGNORECASE)


def _obj_has_faces(path: Path) -> bool:
    """Whether an OBJ file has any ``f`` line (streamed: faces often follow many vertices)."""
    pattern = re.compile(rb"(?:^|\n)[ \t]*f[ \t]")
    tail = b""
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            if pattern.search(tail + chunk):
                return True
            tail = chunk[-8:]
    return False


def _is_iges(text: str) -> bool:
    """IGES: fixed 80-column records, the section letter (S, G, ...) in column 73."""
    rows = text.splitlines()[:3]
    return bool(rows) and all(len(r.rstrip("\r")) >= 73 and r[72] in "SG" for r in rows[:2]) \
        and rows[0][72] == "S"


def _text_kind(text: str, path: Path) -> Detected | None:
    if _is_iges(text):
        return Detected("iges", "cad")
    lines = [ln.strip() for ln in text.splitlines()
             if ln.strip() and not ln.lstrip().startswith(("#", "//"))]
    if not lines:
        return None
    first = lines[0]
    if first.upper().startswith("ISO-10303-21"):
        return Detected("step", "cad")
    if re.match(r"^(C?N?OFF|NOFF|COFF)\s*(\d|$)", first):
        return Detected("off", "mesh")
    if first.lower().startswith("solid") and "facet" in text[:4096].lower():
        return Detected("stl", "mesh")
    if text.lstrip().startswith("{") and '"asset"' in text[:65536]:
        return Detected("gltf", "mesh")
    if any(k in text[:4096] for k in ("VERSION .7", "VERSION 0.7")) or first.startswith("FIELDS"):
        return Detected("pcd", "scan")
    heads = {ln.split()[0] for ln in lines[:2000] if ln.split()}
    if "v" in heads and heads <= {"v", "vn", "vt", "vp", "f", "l", "p", "mtllib", "usemtl", "s", "o", "g"}:
        return Detected("obj", "mesh") if _obj_has_faces(path) else Detected("obj-points", "scan")
    rows = lines[:50]
    if len(rows) >= 2 and re.fullmatch(r"\d+", rows[0]) and all(_NUM_ROW.match(r) for r in rows[1:]):
        return Detected("pts", "scan")
    if all(_NUM_ROW.match(r) for r in rows):
        return Detected("xyz", "scan")
    # One header line naming the columns ("X Y Z", "x,y,z,intensity"), then numeric rows.
    if len(rows) >= 2 and re.fullmatch(r"[A-Za-z_][\w]*(?:[\s,;]+[A-Za-z_][\w]*){2,}", rows[0]) \
            and all(_NUM_ROW.match(r) for r in rows[1:]):
        return Detected("xyz", "scan")
    return None


def _bad_binary_stl(p: Path, head: bytes, size: int) -> None:
    """Raise the :class:`InputError` of a binary ``.stl`` whose size disagrees with its count."""
    if size < 84:
        raise InputError(f"{p}: truncated binary STL: {size} bytes, shorter than its 84-byte header")
    (count,) = struct.unpack("<I", head[80:84])
    if count == 0 and size == 84:
        raise InputError(f"{p}: the binary STL holds no triangles")
    raise InputError(f"{p}: truncated or corrupted binary STL: its header declares {count} triangles "
                     f"({84 + 50 * count} bytes), the file has {size}")


def detect(path: str | os.PathLike) -> Detected:
    """Sniff ``path``; :class:`UnknownFormatError` when nothing matches, :class:`InputError` when
    the file is missing, empty or not a regular file, when a PLY header declares more than the
    file holds, or when a binary ``.stl`` disagrees with its own triangle count."""
    p = check_readable(path)
    size = p.stat().st_size
    with open(p, "rb") as f:
        head = f.read(65536)
    ext = p.suffix.lower()
    if head.startswith(b"ply"):
        return _ply(p)
    if head.startswith(b"glTF"):
        return Detected("glb", "mesh")
    if head.startswith(b"NGSP"):
        return Detected("spz", "splat")
    if head.startswith(b"\x1f\x8b"):
        try:
            with gzip.open(p, "rb") as g:
                inner = g.read(4)
        except (OSError, EOFError, zlib.error):
            raise InputError(f"{p}: corrupted gzip stream") from None
        if inner == b"NGSP":
            return Detected("spz", "splat")
        raise UnknownFormatError(f"{p}: a gzip file that is not an SPZ splat")
    if re.match(rb"^(?:#[^\n]*\n)*\s*(?:VERSION|FIELDS)\b", head) and b"\nDATA " in head[:8192]:
        return Detected("pcd", "scan")
    if head.startswith(b"LASF"):
        return Detected("las", "scan")
    if head.startswith(b"\x28\xb5\x2f\xfd") and ext == ".spz":
        return Detected("spz", "splat")
    # Binary STL: 80-byte header, uint32 count, 50 bytes per triangle.
    if size >= 84:
        (count,) = struct.unpack("<I", head[80:84])
        ascii_stl = head[:5].lower() == b"solid" and b"facet" in head[:1024]
        if count > 0 and size == 84 + 50 * count and not ascii_stl:
            return Detected("stl", "mesh")
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError as exc:  # a character cut by the 64 KiB read still counts as text
        text = head[:exc.start].decode("utf-8") if exc.start >= len(head) - 3 and len(head) == 65536 else None
    is_text = text is not None and "\x00" not in text
    if is_text:
        found = _text_kind(text, p)
        if found is not None:
            return found
    elif ext == ".stl":  # binary, yet its size does not match its triangle count
        _bad_binary_stl(p, head, size)
    # .splat (antimatter15): headerless 32-byte records; only the extension can tell.
    if ext == ".splat":
        if size % 32:
            raise InputError(f"{p}: truncated .splat file ({size} bytes is not a multiple of 32)")
        return Detected("splat", "splat")
    raise UnknownFormatError(
        f"{p}: unknown format; pointcvx reads meshes (OBJ, PLY, STL, OFF, GLB/GLTF), splats "
        "(INRIA/compressed PLY, SPZ, .splat), scans (PLY, PCD, XYZ/PTS, LAS) and CAD (STEP, IGES)"
    )
