"""A :class:`~pointcvx.view.drawing.Drawing` as one self-contained HTML page: the drawing as embedded
JSON and the package's own small WebGL viewer (``viewer.js``, no library, no network), with
mouse orbit, pan and zoom, toggles and a legend; also shown inline in notebooks."""

from __future__ import annotations

import base64
import html
import json
import os
from pathlib import Path

import numpy as np

from ..io.files import atomic_path
from .drawing import POINT_COLOR, REMOVED_COLOR, Drawing, feature_edges

#: Format tag and version of the embedded JSON (``<script id="pointcvx-drawing">``).
FORMAT = "pointcvx-view"
VERSION = 1


def _b64(a: np.ndarray, dtype: str) -> str:
    """An array as base64 of its little-endian bytes (``dtype`` e.g. ``"<f4"``)."""
    return base64.b64encode(np.ascontiguousarray(a, dtype=dtype).tobytes()).decode("ascii")


def drawing_json(drawing: Drawing) -> dict:
    """The JSON the viewer reads: coordinates relative to ``origin`` (the centre of the drawing's
    box, so float32 keeps full detail even far from the input's origin) as base64 arrays.

    Keys: ``format``, ``version``, ``origin`` (3,), ``radius`` (half the box diagonal),
    ``half_extent`` (3,) (half the box's sides), ``up``,
    ``points`` {``count``, ``positions`` <f4 (n, 3), ``colors`` u1 (n, 3) or null, ``normals``
    i1 (n, 3) scaled by 127 or null, ``labels`` <i4 (n,) or null}, ``removed`` {``count``,
    ``positions``} or null, ``hulls`` [{``vertices`` <f4 (v, 3), ``faces`` <u4 (f, 3),
    ``edges`` <u4 (e, 2) creases, ``color`` [r, g, b] in [0, 1]}], ``legend``, ``point_color``,
    ``removed_color``.
    """
    lo, hi = drawing.bounds()
    origin = (lo + hi) / 2.0
    radius = float(np.linalg.norm(hi - lo) / 2.0) or 1.0
    pts = drawing.points
    points = {
        "count": int(len(pts)),
        "positions": _b64(pts - origin, "<f4"),
        "colors": None if drawing.colors is None else _b64(np.round(drawing.colors * 255.0), "u1"),
        "normals": None if drawing.normals is None else _b64(np.round(drawing.normals * 127.0), "i1"),
        "labels": None if drawing.labels is None else _b64(drawing.labels, "<i4"),
    }
    removed = None
    if drawing.removed is not None and len(drawing.removed):
        removed = {"count": int(len(drawing.removed)), "positions": _b64(drawing.removed - origin, "<f4")}
    hulls = [{"vertices": _b64(v - origin, "<f4"), "faces": _b64(f, "<u4"),
              "edges": _b64(feature_edges(v, f), "<u4"), "color": [round(float(c), 4) for c in rgb]}
             for (v, f), rgb in zip(drawing.hulls, drawing.hull_colors, strict=True)]
    legend = {k: (float(v) if isinstance(v, np.floating) else int(v) if isinstance(v, np.integer) else v)
              for k, v in drawing.legend.items()}
    return {"format": FORMAT, "version": VERSION, "origin": origin.tolist(), "radius": radius,
            "half_extent": ((hi - lo) / 2.0).tolist(),
            "up": drawing.up, "points": points, "removed": removed, "hulls": hulls, "legend": legend,
            "point_color": list(POINT_COLOR), "removed_color": list(REMOVED_COLOR)}


def viewer_js() -> str:
    """The viewer's JavaScript (shipped in the package beside this module)."""
    return (Path(__file__).parent / "viewer.js").read_text(encoding="utf-8")


