"""A still picture of a :class:`~pointcvx.view.drawing.Drawing` as PNG: a small numpy software
rasteriser (points splatted as shaded discs, translucent hull triangles composited exactly in
depth order, hull creases and outlines drawn), one fixed 3/4 view, written with zlib.

No plotting library and no GL: it runs wherever numpy does, in a fraction of a second for the
50,000 points and few thousand triangles of a decomposition. The caption (hull count, concavity,
time, features) is drawn with Pillow's built-in font when Pillow is importable, else left off.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.files import atomic_path
from .drawing import POINT_COLOR, REMOVED_COLOR, Drawing, creases, edge_faces, face_normals, up_vector

#: Default picture size (width, height) in pixels.
SIZE = (960, 720)
BACKGROUND = (1.0, 1.0, 1.0)
HULL_ALPHA = 0.32
EDGE_ALPHA = 0.85
CAPTION_HEIGHT = 30  # pixels at the bottom kept for the caption

_AXES = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}  # horizontal axes (h1, h2) with h1 x h2 = +up


def camera(up: str, azimuth: float = -60.0, elevation: float = 22.0,
           exact: np.ndarray | None = None) -> np.ndarray:
    """(3, 3) float64 rows ``right, screen-up, forward`` of a camera looking at the origin from
    ``azimuth`` degrees around the ``up`` axis and ``elevation`` degrees above the horizon.
    ``exact``, a (3,) unit vector near ``up`` (a detected floor's normal), replaces the axis; the
    azimuth is then measured from the axis frame's first direction turned onto its plane."""
    u = up_vector(up)
    i, j = _AXES[up[-1]]
    h1, h2 = np.eye(3)[i], np.eye(3)[j]
    if up.startswith("-"):
        h1, h2 = h2, h1
    if exact is not None and float(np.dot(exact, u)) > 0.5:
        u = np.asarray(exact, dtype=np.float64) / np.linalg.norm(exact)
        h1 = h1 - np.dot(h1, u) * u
        h1 /= np.linalg.norm(h1)
        h2 = np.cross(u, h1)
    az, el = np.radians(azimuth), np.radians(elevation)
    eye = np.cos(el) * (np.cos(az) * h1 + np.sin(az) * h2) + np.sin(el) * u
    forward = -eye
    right = np.cross(forward, u)
    right /= np.linalg.norm(right)
    return np.stack([right, np.cross(right, forward), forward])


def _disc(radius: float) -> np.ndarray:
    """(k, 2) int64 pixel offsets (dx, dy) within ``radius`` of a pixel centre."""
    r = int(np.ceil(radius))
    dy, dx = np.mgrid[-r:r + 1, -r:r + 1]
    keep = dx**2 + dy**2 <= max(radius, 0.5) ** 2
    return np.stack([dx[keep], dy[keep]], axis=1)


def _splat(xy: np.ndarray, depth: np.ndarray, radius: float, width: int, height: int):
    """Fragments of discs at (n, 2) float pixel positions: (k,) pixel index, (k,) depth and
    (k,) index of the disc, only those inside the image."""
    off = _disc(radius)
    px = np.floor(xy).astype(np.int64)
    x = (px[:, None, 0] + off[None, :, 0]).ravel()
    y = (px[:, None, 1] + off[None, :, 1]).ravel()
    src = np.repeat(np.arange(len(xy)), len(off))
    ok = (x >= 0) & (x < width) & (y >= 0) & (y < height)
    return y[ok] * width + x[ok], depth[src[ok]], src[ok]


def _by_pixel_then_depth(pix: np.ndarray, depth: np.ndarray, item: np.ndarray, n_pixels: int,
                         n_items: int) -> tuple[np.ndarray, np.ndarray]:
    """Fragments sorted by pixel, then nearest first: (k,) pixel index and (k,) item.

    Pixel, quantised depth and item are packed into one int64 and sorted in place, which is
    several times faster than an argsort over two keys for the millions of fragments of a
    picture; the item comes back out of the low bits.
    """
    if not len(pix):
        return pix, item
    pix_bits, item_bits = int(n_pixels - 1).bit_length(), max(int(n_items - 1).bit_length(), 1)
    depth_bits = 62 - pix_bits - item_bits
    if depth_bits < 12:  # too many pixels and items to pack: the slow, general way
        order = np.lexsort((depth, pix))
        return pix[order], item[order]
    lo, hi = float(depth.min()), float(depth.max())
    q = ((depth - lo) * (((1 << depth_bits) - 1) / max(hi - lo, 1e-300))).astype(np.int64)
    key = (pix.astype(np.int64) << (depth_bits + item_bits)) | (q << item_bits) | item
    key.sort()
    return key >> (depth_bits + item_bits), key & ((1 << item_bits) - 1)


def _nearest(pix: np.ndarray, depth: np.ndarray, n_pixels: int) -> tuple[np.ndarray, np.ndarray]:
    """A depth buffer: each covered pixel once, (p,) pixel index and (p,) index of its nearest
    fragment."""
    spix, frag = _by_pixel_then_depth(pix, depth, np.arange(len(pix)), n_pixels, len(pix))
    first = np.r_[True, spix[1:] != spix[:-1]] if len(spix) else np.zeros(0, bool)
    return spix[first], frag[first]


def _runs(start: np.ndarray, stop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For half-open integer ranges [start, stop): (k,) index of the range of each element and
    (k,) the element itself, all ranges concatenated."""
    n = np.maximum(stop - start, 0)
    owner = np.repeat(np.arange(len(n)), n)
    return owner, np.repeat(start, n) + np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)


def _triangle_fragments(xy: np.ndarray, z: np.ndarray, width: int, height: int):
    """Rasterise (t, 3, 2) float pixel-space triangles with (t, 3) depths: (k,) pixel index,
    (k,) interpolated depth and (k,) triangle index of every covered pixel centre.

    Scanline spans, all triangles at once: each row a triangle crosses gives the run of pixel
    centres between its two edges (half-open, so triangles sharing an edge never both cover a
    pixel), and depth comes from the triangle's plane.
    """
    x0, y0 = xy[:, 0, 0], xy[:, 0, 1]
    e1, e2 = xy[:, 1] - xy[:, 0], xy[:, 2] - xy[:, 0]
    det = e1[:, 0] * e2[:, 1] - e2[:, 0] * e1[:, 1]
    live = np.flatnonzero(np.abs(det) > 1e-9)
    xy, z, e1, e2, det, x0, y0 = xy[live], z[live], e1[live], e2[live], det[live], x0[live], y0[live]
    dz1, dz2 = z[:, 1] - z[:, 0], z[:, 2] - z[:, 0]
    gx = (dz1 * e2[:, 1] - dz2 * e1[:, 1]) / det  # depth = z0 + gx (x - x0) + gy (y - y0)
    gy = (dz2 * e1[:, 0] - dz1 * e2[:, 0]) / det
    ylo = np.clip(np.ceil(xy[:, :, 1].min(axis=1) - 0.5), 0, height).astype(np.int64)
    yhi = np.clip(np.ceil(xy[:, :, 1].max(axis=1) - 0.5), 0, height).astype(np.int64)
    tri, row = _runs(ylo, yhi)
    yc = row + 0.5
    xl = np.full(len(tri), np.inf)
    xr = np.full(len(tri), -np.inf)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        p, q = xy[tri, i], xy[tri, j]
        cross = (p[:, 1] <= yc) != (q[:, 1] <= yc)  # the edge spans this row's centre
        with np.errstate(divide="ignore", invalid="ignore"):
            x = p[:, 0] + (yc - p[:, 1]) * (q[:, 0] - p[:, 0]) / (q[:, 1] - p[:, 1])
        xl = np.where(cross, np.minimum(xl, x), xl)
        xr = np.where(cross, np.maximum(xr, x), xr)
    ok = np.isfinite(xl) & np.isfinite(xr)
    cl = np.clip(np.ceil(np.where(ok, xl, 0) - 0.5), 0, width).astype(np.int64)
    cr = np.clip(np.ceil(np.where(ok, xr, 0) - 0.5), 0, width).astype(np.int64)
    span, col = _runs(cl, np.where(ok, cr, cl))
    t, r = tri[span], row[span]
    depth = z[t, 0] + gx[t] * (col + 0.5 - x0[t]) + gy[t] * (r + 0.5 - y0[t])
    return r * width + col, depth, live[t]


def _composite(image: np.ndarray, pix: np.ndarray, depth: np.ndarray, item: np.ndarray,
               colors: np.ndarray, alpha: float) -> None:
    """Blend translucent fragments (pixel, depth, index into (c, 3) ``colors``) over ``image``
    ((h*w, 3) float, in place), exactly as drawing them back to front would: a fragment with r
    fragments in front of it counts ``alpha * (1 - alpha)**r``, and what was there
    ``(1 - alpha)**k`` under k fragments."""
    if not len(pix):
        return
    pix, item = _by_pixel_then_depth(pix, depth, item, len(image), len(colors))
    starts = np.flatnonzero(np.r_[True, pix[1:] != pix[:-1]])
    counts = np.diff(np.r_[starts, len(pix)])
    rank = np.arange(len(pix)) - np.repeat(starts, counts)
    weight = alpha * (1.0 - alpha) ** rank
    covered = pix[starts]
    group = np.repeat(np.arange(len(covered)), counts)
    acc = np.stack([np.bincount(group, weights=weight * colors[item, ch], minlength=len(covered))
                    for ch in range(3)], axis=1)
    image[covered] = image[covered] * ((1.0 - alpha) ** counts)[:, None] + acc


def _light(cam: np.ndarray) -> np.ndarray:
    """(3,) unit light direction: from over the viewer's left shoulder."""
    right, up, forward = cam
    v = -forward * 0.75 + up * 0.55 - right * 0.35
    return v / np.linalg.norm(v)


def _point_radius(n: int, extent_px: np.ndarray) -> float:
    """Disc radius (output pixels) that about closes a surface of ``n`` points spread over a
    box of ``extent_px`` (2,) pixels (half of them facing the viewer)."""
    area = max(float(extent_px[0] * extent_px[1]), 1.0) * 0.6
    return float(np.clip(0.5 * np.sqrt(area / max(n / 2.0, 1.0)), 0.9, 3.2))


def render(drawing: Drawing, size: tuple[int, int] = SIZE, *, azimuth: float = -60.0,
           elevation: float = 22.0, supersample: int = 2, caption: bool = True,
           point_radius: float | None = None) -> np.ndarray:
    """(height, width, 3) uint8 picture of ``drawing`` from a fixed 3/4 view.

    Points are opaque shaded discs (their own colours, or one neutral colour), removed points
    grey and smaller, hulls translucent with one colour each and their creases and outlines
    drawn; ``supersample`` x ``supersample`` samples per pixel smooth the edges.
    """
    width, height = (int(s) for s in size)
    if width < 16 or height < 16 or width * height > 16_000_000:
        raise InputError(f"picture size must be between 16x16 and 16 megapixels, got {width}x{height}")
    ss = max(int(supersample), 1)
    cam = camera(drawing.up, azimuth, elevation, drawing.up_exact)
    light = _light(cam)
    lo, hi = drawing.bounds()
    center = (lo + hi) / 2.0

    def project(p):
        q = (np.asarray(p, dtype=np.float64) - center) @ cam.T
        return q[:, :2], q[:, 2]

    extra = [v for v, _ in drawing.hulls]
    if drawing.removed is not None:
        extra.append(drawing.removed)
    allxy, _ = project(np.concatenate([drawing.points, *extra]))
    xy_lo, xy_hi = allxy.min(axis=0), allxy.max(axis=0)
    cap = CAPTION_HEIGHT if caption else 0
    span = np.maximum(xy_hi - xy_lo, 1e-12)
    scale = min((width * 0.92) / span[0], ((height - cap) * 0.92) / span[1])
    mid = (xy_lo + xy_hi) / 2.0
    W, H = width * ss, height * ss

    def to_pixels(xy):
        return np.stack([(xy[:, 0] - mid[0]) * scale * ss + W / 2.0,
                         (H - cap * ss) / 2.0 - (xy[:, 1] - mid[1]) * scale * ss], axis=1)

    image = np.empty((W * H, 3))
    image[:] = BACKGROUND
    zbuf = np.full(W * H, np.inf)
    radius = point_radius or _point_radius(len(drawing.points), span * scale)
    # opaque points: the nearest disc fragment of each pixel wins
    layers = [(drawing.points, drawing.colors, drawing.normals, POINT_COLOR, radius)]
    if drawing.removed is not None and len(drawing.removed):
        layers.append((drawing.removed, None, None, REMOVED_COLOR, max(radius * 0.75, 0.8)))
    frags = []
    for pts, cols, nrm, default, r in layers:
        xy, z = project(pts)
        rgb = np.tile(np.asarray(default, dtype=np.float64), (len(pts), 1)) if cols is None else cols
        if nrm is not None:  # shaded by the normal, two-sided (a partial scan shows its inside)
            lit = np.abs(nrm @ light)
            shade = 0.62 + 0.38 * lit if cols is not None else 0.5 + 0.5 * lit  # own colours stay true
            rgb = rgb * shade[:, None]
        pix, depth, src = _splat(to_pixels(xy), z, r * ss, W, H)
        frags.append((pix, depth, np.asarray(rgb, dtype=np.float64)[src]))
    if frags:
        pix = np.concatenate([f[0] for f in frags])
        depth = np.concatenate([f[1] for f in frags])
        rgb = np.concatenate([f[2] for f in frags])
        covered, win = _nearest(pix, depth, W * H)
        image[covered] = rgb[win]
        zbuf[covered] = depth[win]
    # translucent hull triangles, in front of the points they cover
    colors = drawing.hull_colors
    tri_xy, tri_z, tri_rgb, edge_segments = [], [], [], []
    for k, (v, f) in enumerate(drawing.hulls):
        if not len(f):
            continue
        xy, z = project(v)
        pxy = to_pixels(xy)
        nrm = face_normals(v, f)
        shade = 0.55 + 0.45 * np.abs(nrm @ light)
        tri_xy.append(pxy[f])
        tri_z.append(z[f])
        tri_rgb.append(colors[k][None, :] * shade[:, None])
        # creases and the outline, on the side that faces the viewer
        edges, pair = edge_faces(f)
        front = (nrm @ -cam[2]) > 0
        fa = np.where(pair[:, 0] >= 0, front[pair[:, 0]], True)
        fb = np.where(pair[:, 1] >= 0, front[pair[:, 1]], True)
        show = (creases(nrm, pair) & (fa | fb)) | (fa != fb)
        e = edges[show]
        edge_segments.append((pxy[e[:, 0]], pxy[e[:, 1]], z[e[:, 0]], z[e[:, 1]], np.full(len(e), k)))
    if tri_xy:
        t_xy, t_z, t_rgb = np.concatenate(tri_xy), np.concatenate(tri_z), np.concatenate(tri_rgb)
        pix, depth, tri = _triangle_fragments(t_xy, t_z, W, H)
        seen = depth < zbuf[pix]
        _composite(image, pix[seen], depth[seen], tri[seen], t_rgb, HULL_ALPHA)
    if edge_segments:
        _draw_edges(image, zbuf, edge_segments, colors, W, H, ss, bias=4.0 * radius / scale)
    out = image.reshape(H, W, 3)
    if ss > 1:
        out = out.reshape(height, ss, width, ss, 3).mean(axis=(1, 3))
    out = np.clip(np.round(out * 255.0), 0, 255).astype(np.uint8)
    if caption:
        out = _caption(out, drawing.legend)
    return out


def _draw_edges(image, zbuf, segments, colors, W: int, H: int, ss: int, bias: float) -> None:
    """Draw hull edges (per hull: (e, 2) pixel ends a and b, (e,) depths at a and b, (e,) hull
    index) about one output pixel
    wide over ``image``, hidden only behind opaque points."""
    a, b, za, zb, hull = (np.concatenate([s[i] for s in segments]) for i in range(5))
    if not len(a):
        return
    steps = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1)).astype(np.int64), 1) + 1
    seg = np.repeat(np.arange(len(a)), steps)
    t = (np.arange(steps.sum()) - np.repeat(np.cumsum(steps) - steps, steps)) / np.repeat(steps - 1, steps)
    xy = a[seg] + (b[seg] - a[seg]) * t[:, None]
    z = za[seg] + (zb[seg] - za[seg]) * t
    pix, depth, src = _splat(xy, z, 0.5 * ss, W, H)
    # a hull's outline runs through the points on its surface: let it show through a depth
    # of a few pixels of them, not through the points of what is in front of it
    seen = depth <= zbuf[pix] + bias
    pix, depth, src = pix[seen], depth[seen], src[seen]
    if not len(pix):
        return
    p, win = _nearest(pix, depth, W * H)
    rgb = colors[hull[seg[src[win]]]] * 0.55
    image[p] = image[p] * (1.0 - EDGE_ALPHA) + rgb * EDGE_ALPHA


