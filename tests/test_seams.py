"""Closed seams (pointcvx.decomposition.seams): neighbouring hulls overlap along their cut, so the
union of hulls has no crack inside the solid."""

from __future__ import annotations

import numpy as np
import pytest
from shapes import l_block

import pointcvx
from pointcvx.decomposition.concavity import nearest_distance
from pointcvx.decomposition.hull import convex_hull
from pointcvx.decomposition.seams import SEAM_SPACINGS, seam_parts
from pointcvx.evaluate import union_surface_samples


def _grid(h: float = 0.1) -> np.ndarray:
    """(10 * 10, 3) float: a square grid of spacing ``h`` in the plane z = 0, x in [-5h, 4h]."""
    x, y = np.meshgrid(np.arange(-5, 5) * h, np.arange(10) * h, indexing="ij")
    return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])


def test_each_part_takes_the_first_row_of_its_neighbour_and_nothing_more():
    h = 0.1
    pts = _grid(h)
    labels = (pts[:, 0] > -h / 2).astype(np.int64)  # part 0: x < 0; part 1: x >= 0
    noise = np.flatnonzero(np.isclose(pts[:, 0], -h) & np.isclose(pts[:, 1], 0.0))
    labels[noise] = -1  # a point of no part, at the seam
    assert 1.0 < SEAM_SPACINGS < 2.0  # one row across (h, sqrt(2) h), not two (2 h)
    zero, one = seam_parts(pts, labels, h)
    assert np.all(np.diff(zero) > 0) and np.all(np.diff(one) > 0)
    np.testing.assert_array_equal(np.setdiff1d(zero, np.flatnonzero(labels == 0)),
                                  np.flatnonzero(np.isclose(pts[:, 0], 0.0)))
    np.testing.assert_array_equal(np.setdiff1d(one, np.flatnonzero(labels == 1)),
                                  np.setdiff1d(np.flatnonzero(np.isclose(pts[:, 0], -h)), noise))
    assert noise[0] not in zero and noise[0] not in one


def test_one_part_or_no_spacing_gives_the_parts_themselves():
    pts = _grid()
    whole = seam_parts(pts, np.zeros(len(pts), dtype=np.int64), 0.1)
    assert len(whole) == 1 and len(whole[0]) == len(pts)
    labels = (pts[:, 0] > 0).astype(np.int64)
    parts = seam_parts(pts, labels, 0.0)
    np.testing.assert_array_equal(parts[1], np.flatnonzero(labels == 1))


@pytest.fixture(scope="module")
def l_result():
    return pointcvx.decompose(l_block(), threshold=0.1, n_points=6000, seed=0)


def _worst_boundary_gap(hulls: list[np.ndarray], surface: np.ndarray) -> float:
    """The farthest the boundary of the union of ``hulls`` gets from the shape's surface."""
    union = union_surface_samples([convex_hull(v) for v in hulls], 20000, np.random.default_rng(0))
    return float(nearest_distance(union, surface).max())


def test_the_hulls_of_a_cut_shape_leave_no_crack_inside_it(l_result):
    # The L in two convex pieces: with the seam closed, the boundary of the union of hulls is
    # the L's surface (within a few sample spacings); the hulls of the two parts' own points
    # alone leave a gap along the cut whose walls run through the middle of the solid.
    assert len(l_result) == 2
    norm = l_result.cloud.normalization
    surface = norm.forward(l_block().sample(50000, seed=0))
    spacing = l_result._decomposer.spacing
    closed = [norm.forward(h.vertices) for h in l_result.hulls]
    assert _worst_boundary_gap(closed, surface) < 3 * spacing
    own = [l_result.cloud.points[l_result.labels == i] for i in range(len(l_result))]
    assert _worst_boundary_gap(own, surface) > 0.2
    # The labels are still a partition, each hull counts its own points.
    assert [h.n_points for h in l_result.hulls] == [len(p) for p in own]


def test_eval_dataset_scores_the_open_seams_beside_the_closed_ones(tmp_path):
    from conftest import load_tool

    path = tmp_path / "l_block.obj"
    l_block().export(path)
    row = load_tool("eval_dataset").run_one(str(path), {"threshold": 0.1, "n_points": 4000, "seed": 0},
                                            open_seams=True)
    assert "error" not in row, row
    assert row["hulls"] == row["open_hulls"] == 2
    # The gap along the cut is boundary of the open union: reconstruction error it adds.
    assert row["open_reconstruction"] > 1.2 * row["reconstruction"]
