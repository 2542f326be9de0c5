"""tools/cut_separation.py: the domain's smallest wedge, which bounds the worst angle any mesh
of a cut body can reach, and the per-cut count of the quality target."""

from __future__ import annotations

import math

import numpy as np

from conftest import load_tool, single_tet
from wcut.cut import Cutter, Plane
from wcut.mesh import beam, dihedral_angles
from wcut.topology import TetTopology

tool = load_tool("cut_separation")


def test_the_wedge_of_a_box_is_a_right_angle_and_of_one_element_its_worst_angle():
    box = beam(2, 2, 2, size=(1.0, 1.0, 1.0))
    assert math.isclose(tool.domain_wedge(box), 90.0, abs_tol=1e-9)
    tet = single_tet()
    assert math.isclose(tool.domain_wedge(tet), dihedral_angles(tet.vertices, tet.tets).min(),
                        abs_tol=1e-9)


def test_a_plane_at_sixty_degrees_to_two_faces_makes_a_wedge_of_sixty():
    box = beam(2, 2, 2, size=(1.0, 1.0, 1.0))
    s = math.sin(math.radians(30.0))
    plane = Plane([0.5, 0.5, 0.5], [0.0, s, math.sqrt(1.0 - s * s)])
    topo = TetTopology(box)
    Cutter(topo, epsilon=0.0).cut(plane)
    after = topo.to_mesh()
    assert math.isclose(tool.domain_wedge(after), 60.0, abs_tol=1e-6)


def test_a_chain_counts_each_cut_against_the_target():
    """Two cuts of a clean beam: both counted, none a miss (the beam's elements are fine)."""
    mesh = beam(4, 2, 2, size=(0.08, 0.04, 0.04))
    planes = [Plane([0.03, 0.02, 0.02], [1.0, 0.1, 0.05]), Plane([0.05, 0.02, 0.02], [0.1, 1.0, 0.3])]
    record = tool.one(mesh, planes, "paulus", 0.1)
    assert record["separated"] and not record["error"]
    assert record["misses"] == record["misses_input"] == record["forced"] == 0
    assert record["min_dihedral"] >= min(tool.TARGET_DEGREES, dihedral_angles(mesh.vertices, mesh.tets).min() / 2)
    assert tool.TARGET_DEGREES <= record["worst_new"] < 90.0  # the elements the cuts made
    assert np.isfinite(record["volume_change"]) and record["volume_change"] < 1e-9
