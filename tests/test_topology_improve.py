"""Local mesh improvement (wcut.topology.improve): flips and smoothing that never make the
worst element worse and keep the boundary, the frozen vertices and the volume."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from wcut.cut import Cutter, Plane
from wcut.mesh import beam, dihedral_angles, perturbed
from wcut.topology import TetTopology, check_topology
from wcut.topology.improve import improve, min_sine

POOR = perturbed(beam(5, 4, 4, size=(0.05, 0.04, 0.04)), 1.0, seed=1)  # worst dihedral 0.52 degrees


@settings(max_examples=50, deadline=None, derandomize=True)
@given(st.lists(st.floats(-1.0, 1.0), min_size=12, max_size=12))
def test_min_sine_is_the_smallest_sine_of_the_dihedral_angles(values):
    p = np.array(values).reshape(4, 3)
    volume = np.linalg.det(p[1:] - p[0])
    if abs(volume) < 1e-3:
        return
    if volume < 0:
        p = p[[1, 0, 2, 3]]
    expected = np.sin(np.radians(dihedral_angles(p, np.array([[0, 1, 2, 3]])))).min()
    assert math.isclose(min_sine(*map(tuple, p)), expected, rel_tol=1e-9, abs_tol=1e-12)
    assert min_sine(*map(tuple, p[[1, 0, 2, 3]])) < 0  # inverted: negative


def _worst_angle(topo) -> float:
    mesh = topo.to_mesh()
    return float(dihedral_angles(mesh.vertices, mesh.tets).min())


def test_improving_a_poor_mesh_raises_its_worst_angle_and_keeps_boundary_and_volume():
    topo = TetTopology(POOR)
    boundary = POOR.boundary().vertex_ids
    frozen = set(range(0, POOR.vertex_count, 7))  # some vertices that must stay
    before_x = topo.rest_positions.copy()
    topo.begin_change()
    stats = improve(topo, topo.live_tets().tolist(), frozen, target=15.0)
    change = topo.end_change()
    check_topology(topo, POOR.volumes().sum(), volume_tolerance=1e-12)
    after_x = topo.rest_positions
    assert stats.edge_flips + stats.face_flips > 0
    assert stats.worst_after >= 15.0 > stats.worst_before
    assert _worst_angle(topo) >= float(dihedral_angles(POOR.vertices, POOR.tets).min())
    # the box's boundary vertices stay in their faces' planes; frozen vertices do not move
    moved = np.flatnonzero(np.any(after_x[: POOR.vertex_count] != before_x[: POOR.vertex_count], axis=1))
    assert not set(moved.tolist()) & frozen
    on_faces = np.isclose(before_x[boundary][:, None, :], [[0.0, 0.0, 0.0], [0.05, 0.04, 0.04]]).any(axis=1)
    assert np.array_equal(np.isclose(after_x[boundary][:, None, :], [[0.0, 0.0, 0.0], [0.05, 0.04, 0.04]])
                          .any(axis=1) | ~on_faces, np.ones_like(on_faces))
    # the change record expresses the moved vertices by their neighbours
    carried = np.einsum("vk,vkj->vj", change.vertex_weights, POOR.vertices[change.vertex_sources])
    np.testing.assert_allclose(carried, topo.to_mesh().vertices, atol=1e-15)


def test_a_cut_with_improvement_keeps_its_surface_and_separates():
    plane = Plane([0.026, 0.019, 0.021], [1.0, 0.3, -0.2])
    plain, improved = TetTopology(POOR), TetTopology(POOR)
    Cutter(plain, epsilon=0.1).cut(plane)
    cutter = Cutter(improved, epsilon=0.1, improve=True)
    stats = cutter.cut(plane).stats
    check_topology(improved, POOR.volumes().sum(), volume_tolerance=1e-12)
    assert stats.improved_edge_flips + stats.improved_face_flips + stats.smoothed_vertices > 0
    # the vertices on the cut plane are where the cut put them
    x = improved.rest_positions[improved.live_tets().size and np.unique(improved.tets[improved.live_tets()])]
    on = np.abs(plane.signed_distance(x)) <= cutter.tolerance
    y = plain.rest_positions[np.unique(plain.tets[plain.live_tets()])]
    on_plain = np.abs(plane.signed_distance(y)) <= cutter.tolerance
    assert on.sum() == on_plain.sum()
    from wcut.cut.separation import plane_separation

    mesh = improved.to_mesh()
    assert plane_separation(mesh.vertices, mesh.tets, plane, cutter.tolerance).separated
    assert _worst_angle(improved) >= _worst_angle(plain)


def test_a_vertex_pushed_against_a_face_is_smoothed_back():
    """The middle vertex of a 2x2x2 box, moved 90% of the way to a face of its star (every
    other vertex frozen): moving it back is what helps, and smoothing does it."""
    mesh = beam(2, 2, 2, tets_per_hex=6)
    middle = 13
    x = mesh.vertices.copy()
    x[middle] += 0.9 * (np.array([1.0, 0.5, 0.5]) - x[middle])
    from wcut.mesh import TetMesh

    topo = TetTopology(TetMesh(x, mesh.tets))
    frozen = set(range(mesh.vertex_count)) - {middle}
    stats = improve(topo, topo.live_tets().tolist(), frozen, target=20.0)
    assert stats.smoothed > 0 and stats.edge_flips == 0
    assert stats.worst_after > stats.worst_before + 5.0
    check_topology(topo, 1.0, volume_tolerance=1e-12)
