"""A look at the result: a decomposition (or any cloud, or bare arrays) as a self-contained
offline HTML page with the package's own WebGL viewer, and as a PNG from a numpy rasteriser.

    import pointcvx.view
    pointcvx.view.write_html("mug.html", result)      # points, translucent hulls, legend
    pointcvx.view.render_png("mug.png", result)       # the same from a fixed 3/4 view
    pointcvx.view.show(result)                        # inline in a notebook

Everything is in the input's units. What a picture holds is a :class:`Drawing`
(:mod:`pointcvx.view.drawing`); :mod:`pointcvx.view.html` and :mod:`pointcvx.view.png` draw it.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import OutputError
from ..io.files import atomic_path
from .drawing import MAX_POINTS, UP_AXES, Drawing, drawing, drawing_from, hull_colors
from .html import Page, drawing_json, html_page, write_page
from .png import SIZE, render, write_png

__all__ = [
    "MAX_POINTS",
    "Page",
    "SIZE",
    "Drawing",
    "UP_AXES",
    "html_page",
    "hull_colors",
    "render",
    "render_png",
    "drawing",
    "drawing_from",
    "drawing_json",
    "show",
    "write_html",
    "write_png",
    "write_view",
]


def _drawing(x, hulls, removed, options) -> Drawing:
    if isinstance(x, Drawing):
        if hulls is not None or removed is not None or options:
            raise TypeError("a Drawing is drawn as it is: give hulls, removed and options to drawing()")
        return x
    return drawing_from(x, hulls, removed, **options)


def write_html(path: str | os.PathLike, x, hulls=None, removed=None, *, overwrite: bool = True,
               **options) -> Path:
    """Write the viewer page of ``x`` to ``path``.

    ``x``: a :class:`~pointcvx.result.Decomposition`, an :class:`~pointcvx.cloud.OrientedCloud`,
    an (n, 3) array of points or a :class:`Drawing`; ``hulls`` (any form :func:`drawing.as_hulls`
    takes) and ``removed`` ((m, 3) points drawn grey) replace or add to what ``x`` holds;
    ``options``: :func:`drawing_from`'s ``colors``, ``legend``, ``up``, ``max_points``, ``seed``.
    """
    return write_page(path, _drawing(x, hulls, removed, options), overwrite=overwrite)


def render_png(path: str | os.PathLike, x, hulls=None, removed=None, *, size: tuple[int, int] = SIZE,
               overwrite: bool = True, **options) -> Path:
    """Render ``x`` (as for :func:`write_html`) from a fixed 3/4 view to a PNG of ``size``
    (width, height) pixels at ``path``."""
    return write_png(path, render(_drawing(x, hulls, removed, options), size), overwrite=overwrite)


def show(x, hulls=None, removed=None, *, height: int = 520, **options) -> Page:
    """The viewer of ``x`` (as for :func:`write_html`) for a notebook: the last expression of a
    cell shows it inline; ``.save(path)`` writes the page."""
    return Page(_drawing(x, hulls, removed, options), height=height)


def view_outputs(path: str | os.PathLike,
                 png: bool | str | os.PathLike = True) -> tuple[Path | None, Path | None]:
    """(page, picture) paths :func:`write_view` writes for ``path``: a ``.png`` path is the
    picture alone; any other is the page, with the picture at ``png`` (True: beside it, with
    the suffix ``.png``; False: none)."""
    out = Path(path)
    if out.suffix.lower() == ".png":
        return None, out
    if png is True:
        return out, out.with_suffix(".png")
    return out, (Path(png) if png else None)


def write_view(path: str | os.PathLike, x, hulls=None, removed=None, *,
               png: bool | str | os.PathLike = True, size: tuple[int, int] = SIZE,
               overwrite: bool = False, **options) -> list[Path]:
    """The page and the picture of ``x`` (see :func:`view_outputs`); what ``pointcvx view`` and
    ``pointcvx decompose --preview`` write. Without ``overwrite`` an existing output is refused
    before anything is written. Returns the paths written."""
    page, picture = view_outputs(path, png)
    targets = [p for p in (page, picture) if p is not None]
    if page is not None and picture is not None and page.resolve() == picture.resolve():
        raise OutputError(f"{page}: the page and the picture cannot be the same file")
    for target in targets:
        if target.exists() and not overwrite:
            raise OutputError(f"{target}: exists; pass --overwrite to replace it")
        if target.is_dir():
            raise OutputError(f"{target}: is a directory")
        if str(target.parent) and not target.parent.is_dir():
            raise OutputError(f"{target.parent}: output directory does not exist")
    sc = _drawing(x, hulls, removed, options)
    text = html_page(sc) if page is not None else None  # both made before either is written
    image = render(sc, size) if picture is not None else None
    if page is not None:
        with atomic_path(page, overwrite=overwrite) as tmp:
            tmp.write_text(text, encoding="utf-8")
    if picture is not None:
        write_png(picture, image, overwrite=overwrite)
    return targets