def caption_parts(legend: dict) -> list[str]:
    """What the caption says, most important first: the parts the legend knows."""
    parts = [legend.get("title")]
    if legend.get("hulls"):
        parts.append(f"{legend['hulls']} hulls")
    if legend.get("max_concavity") is not None:
        parts.append(f"max concavity {legend['max_concavity']:.3f}")
    # what qualifies that number comes next, so a narrow picture keeps it
    if legend.get("resolved_threshold"):
        parts.append(f"sparse: cut at {legend['resolved_threshold']:.3g}")
    if legend.get("budget"):
        parts.append(f"stopped at the {legend['budget']}-hull budget")
    if legend.get("seconds") is not None:
        parts.append(f"{legend['seconds']:.1f} s")
    if legend.get("features"):
        parts.append(f"{legend['features']} features")
    if legend.get("points_total"):
        shown, total = legend.get("points"), legend["points_total"]
        parts.append(f"{total:,} points" if shown == total else f"{shown:,} of {total:,} points")
    if legend.get("removed"):
        parts.append(f"{legend['removed']:,} removed (grey)")
    if legend.get("noise"):
        parts.append(f"{legend['noise']:,} noise")
    if legend.get("static"):
        parts.append(f"static: {legend['static']}")
    return [str(p) for p in parts if p]


