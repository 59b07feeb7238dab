"""glTF/GLB structure checks: every size and reference a file declares, before trimesh reads it.

trimesh trusts a glTF's numbers: a buffer view past its buffer is a bare ``AssertionError``, a
huge accessor count a reshape error, a deeply nested JSON a ``RecursionError``, and a buffer URI
naming a FIFO blocks forever. :func:`check_gltf` reads the JSON (and a GLB's chunk table) and
checks each buffer, buffer view and accessor against what the file really holds, and where each
URI points: only ``data:`` URIs and relative paths to regular files inside the glTF's own folder
are followed (never absolute paths, ``..``, ``file:`` or network URLs). Images are not checked:
the mesh loader skips materials.
"""

from __future__ import annotations

import base64
import binascii
import json
import os
import struct
from pathlib import Path
from urllib.parse import unquote

from ..errors import InputError, first_line

#: Bytes per component of each accessor componentType, and components per accessor type.
COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
TYPE_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_GLB_JSON, _GLB_BIN = 0x4E4F534A, 0x004E4942


def _int(value, what: str, p: Path) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise InputError(f"{p}: corrupted glTF: {what} is {value!r}, not a count")
    return value


def _glb_chunks(p: Path, raw: bytes) -> tuple[bytes, bytes | None]:
    """The JSON chunk and the BIN chunk (or None) of a GLB container."""
    if len(raw) < 20:
        raise InputError(f"{p}: truncated GLB: {len(raw)} bytes, shorter than its headers")
    _, version, length = struct.unpack_from("<4sII", raw, 0)
    if version != 2:
        raise InputError(f"{p}: unsupported GLB version {version} (2 is read)")
    if length > len(raw):
        raise InputError(f"{p}: truncated GLB: the header declares {length} bytes, the file has {len(raw)}")
    chunks: dict[int, bytes] = {}
    offset = 12
    while offset + 8 <= length:
        size, kind = struct.unpack_from("<II", raw, offset)
        if offset + 8 + size > length:
            raise InputError(f"{p}: truncated GLB: a chunk of {size} bytes at {offset} runs past the end")
        chunks.setdefault(kind, raw[offset + 8:offset + 8 + size])
        offset += 8 + size + (-size % 4)
    if _GLB_JSON not in chunks:
        raise InputError(f"{p}: corrupted GLB: no JSON chunk")
    return chunks[_GLB_JSON], chunks.get(_GLB_BIN)


def _parse_json(p: Path, text: bytes) -> dict:
    try:
        tree = json.loads(text.decode("utf-8-sig"))
    except RecursionError:
        raise InputError(f"{p}: corrupted glTF: its JSON is nested too deeply") from None
    except (UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"{p}: corrupted glTF: bad JSON ({first_line(exc)})") from None
    if not isinstance(tree, dict) or not isinstance(tree.get("asset"), dict):
        raise InputError(f"{p}: corrupted glTF: the JSON has no 'asset' object")
    return tree


def resource_size(p: Path, uri: str) -> int:
    """Bytes behind a buffer URI of the glTF at ``p``; :class:`InputError` naming what was blocked
    and why when it points outside the glTF's folder or at something that is not a regular file."""
    if uri.startswith("data:"):
        head, sep, payload = uri.partition(",")
        if not sep or not head.endswith(";base64"):
            raise InputError(f"{p}: corrupted glTF: a data URI that is not base64 ({uri[:40]!r}...)")
        try:
            return len(base64.b64decode(payload, validate=True))
        except (binascii.Error, ValueError):
            raise InputError(f"{p}: corrupted glTF: a data URI with invalid base64") from None
    name = unquote(uri)
    blocked = None
    if "://" in name or name.startswith(("file:", "http:", "https:")):
        blocked = "it is a URL; only files beside the glTF are read"
    elif os.path.isabs(name) or name.startswith(("/", "\\")) or (len(name) > 1 and name[1] == ":"):
        blocked = "it is an absolute path; only relative paths inside the glTF's folder are followed"
    elif ".." in Path(name.replace("\\", "/")).parts:
        blocked = "it climbs out with '..'; only paths inside the glTF's folder are followed"
    if blocked:
        raise InputError(f"{p}: glTF buffer URI {uri[:80]!r} blocked: {blocked}")
    folder = p.resolve().parent
    target = (folder / name).resolve()
    if target != folder and folder not in target.parents:
        raise InputError(f"{p}: glTF buffer URI {uri[:80]!r} blocked: it leads outside the glTF's folder "
                         "(through a link)")
    if not target.is_file():
        what = "missing" if not target.exists() else "not a regular file"
        raise InputError(f"{p}: glTF buffer {uri[:80]!r} is {what}")
    return target.stat().st_size


