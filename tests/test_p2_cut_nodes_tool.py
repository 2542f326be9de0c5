"""tools/p2_cut_nodes.py (thesis table 6.4 and the coarse liver): the tool end to end, and
what its figures must show."""

from __future__ import annotations

import csv

import pytest

from conftest import load_tool


@pytest.fixture(scope="module")
def rows(tmp_path_factory):
    module = load_tool("p2_cut_nodes")
    out = tmp_path_factory.mktemp("p2nodes") / "p2_cut_nodes"
    assert module.main(["-o", str(out), "--quick"]) == 0
    assert out.with_suffix(".png").stat().st_size > 10_000
    with open(out.with_suffix(".csv")) as f:
        return list(csv.DictReader(f))


def test_every_cut_keeps_the_volume_and_separates(rows):
    assert len(rows) == 3 * 5
    for row in rows:
        assert abs(float(row["volume_change"])) < 1e-9
        assert int(row["components"]) == 2
        assert int(row["cut_elements"]) > 20


def test_snapping_brings_the_added_nodes_down(rows):
    """The thesis's coarse liver needed about 48 added nodes per cut element; snapping should
    bring the count down (6.1.5): here on every case from epsilon 0 to 0.3."""
    by_case: dict[str, dict[float, float]] = {}
    for row in rows:
        by_case.setdefault(row["case"], {})[float(row["epsilon"])] = float(row["added_per_cut_element"])
    for case, added in by_case.items():
        assert added[0.3] < added[0.0], case
        assert added[0.0] < 48.4, case
