"""A look at the result: the offline HTML page (one file, nothing fetched, the scene embedded as
JSON), the PNG (valid, of its size, the shape and the hull colours in it), `pointcvx view` and
`pointcvx decompose --preview` end to end, one-line errors, outputs with the user's umask."""

from __future__ import annotations

import base64
import colorsys
import json
import os
import re
from html.parser import HTMLParser

import numpy as np
import pytest
import trimesh

from conftest import SAMPLES
from pointcvx.cli import EXIT_INPUT, EXIT_USAGE, main
from pointcvx.evaluate import load_hulls
from pointcvx.view import drawing, hull_colors, render, render_png, show, write_html, write_view
from pointcvx.view.drawing import as_hulls, feature_edges
from pointcvx.view.png import png_bytes

MUG = SAMPLES / "mug.obj"


class _Page(HTMLParser):
    """Collects a page's tags, their attributes and the text of its scripts."""

    def __init__(self):
        super().__init__()
        self.tags, self.scripts, self._in = [], [], None

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))
        if tag == "script":
            self._in = dict(attrs)
            self.scripts.append([self._in, ""])

    def handle_endtag(self, tag):
        if tag == "script":
            self._in = None

    def handle_data(self, data):
        if self._in is not None:
            self.scripts[-1][1] += data


def _parse(text: str) -> tuple[_Page, dict]:
    page = _Page()
    page.feed(text)
    page.close()
    data = [body for attrs, body in page.scripts if attrs.get("type") == "application/json"]
    assert len(data) == 1
    return page, json.loads(data[0])


def _decode(text: str, dtype: str, width: int) -> np.ndarray:
    return np.frombuffer(base64.b64decode(text), dtype=dtype).reshape(-1, width)


def _boxes() -> list[trimesh.Trimesh]:
    """Three boxes side by side, apart: three hulls."""
    move = trimesh.transformations.translation_matrix
    return [trimesh.creation.box(extents=(0.8, 0.8, 0.8), transform=move((x, 0.0, 0.0)))
            for x in (-1.2, 0.0, 1.2)]


def _sphere_points(n: int, seed: int = 0) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.fixture(scope="module")
def mug_run(tmp_path_factory):
    """`pointcvx decompose io/mug.obj -n 2000 -k 4 --features model --preview`, then the hulls."""
    out = tmp_path_factory.mktemp("view")
    hulls, preview = out / "mug_hulls.obj", out / "preview.html"
    assert main(["decompose", str(MUG), "-n", "2000", "-k", "4", "--features", "model", "-q",
                 "-o", str(hulls), "--preview", str(preview)]) == 0
    return out, hulls, preview


def test_page_is_one_offline_file_with_the_scene_inside(tmp_path):
    pts = _sphere_points(120_000) * 2.0 + 1000.0  # far from the origin: float32 must still hold it
    removed = np.c_[np.linspace(998, 1002, 300), np.full(300, 997.5), np.zeros(300) + 1000]
    boxes = [(b.vertices + 1000.0, b.faces) for b in _boxes()]
    page_path = write_html(tmp_path / "p.html", pts, hulls=boxes, removed=removed,
                           legend={"title": "</script><b>x</b>"})
    assert [p.name for p in tmp_path.iterdir()] == ["p.html"]  # one file, no temporary left
    text = page_path.read_text()
    page, scene = _parse(text)
    # nothing is fetched: no src or href anywhere, no URL outside the embedded data
    assert not [t for t, a in page.tags if {"src", "href"} & set(a)]
    tags = {t for t, _ in page.tags}
    assert tags >= {"html", "canvas", "script"} and not tags & {"link", "img", "iframe"}
    code = re.sub(r'<script type="application/json".*?</script>', "", text, flags=re.S)
    assert "http" not in code and "url(" not in code and "fetch(" not in code and "XMLHttpRequest" not in code
    assert "<b>x</b>" not in code  # the title is text, never markup
    assert scene["legend"]["title"] == "</script><b>x</b>"
    # at most 50,000 points, a seeded subset, in place after the origin is added back
    assert scene["points"]["count"] == 50_000 and scene["legend"]["points_total"] == 120_000
    got = _decode(scene["points"]["positions"], "<f4", 3) + np.asarray(scene["origin"])
    assert len(got) == 50_000
    np.testing.assert_allclose(np.linalg.norm(got - 1000.0, axis=1), 2.0, atol=1e-5)
    assert len(scene["hulls"]) == 3 and scene["legend"]["hulls"] == 3
    for h, (v, f) in zip(scene["hulls"], boxes, strict=True):
        np.testing.assert_allclose(_decode(h["vertices"], "<f4", 3) + scene["origin"], v, atol=1e-4)
        assert len(_decode(h["faces"], "<u4", 3)) == len(f) == 12
        assert len(_decode(h["edges"], "<u4", 2)) == 12  # a box's creases, not its diagonals
    assert len({tuple(h["color"]) for h in scene["hulls"]}) == 3
    assert scene["removed"]["count"] == 300 and scene["legend"]["removed"] == 300
    assert scene["points"]["colors"] is None and scene["points"]["labels"] is None


