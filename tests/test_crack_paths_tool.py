"""tools/crack_paths.py (thesis 6.2, figure 6.16): crack paths of the fracture variants on
the precut sheet, end to end on a tiny case, and its path measure and clamps."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from conftest import load_tool

CELLS = 8


@pytest.fixture(scope="module")
def tool():
    return load_tool("crack_paths")


@pytest.fixture(scope="module")
def tiny_run(tool, tmp_path_factory):
    """8x8 cells, variants none and spatial, a fast load: the crack starts at step 57 (mode I)
    and 65 (inclined) and reaches the boundary by step 71 (about 3 s in all)."""
    out = tmp_path_factory.mktemp("crack_paths")
    code = tool.main(["--out", str(out), "--cells", str(CELLS), "--steps", "90", "--strain-rate", "1.5e-3",
                      "--variants", "none", "spatial", "--quiet"])
    with open(out / tool.CSV_NAME, newline="", encoding="utf-8") as f:
        rows = {(r["case"], r["variant"]): r for r in csv.DictReader(f)}
    return code, out, rows


def test_writes_one_row_per_case_and_variant_and_a_png(tool, tiny_run):
    from PIL import Image

    code, out, rows = tiny_run
    assert code == 0
    assert set(rows) == {(c, v) for c in ("mode-I", "inclined") for v in ("none", "spatial")}
    with open(out / tool.CSV_NAME, newline="", encoding="utf-8") as f:
        assert next(csv.reader(f)) == list(tool.COLUMNS)
    with Image.open(out / tool.PNG_NAME) as image:
        image.verify()
    with Image.open(out / tool.PNG_NAME) as image:
        assert image.format == "PNG" and image.size[0] > 800 and image.size[1] > 400
    assert not list(out.glob(".*tmp*"))  # atomic writes leave no temporary file


def test_every_run_succeeds_and_starts_at_the_notch_tip(tiny_run):
    _, _, rows = tiny_run
    for key, r in rows.items():
        assert r["status"] == "ok", (key, r["failure"])
        assert r["finite"] == r["topology_ok"] == r["crack_started"] == r["started_at_tip"] == "true", key
        assert r["reached_boundary"] == "true" and r["other_initiations"] == "0", key


def test_mode_one_crack_of_none_runs_straight_along_the_middle(tiny_run):
    """The sheet and its load are symmetric about y = h/2, a line of mesh edges: the crack of
    ``none`` opens exactly that line, from the tip (x = 2 cells) to the right side."""
    _, _, rows = tiny_run
    r = rows[("mode-I", "none")]
    assert int(r["events"]) == CELLS - 2 and r["snapped_events"] == "0" and r["refined_events"] == "0"
    assert float(r["max_deviation_m"]) < 1e-9  # finite: points beyond one cell from the tip exist
    assert float(r["reach_m"]) == pytest.approx(0.1 * (1 - 2 / CELLS), abs=1e-12)
    assert float(r["path_length_m"]) == pytest.approx(float(r["reach_m"]), abs=1e-12)
    assert int(r["nodes_added"]) == 2 * (CELLS - 2) + 1 and r["triangles_added"] == "0"


def test_inclined_case_discriminates_the_variants(tiny_run):
    """Off mesh lines, ``none`` can only zig-zag along edges (it keeps the mesh), while
    ``spatial`` snaps corners towards the expected line and follows it more closely."""
    _, _, rows = tiny_run
    none, spatial = rows[("inclined", "none")], rows[("inclined", "spatial")]
    cell = 0.1 / CELLS
    assert float(none["max_deviation_m"]) > 0.5 * cell
    assert int(spatial["snapped_events"]) > 0 and none["snapped_events"] == "0"
    assert float(spatial["max_deviation_m"]) < 0.5 * float(none["max_deviation_m"])
    assert float(none["min_quality"]) == pytest.approx(np.sqrt(3) / 2, abs=1e-6)  # untouched right triangles
    assert float(spatial["min_quality"]) < float(none["min_quality"])


def test_path_figures_measure_distance_from_the_line_beyond_one_cell(tool):
    tip, t, cell = np.zeros(3), np.array([1.0, 0.0, 0.0]), 0.01
    segments = np.array([[[0, 0, 0], [0.008, 0.004, 0]],         # within one cell: left out
                         [[0.008, 0.004, 0], [0.02, -0.002, 0]],
                         [[0.02, -0.002, 0], [0.03, 0.0, 0]]], dtype=float)
    f = tool.path_figures(segments, tip, t, cell)
    assert f["max_deviation_m"] == pytest.approx(0.002)
    assert f["mean_deviation_m"] == pytest.approx(0.001)
    assert f["reach_m"] == pytest.approx(0.03)
    assert f["angle_error_deg"] == pytest.approx(0.0, abs=1e-9)
    assert np.isnan(tool.path_figures(segments[:1], tip, t, cell)["max_deviation_m"])


def test_inclined_clamps_hold_the_outer_boundary_but_not_the_notch(tool):
    mesh, tip = tool.sheet(CELLS)
    X = mesh.vertices
    mask = tool.clamped(X, tool.make_case("inclined", 30.0))
    outer = tool.on_outer_boundary(X)
    # 4n corners and 4n edge nodes, and the notch's mouth doubled
    assert (mask == outer).all() and outer.sum() == 8 * CELLS + 1
    notch = (np.abs(X[:, 1] - 0.05) < 1e-12) & (X[:, 0] > 1e-12) & (X[:, 0] <= tip[0] + 1e-12)
    # the notch is 2 cells long: 2 copies of its middle corner, 2 x 2 edge nodes, the tip
    assert notch.sum() == 7 and not mask[notch].any()
    assert tool.make_case("inclined", 30.0).expected_direction == pytest.approx([np.sqrt(3) / 2, -0.5, 0.0])


def test_a_diverging_solver_is_reported_as_a_failed_run_not_raised(tool, monkeypatch):
    import wcut
    from wcut.solver import SolverCorotational

    calls = []

    def diverge(self):
        calls.append(1)
        if len(calls) == 3:
            raise wcut.SimulationError("the simulation diverged: 1 non-finite vertex updates")

    monkeypatch.setattr(SolverCorotational, "check", diverge)
    row = tool.run(tool.make_case("inclined", 30.0), "none", 4, 10, 1e-3)
    assert row["status"] == "failed" and row["finite"] is False and row["steps_run"] == 3
    assert "step 2" in row["failure"] and "diverged" in row["failure"]


def test_tip_component_keeps_only_cracks_connected_to_the_tip(tool):
    class Event:
        def __init__(self, *segments):
            self.segments = np.array(segments, dtype=float)

    tip = np.array([0.025, 0.05, 0.0])
    events = [Event([tip, [0.0375, 0.05, 0]]), Event([[0.1, 0.0, 0], [0.0875, 0.0125, 0]]),
              Event([[0.0375, 0.05, 0], [0.05, 0.0375, 0]])]
    component = tool.tip_component(events, tip)
    assert len(component) == 3 and not tool.on_outer_boundary(component).any()
    assert tool.on_outer_boundary(tool.tip_component(events + [Event([[0.05, 0.0375, 0], [0.1, 0.0375, 0]])],
                                                     tip)).any()