_STYLE = """
html, body { margin: 0; height: 100%; overflow: hidden; background: #fff;
  font: 13px/1.35 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; color: #333; }
#view { position: absolute; inset: 0; width: 100%; height: 100%; display: block; touch-action: none;
  cursor: grab; }
#view:active { cursor: grabbing; }
.panel { position: absolute; background: rgba(255, 255, 255, 0.86); border: 1px solid #ddd;
  border-radius: 6px; padding: 8px 10px; box-shadow: 0 1px 3px rgba(0, 0, 0, 0.08); }
#legend { top: 10px; left: 10px; max-width: 300px; }
#legend h1 { font-size: 14px; margin: 0 0 4px; word-break: break-all; }
#stats td { padding: 0 10px 0 0; white-space: nowrap; }
#stats td:first-child { color: #666; }
#swatches { margin-top: 6px; max-height: 120px; overflow-y: auto; line-height: 0; }
.swatch { display: inline-block; width: 14px; height: 14px; margin: 0 3px 3px 0; border-radius: 3px;
  cursor: pointer; box-shadow: inset 0 0 0 1px rgba(0, 0, 0, 0.25); }
.swatch.off { opacity: 0.15; }
#controls { top: 10px; right: 10px; }
#controls label { display: block; white-space: nowrap; user-select: none; }
#controls input[type=range] { width: 110px; vertical-align: middle; }
#controls button { margin-top: 4px; font: inherit; }
#hint { bottom: 8px; left: 10px; color: #777; font-size: 12px; padding: 3px 8px; }
#nogl { display: none; top: 45%; left: 50%; transform: translate(-50%, -50%); max-width: 420px; }
"""

_BODY = """
<canvas id="view"></canvas>
<div id="legend" class="panel"><h1 id="title"></h1><table id="stats"></table><div id="swatches"></div></div>
<div id="controls" class="panel">
  <label><input type="checkbox" id="show-points"> points <small>(P)</small></label>
  <label id="row-removed"><input type="checkbox" id="show-removed"> removed, grey <small>(G)</small></label>
  <label id="row-by-hull"><input type="checkbox" id="by-hull"> points by hull <small>(C)</small></label>
  <label><input type="checkbox" id="show-hulls"> hulls <small>(H)</small></label>
  <label><input type="checkbox" id="show-edges"> hull edges <small>(E)</small></label>
  <label>point size <input type="range" id="point-size" min="0.5" max="8" step="0.25"></label>
  <label>hull opacity <input type="range" id="hull-alpha" min="0" max="1" step="0.02"></label>
  <button id="reset" type="button">reset view (R)</button>
</div>
<div id="hint" class="panel">drag: orbit &middot; right-drag or shift-drag: pan &middot; wheel: zoom
  &middot; double-click: reset &middot; click a colour: hide that hull</div>
<div id="nogl" class="panel">This browser gives the page no WebGL, so the 3D view cannot be drawn.
  The legend still lists what was decomposed; pointcvx writes a PNG picture beside this page.</div>
"""


def html_page(drawing: Drawing) -> str:
    """The whole page as text: everything inline, nothing fetched."""
    data = json.dumps(drawing_json(drawing), separators=(",", ":"), allow_nan=False)
    data = data.replace("<", "\\u003c")  # no "</script>" can end the data early
    js = viewer_js()
    title = html.escape(f"{drawing.legend.get('title') or 'pointcvx'} - pointcvx view")
    return ("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
            f"<title>{title}</title>\n<style>{_STYLE}</style>\n</head>\n<body>{_BODY}"
            f"<script type=\"application/json\" id=\"pointcvx-drawing\">{data}</script>\n"
            f"<script>\n{js}</script>\n</body>\n</html>\n")


def write_page(path: str | os.PathLike, drawing: Drawing, overwrite: bool = True) -> Path:
    """Write the page of ``drawing`` to ``path``, whole or not at all, with the user's umask."""
    text = html_page(drawing)
    with atomic_path(path, overwrite=overwrite) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


class Page:
    """A page for a notebook: shown inline (in an iframe, so several on one notebook never
    share ids or styles), ``html`` the whole page, :meth:`save` writes it."""

    def __init__(self, drawing: Drawing, height: int = 520):
        self.drawing = drawing
        self.height = int(height)
        self.html = html_page(drawing)

    def _repr_html_(self) -> str:
        doc = html.escape(self.html, quote=True)
        return (f'<iframe srcdoc="{doc}" style="width: 100%; height: {self.height}px; border: 0" '
                'sandbox="allow-scripts"></iframe>')

    def save(self, path: str | os.PathLike, overwrite: bool = True) -> Path:
        with atomic_path(path, overwrite=overwrite) as tmp:
            tmp.write_text(self.html, encoding="utf-8")
        return Path(path)