def test_png_is_valid_of_its_size_with_the_shape_and_every_hull_colour(tmp_path):
    from PIL import Image

    boxes = _boxes()
    pts = np.concatenate([b.sample(3000, seed=i) for i, b in enumerate(boxes)])
    d = drawing(pts, hulls=[(b.vertices, b.faces) for b in boxes], legend={"title": "boxes"})
    img = render(d, (320, 240))
    assert img.shape == (240, 320, 3) and img.dtype == np.uint8
    path = render_png(tmp_path / "boxes.png", pts, hulls=[(b.vertices, b.faces) for b in boxes],
                      size=(320, 240), legend={"title": "boxes"})
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with Image.open(path) as pic:
        assert pic.size == (320, 240) and pic.mode == "RGB"
        back = np.asarray(pic)
    np.testing.assert_array_equal(back, img)  # the file holds exactly what was rendered
    assert (back[:10, :10] == 255).all()  # a corner is background
    middle = back[60:170, 40:280].reshape(-1, 3)
    assert (middle.min(axis=1) < 200).mean() > 0.3  # the shape is there
    hsv = np.array([colorsys.rgb_to_hsv(*c) for c in back.reshape(-1, 3)[::3] / 255.0])
    coloured = hsv[hsv[:, 1] > 0.15]
    for rgb in hull_colors(3):
        hue = colorsys.rgb_to_hsv(*rgb)[0]
        near = np.abs((coloured[:, 0] - hue + 0.5) % 1.0 - 0.5) < 0.03
        assert near.sum() > 100, f"hull colour {rgb} is missing"
    # without hulls: nothing saturated, only the neutral points
    plain = render(drawing(pts), (320, 240), caption=False)
    hsv = np.array([colorsys.rgb_to_hsv(*c) for c in plain.reshape(-1, 3)[::3] / 255.0])
    assert (hsv[:, 1] > 0.3).mean() < 0.001 and (plain.min(axis=2) < 220).mean() > 0.05


def test_png_writer_round_trips_rgba_and_refuses_other_arrays():
    import io

    from PIL import Image

    rgba = np.random.default_rng(0).integers(0, 256, size=(7, 5, 4), dtype=np.uint8)
    with Image.open(io.BytesIO(png_bytes(rgba))) as pic:
        np.testing.assert_array_equal(np.asarray(pic), rgba)
    with pytest.raises(Exception, match="uint8"):
        png_bytes(np.zeros((4, 4, 3)))


