"""tools/cut_conditioning.py (thesis figure 5.11) end to end, in-process, on a small beam."""

from __future__ import annotations

import csv
import math

import pytest

import wcut
from conftest import load_tool


@pytest.fixture(scope="module")
def tool():
    return load_tool("cut_conditioning")


@pytest.fixture(scope="module")
def quick_run(tool, tmp_path_factory):
    """The tool with --quick (8 steps, epsilon 0 and 0.2) on a 4x2x2-cell beam; its CSV rows."""
    tmp = tmp_path_factory.mktemp("cut_conditioning")
    mesh_path = tmp / "beam.vtu"
    wcut.beam(4, 2, 2, size=(0.16, 0.04, 0.04)).save(mesh_path)
    out = tmp / "out"
    code = tool.main(["--quick", "--quiet", "--mesh", str(mesh_path), "--out-dir", str(out)])
    with open(out / tool.CSV_NAME, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    return code, out, rows


def _case(rows, method, epsilon):
    return [r for r in rows if r["method"] == method and float(r["epsilon"]) == epsilon]


def test_runs_and_writes_csv_and_png(tool, quick_run):
    code, out, rows = quick_run
    assert code == 0
    assert (out / tool.PNG_NAME).stat().st_size > 0
    assert list(rows[0]) == list(tool.COLUMNS)
    assert not list(out.glob(".*tmp*"))  # atomic writes leave no temporary file


def test_one_row_per_method_epsilon_step(quick_run):
    _, _, rows = quick_run
    for method in ("paulus", "bielser"):
        for epsilon in (0.0, 0.2):
            assert [int(r["step"]) for r in _case(rows, method, epsilon)] == list(range(9))
    assert len(rows) == 2 * 2 * 9


def test_nodes_grow_and_beam_separates(quick_run):
    """Every method and epsilon, paulus without snapping included, leaves the beam in two
    pieces once the blade is through (an element is cut once the blade has passed it, so the
    last front opens), and in one piece before."""
    _, _, rows = quick_run
    for method in ("paulus", "bielser"):
        for epsilon in (0.0, 0.2):
            case = _case(rows, method, epsilon)
            nodes = [int(r["nodes"]) for r in case]
            assert all(b >= a for a, b in zip(nodes, nodes[1:])), (method, epsilon, nodes)
            assert nodes[-1] > nodes[0]
            pieces = [int(r["components"]) for r in case]
            assert pieces[-1] == 2, (method, epsilon, pieces)
            assert pieces[:7] == [1] * 7, (method, epsilon, pieces)  # steps 0-6: the blade is in the beam


def test_condition_numbers_finite_and_above_one(quick_run):
    _, _, rows = quick_run
    for r in rows:
        kappa = float(r["condition_number"])
        assert math.isfinite(kappa) and kappa > 1.0, r


def test_paulus_adds_fewer_nodes_than_bielser(quick_run):
    """Thesis 5.2: about 2 added nodes per cut element for paulus, 4.2 to 5.6 for Bielser.

    Both methods cut the same elements of the uncut mesh (the thesis's n(v)), so per cut
    element paulus must add fewer nodes; per element the cutter reported as well."""
    _, _, rows = quick_run
    added, per_cut = {}, {}
    for method in ("paulus", "bielser"):
        case = _case(rows, method, 0.0)
        added[method] = int(case[-1]["nodes"]) - int(case[0]["nodes"])
        per_cut[method] = added[method] / int(case[-1]["cut_elements_total"])
    assert per_cut["paulus"] < per_cut["bielser"], per_cut
    assert added["paulus"] < added["bielser"], added


def test_sparse_and_dense_spectra_agree(tool):
    """The sparse eigensolver used above DENSE_MAX_DOFS gives the dense condition number,
    also on a cut mesh with sliver elements."""
    import numpy as np

    from wcut.cut import Cutter, Plane
    from wcut.topology import TetTopology

    mesh = wcut.beam(4, 2, 2, size=(0.16, 0.04, 0.04))
    topo = TetTopology(mesh)
    Cutter(topo, method="paulus", epsilon=0.0, improve=False).cut(Plane((0.0801, 0.0, 0.0), (1.0, 0.0, 0.0)))
    cut = topo.to_mesh()
    args = tool.parse_args([])
    fixed = cut.vertices[:, 0] <= 1e-12
    A = tool.system_matrix(cut.vertices, cut.tets, fixed, args)
    dense = np.array(tool.extreme_eigenvalues(A, "dense"))
    sparse = np.array(tool.extreme_eigenvalues(A, "sparse"))
    assert np.allclose(sparse, dense, rtol=1e-8, atol=0.0), (dense, sparse)
    uncut = tool.condition_number(mesh.vertices, mesh.tets, mesh.vertices[:, 0] <= 1e-12, args)
    assert dense[1] / dense[0] > 10.0 * uncut  # the cut made slivers


def test_the_cut_without_improvement_runs_and_keeps_the_mesh_valid(tool, tmp_path):
    """``--no-improve``: the same progressive cut without the local mesh improvement after each
    step (each step's mesh is checked inside the tool: valid, volume kept); the beam still comes
    apart."""
    mesh_path = tmp_path / "beam.vtu"
    wcut.beam(4, 2, 2, size=(0.16, 0.04, 0.04)).save(mesh_path)
    out = tmp_path / "out"
    assert tool.main(["--quick", "--quiet", "--no-improve", "--methods", "paulus", "--epsilons", "0",
                      "--mesh", str(mesh_path), "--out-dir", str(out)]) == 0
    with open(out / tool.CSV_NAME, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert int(rows[-1]["components"]) == 2