def _caption(image: np.ndarray, legend: dict) -> np.ndarray:
    """``image`` with the caption written in its bottom strip, as many parts as fit (unchanged
    without Pillow)."""
    try:
        from PIL import Image, ImageDraw, ImageFont
    except ImportError:  # Pillow comes with scikit-image; without it the picture has no caption
        return image
    pic = Image.fromarray(image)
    draw = ImageDraw.Draw(pic)
    try:
        font = ImageFont.load_default(size=int(np.clip(image.shape[1] / 64, 10, 15)))
    except TypeError:  # Pillow < 10.1: the small bitmap font only
        font = ImageFont.load_default()
    parts = caption_parts(legend)
    while len(parts) > 1 and draw.textlength("  ·  ".join(parts), font=font) > image.shape[1] - 20:
        parts.pop()
    draw.text((10, image.shape[0] - CAPTION_HEIGHT + 7), "  ·  ".join(parts), fill=(70, 70, 70), font=font)
    return np.asarray(pic)


def png_bytes(image: np.ndarray) -> bytes:
    """(h, w, 3) or (h, w, 4) uint8 -> the bytes of a PNG file (8-bit RGB or RGBA, the "up"
    filter on every row, zlib)."""
    img = np.ascontiguousarray(image)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] not in (3, 4):
        raise InputError(f"a PNG needs an (h, w, 3 or 4) uint8 image, got {img.dtype} {img.shape}")
    h, w, c = img.shape
    rows = img.reshape(h, w * c)
    up = np.diff(rows, axis=0, prepend=np.zeros((1, w * c), np.uint8))  # wraps mod 256, as PNG wants
    raw = np.concatenate([np.full((h, 1), 2, np.uint8), up], axis=1).tobytes()

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    header = struct.pack(">IIBBBBB", w, h, 8, 2 if c == 3 else 6, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw, 9))
            + chunk(b"IEND", b""))


def write_png(path: str | os.PathLike, image: np.ndarray, overwrite: bool = True) -> Path:
    """Write (h, w, 3) uint8 ``image`` as a PNG, whole or not at all, with the user's umask."""
    data = png_bytes(image)
    with atomic_path(path, overwrite=overwrite) as tmp:
        tmp.write_bytes(data)
    return Path(path)