def check_gltf(path: str | os.PathLike, fmt: str) -> None:
    """Check a ``glb`` or ``gltf`` file's structure (see the module docstring); silent when sound."""
    p = Path(path)
    raw = p.read_bytes()
    binary = None
    if fmt == "glb":
        text, binary = _glb_chunks(p, raw)
    else:
        text = raw
    tree = _parse_json(p, text)

    def items(key: str) -> list:
        value = tree.get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            raise InputError(f"{p}: corrupted glTF: '{key}' is not a list of objects")
        return value

    buffers = []
    for i, buf in enumerate(items("buffers")):
        length = _int(buf.get("byteLength", 0), f"buffers[{i}].byteLength", p)
        uri = buf.get("uri")
        if uri is None and "extensions" in buf:  # a compression extension's placeholder
            have = length
        elif uri is None:
            have = len(binary) if (binary is not None and i == 0) else 0
        elif not isinstance(uri, str):
            raise InputError(f"{p}: corrupted glTF: buffers[{i}].uri is not a string")
        else:
            have = resource_size(p, uri)
        if have < length:
            raise InputError(f"{p}: truncated glTF: buffer {i} declares {length} bytes, holds {have}")
        buffers.append(length)
    views = []
    for i, view in enumerate(items("bufferViews")):
        b = view.get("buffer")
        if not isinstance(b, int) or not 0 <= b < len(buffers):
            raise InputError(f"{p}: corrupted glTF: bufferViews[{i}] names buffer {b!r}, which is missing")
        start = _int(view.get("byteOffset", 0), f"bufferViews[{i}].byteOffset", p)
        length = _int(view.get("byteLength", 0), f"bufferViews[{i}].byteLength", p)
        if start + length > buffers[b]:
            raise InputError(f"{p}: corrupted glTF: bufferViews[{i}] (bytes {start}..{start + length}) lies "
                             f"outside buffer {b} ({buffers[b]} bytes)")
        views.append((length, view.get("byteStride")))
    for i, acc in enumerate(items("accessors")):
        comp, kind = COMPONENT_BYTES.get(acc.get("componentType")), TYPE_COMPONENTS.get(acc.get("type"))
        if comp is None or kind is None:
            raise InputError(f"{p}: corrupted glTF: accessors[{i}] has componentType "
                             f"{acc.get('componentType')!r} and type {acc.get('type')!r}")
        count = _int(acc.get("count", 0), f"accessors[{i}].count", p)
        if "bufferView" not in acc:
            continue  # all zeros (or sparse), nothing to read
        v = acc["bufferView"]
        if not isinstance(v, int) or not 0 <= v < len(views):
            raise InputError(f"{p}: corrupted glTF: accessors[{i}] names bufferView {v!r}, which is missing")
        start = _int(acc.get("byteOffset", 0), f"accessors[{i}].byteOffset", p)
        length, stride = views[v]
        element = comp * kind
        stride = stride if isinstance(stride, int) and stride >= element else element
        need = start + (count - 1) * stride + element if count else 0
        if need > length:
            raise InputError(f"{p}: corrupted glTF: accessors[{i}] declares {count} elements ({need} bytes), "
                             f"its buffer view holds {length}")