def test_hulls_in_any_form_are_wound_outward():
    box = trimesh.creation.box()
    inward = (box.vertices, box.faces[:, ::-1])
    (v, f), = as_hulls([inward])
    np.testing.assert_array_equal(f, box.faces)
    (v2, f2), = as_hulls([box.vertices])  # bare vertices: their convex hull
    assert len(v2) == 8 and len(f2) == 12
    sphere = trimesh.creation.icosphere(3)
    assert len(feature_edges(sphere.vertices, sphere.faces)) == 0  # round: no creases to draw


def test_outputs_get_the_users_umask(tmp_path):
    old = os.umask(0o027)
    try:
        written = write_view(tmp_path / "v.html", _sphere_points(500), size=(64, 48))
    finally:
        os.umask(old)
    assert [p.name for p in written] == ["v.html", "v.png"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.html", "v.png"]
    assert {oct(p.stat().st_mode & 0o777) for p in written} == {oct(0o640)}


def test_view_cli_round_trip(mug_run, capsys):
    out, hulls_file, preview = mug_run
    n_hulls = len(load_hulls(hulls_file))
    assert 2 <= n_hulls <= 4
    page = out / "mug_view.html"
    assert main(["view", str(MUG), str(hulls_file), "-o", str(page)]) == 0
    assert f"{n_hulls} hulls" in capsys.readouterr().out
    _, scene = _parse(page.read_text())
    assert len(scene["hulls"]) == n_hulls and scene["points"]["count"] == 50_000
    assert scene["legend"]["hulls_file"] == "mug_hulls.obj" and scene["legend"]["modality"] == "mesh"
    assert scene["up"] == "z"
    assert (out / "mug_view.png").read_bytes()[:4] == b"\x89PNG"
    # the hulls in the page are the file's, in its units
    first = _decode(scene["hulls"][0]["vertices"], "<f4", 3) + scene["origin"]
    assert np.abs(first - load_hulls(hulls_file)[0].mean(axis=0)).max() < 1.5
    # the preview of the decomposition itself: its points, labelled by hull, and its numbers
    _, prev = _parse(preview.read_text())
    assert len(prev["hulls"]) == n_hulls and prev["points"]["count"] == 2000
    labels = _decode(prev["points"]["labels"], "<i4", 1).ravel()
    assert set(np.unique(labels)) == set(range(n_hulls))
    assert prev["legend"]["features"] == "model" and prev["legend"]["max_concavity"] > 0
    assert prev["legend"]["seconds"] > 0 and prev.get("removed") is None
    assert preview.with_suffix(".png").is_file()
    # a PNG alone, larger, z up
    shot = out / "shot.png"
    assert main(["view", str(MUG), "-o", str(shot), "--size", "200x150", "-n", "3000", "-q"]) == 0
    assert capsys.readouterr().out == "" and not (out / "shot.html").exists()
    from PIL import Image

    with Image.open(shot) as pic:
        assert pic.size == (200, 150)


@pytest.mark.parametrize("name", ["mug.obj", "mug_splat.ply", "mug_scan.ply", "mug_scan.xyz"])
def test_view_any_input_alone(name, tmp_path, capsys):
    page = tmp_path / "v.html"
    assert main(["view", str(SAMPLES / name), "-o", str(page), "-n", "4000", "--no-png", "-q"]) == 0
    assert [p.name for p in tmp_path.iterdir()] == ["v.html"]
    _, scene = _parse(page.read_text())
    assert scene["hulls"] == [] and 1000 < scene["points"]["count"] <= 4000
    assert (scene["points"]["colors"] is not None) == (name == "mug_splat.ply")
    assert scene["points"]["normals"] is not None


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("pointcvx: error:"), err
    return err


def test_view_bad_input_is_one_line(tmp_path, capsys):
    page = tmp_path / "v.html"
    assert main(["view", str(tmp_path / "missing.obj"), "-o", str(page)]) == EXIT_INPUT
    assert "no such file" in _one_line_error(capsys)
    text = tmp_path / "notes.obj"
    text.write_text("hello, this is not a mesh\n")
    assert main(["view", str(MUG), str(text), "-o", str(page)]) == EXIT_INPUT
    _one_line_error(capsys)
    # a point cloud is no hulls file
    assert main(["view", str(MUG), str(SAMPLES / "mug_scan.ply"), "-o", str(page)]) == EXIT_INPUT
    assert "no triangles" in _one_line_error(capsys)
    assert main(["view", str(MUG), str(tmp_path / "none.obj"), "-o", str(page)]) == EXIT_INPUT
    _one_line_error(capsys)
    assert not list(tmp_path.glob("v.*")) and not list(tmp_path.glob(".v.*"))
    for bad in (["--up", "w"], ["--size", "10x10"], ["--size", "big"]):
        with pytest.raises(SystemExit) as exit_:
            main(["view", str(MUG), *bad])
        assert exit_.value.code == EXIT_USAGE
        assert capsys.readouterr().err.count("\n") == 1


def test_view_never_replaces_what_is_there(tmp_path, capsys):
    page, picture = tmp_path / "v.html", tmp_path / "v.png"
    picture.write_bytes(b"mine")
    assert main(["view", str(MUG), "-o", str(page), "-n", "500"]) == EXIT_INPUT
    assert "exists" in _one_line_error(capsys)
    assert picture.read_bytes() == b"mine" and not page.exists()  # nothing half written
    src = tmp_path / "in.obj"
    src.write_bytes(MUG.read_bytes())
    assert main(["view", str(src), "-o", str(src), "--overwrite"]) == EXIT_INPUT
    assert "input" in _one_line_error(capsys) and src.read_bytes() == MUG.read_bytes()
    assert main(["view", str(MUG), "-o", str(page), "-n", "500", "--overwrite", "-q"]) == 0
    assert picture.read_bytes()[:4] == b"\x89PNG"


def test_notebook_view_is_an_isolated_inline_page():
    page = show(_sphere_points(300), hulls=[b.vertices for b in _boxes()[:2]], height=300)
    inline = page._repr_html_()
    assert inline.startswith("<iframe srcdoc=") and 'height: 300px' in inline
    assert "<script" not in inline  # escaped inside the iframe's document
    _, scene = _parse(page.html)
    assert len(scene["hulls"]) == 2 and scene["points"]["count"] == 300


def test_decomposition_draws_what_isolation_removed(result):
    from pointcvx.view import drawing_from

    d = drawing_from(result)
    removed = getattr(result, "removed_points", None)
    assert d.legend["removed"] == (0 if removed is None else len(removed))
    assert len(d.hulls) == len(result.hulls) and len(d.labels) == len(d.points) == len(result.labels)
    np.testing.assert_allclose(d.points, result.cloud.normalization.inverse(result.cloud.points))
    assert d.legend["features"] == "model" and d.legend["max_concavity"] == result.max_concavity
    extra = np.array([[9.0, 9.0, 9.0], [9.5, 9.0, 9.0]])
    d = drawing_from(result, removed=extra)
    np.testing.assert_array_equal(d.removed, extra)
    assert d.legend["removed"] == 2 and d.legend["hulls"] == len(result.hulls)


def test_camera_stands_on_a_tilted_floor():
    """A depth frame's floor normal lies between axes: the picture's eye is 22 degrees above that
    floor (not above the nearest axis's plane), and the screen's up leans with it."""
    from pointcvx.view.drawing import nearest_axis
    from pointcvx.view.png import camera

    up = np.array([0.07, -0.69, -0.72])
    up /= np.linalg.norm(up)
    axis = nearest_axis(up)
    right, screen_up, forward = camera(axis, exact=up)
    assert np.degrees(np.arcsin(np.dot(-forward, up))) == pytest.approx(22.0)
    assert np.dot(right, up) == pytest.approx(0.0, abs=1e-12)
    assert np.dot(screen_up, up) > 0.9
    plain = camera(axis)
    assert np.degrees(np.arcsin(np.dot(-plain[2], up))) != pytest.approx(22.0, abs=3)
