"""tools/p2_accuracy.py (thesis figure 3.12 and volumetric locking): observed convergence
orders of P1 and P2, P2 more accurate at equal degrees of freedom, and the tool end to end."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from conftest import load_tool


@pytest.fixture(scope="module")
def tool():
    return load_tool("p2_accuracy")


def energy_order(tool, order: int, levels) -> float:
    """Order of the energy-norm error from three nested meshes, without a reference: with
    consistent loads ``C_h/2 - C_h`` is the squared energy norm of ``u_h/2 - u_h``, which
    shrinks by ``2^(2p)`` per halving."""
    c = [tool.cantilever(order, n, 0.0)["compliance_J"] for n in levels]
    assert c[0] < c[1] < c[2]  # compliance grows towards the exact one (the FE solution is too stiff)
    return float(np.log2((c[1] - c[0]) / (c[2] - c[1])) / 2)


def test_p1_converges_with_order_one(tool):
    """Against a converged reference (P2 at n = 4, whose energy error is 30x smaller), the P1
    error halves as h halves. Without a reference, on nested meshes, the order is still
    pre-asymptotic at these sizes (0.69 from n = 2, 4, 8: the bending of a coarse P1 beam
    is too stiff)."""
    reference = tool.cantilever(2, 4, 0.0)["compliance_J"]
    error = [np.sqrt((reference - tool.cantilever(1, n, 0.0)["compliance_J"]) / reference) for n in (3, 6)]
    assert 0.8 < np.log2(error[0] / error[1]) < 1.2


def test_p2_converges_with_order_two(tool):
    assert 1.6 < energy_order(tool, 2, (1, 2, 4)) < 2.4


def test_p2_beats_p1_at_equal_degrees_of_freedom(tool):
    reference = tool.cantilever(2, 4, 0.0)
    p1, quadratic = tool.cantilever(1, 4, 0.0), tool.cantilever(2, 2, 0.0)
    assert quadratic["dofs"] <= p1["dofs"]
    error = lambda row: abs(row["tip_deflection_m"] / reference["tip_deflection_m"] - 1)  # noqa: E731
    assert error(quadratic) < 0.1 * error(p1)


def test_p1_locks_more_than_p2_when_nearly_incompressible(tool):
    rows = tool.locking((0.3, 0.49), n_p1=2, n_p2=1, reference_n=3)
    err = {(r["order"], r["poisson_ratio"]): r["tip_error"] for r in rows}
    assert err[(1, 0.49)] > err[(1, 0.3)]  # locking: P1 gets stiffer as nu -> 0.5
    assert err[(2, 0.49)] < 0.5 * err[(1, 0.49)]


def test_tool_writes_csv_and_png(tool, tmp_path):
    out = tmp_path / "acc"
    assert tool.main(["-o", str(out), "--reference-n", "3"]) == 0
    with open(out.with_suffix(".csv")) as f:
        rows = list(csv.DictReader(f))
    assert {r["study"] for r in rows} == {"convergence", "locking"}
    assert {r["order"] for r in rows} == {"1", "2"}
    assert out.with_suffix(".png").stat().st_size > 10000
