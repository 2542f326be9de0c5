"""tools/cut_turns.py: the scan of progressive cuts whose blade turns, end to end, and its
crossing count, which must see the edges the crossing contract hides."""

from __future__ import annotations

import csv

import numpy as np

from conftest import load_tool
from wcut.cut.surface import TriangleSurface
from wcut.mesh import TetMesh

tool = load_tool("cut_turns")


def test_the_scan_writes_one_row_per_path_and_a_straight_cut_separates(tmp_path):
    out = tmp_path / "turns"
    assert tool.main(["-o", str(out), "--paths", "2", "--turns", "0"]) == 0
    with open(out.with_suffix(".csv")) as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2
    assert {row["compiled"] for row in rows} == {"True", "False"}
    for row in rows:  # no turn: a clean cut into two pieces
        assert int(row["crossing_edges"]) == 0
        assert int(row["pieces"]) == 2
        assert int(row["crumbs"]) == 0


def test_an_edge_from_one_sheet_across_the_other_counts():
    # a V-shaped surface (two vertical sheets meeting at x = 0) and an edge from a point on the
    # left sheet to the right of the right sheet
    v = np.array([[-1.0, 1.0, -1.0], [-1.0, 1.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0],
                  [1.0, 1.0, -1.0], [1.0, 1.0, 1.0]])
    surface = TriangleSurface(v, np.array([[0, 2, 1], [1, 2, 3], [2, 4, 3], [3, 4, 5]]))
    a, b = np.array([-0.5, 0.5, 0.0]), np.array([1.0, 0.5, 0.0])
    mesh = TetMesh(np.array([a, b, [0.0, 2.0, 0.5], [0.0, 2.0, -0.5]]), np.array([[0, 1, 2, 3]]))
    t, _ = surface.crossings(a[None], b[None], 1e-9)
    assert np.isnan(t[0])  # the contract: an endpoint on S makes no crossing
    edges = mesh.edges()
    t, _ = surface.crossings(mesh.vertices[edges[:, 0]], mesh.vertices[edges[:, 1]], 1e-9)
    assert tool.crossing_edges(mesh, surface) == np.isfinite(t).sum() + 1  # that edge, and only it
