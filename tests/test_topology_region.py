"""A part of a TetTopology edited by the compiled operators and written back
(wcut.topology.region), and the cutter's compiled insertion that uses it."""

from __future__ import annotations

import contextlib
import dataclasses
import functools

import numpy as np
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from wcut.cut import Cutter
from wcut.cut.surface import Plane
from wcut.mesh import beam, perturbed, tet_volumes
from wcut.topology import TetTopology, check_topology, connected_components, remove_edge
from wcut.topology.region import OUTSIDE, TetRegion

from conftest import element_set


@contextlib.contextmanager
def canonical_general_flips():
    """The Python cutter's and the improvement's general flips started as the compiled walk
    starts them (at the ring's first vertex by rest position), so that the two cutters can be
    compared element by element."""
    import wcut.cut.cutter as cutter_module
    import wcut.topology.improve as improve_module

    originals = cutter_module.remove_edge, improve_module.remove_edge
    cutter_module.remove_edge = functools.partial(remove_edge, canonical=True)
    improve_module.remove_edge = functools.partial(remove_edge, canonical=True)
    try:
        yield
    finally:
        cutter_module.remove_edge, improve_module.remove_edge = originals


def test_a_region_marks_faces_to_the_rest_of_the_mesh_and_writes_back_its_splits():
    mesh = beam(4, 2, 2, size=(0.4, 0.2, 0.2))
    topo = TetTopology(mesh)
    topo.begin_change()
    slots = [3, 4, 5, 20]
    region = TetRegion(topo, slots)
    neighbors = region.arrays.tet_neighbors.numpy()[: len(slots)]
    assert (neighbors == OUTSIDE).any() and (neighbors == -1).any()
    region.arrays.check()
    assert region.arrays.split_tets([region.local_slot(4)], [[0.1, 0.2, 0.3, 0.4]]) == [None]
    global_of = region.write_back()
    assert global_of[: len(region.vertices)].tolist() == region.vertices.tolist()
    assert global_of[len(region.vertices):].tolist() == [mesh.vertex_count]
    check_topology(topo)
    volume = float(tet_volumes(mesh.vertices, mesh.tets).sum())
    assert abs(float(tet_volumes(topo.rest_positions, topo.tets[topo.live_tets()]).sum()) - volume) < 1e-12 * volume
    change = topo.end_change()
    assert change.vertex_count_after == mesh.vertex_count + 1 and len(change.removed_elements) == 1
    assert (change.element_parent[change.added_elements] == 4).all()


@settings(max_examples=15, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(point=st.tuples(st.floats(0.05, 0.55), st.floats(0.05, 0.25), st.floats(0.05, 0.25)),
       normal=st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)).filter(
           lambda n: np.linalg.norm(n) > 0.1),
       epsilon=st.sampled_from([0.0, 0.1, 0.3]))
def test_compiled_cut_equals_the_python_operators(point, normal, epsilon):
    """A plane cut with the compiled insertion and disconnection gives the mesh, counts and
    pieces of the Python operators (general flips started as the compiled walk starts them),
    and a valid mesh."""
    mesh = beam(6, 3, 3, size=(0.6, 0.3, 0.3))
    plane = Plane(point, normal)
    results = []
    with canonical_general_flips():
        for compiled in (False, True):
            topo = TetTopology(mesh)
            result = Cutter(topo, epsilon=epsilon, compiled=compiled, improve=False).cut(plane)
            check_topology(topo)
            stats = dataclasses.asdict(result.stats)
            stats["refused"] = len(stats["refused"])
            cut = topo.to_mesh()
            results.append((element_set(cut), stats, result.change.vertex_count_after,
                            len(set(connected_components(cut).tolist()))))
    assert results[0] == results[1]


def test_faces_left_unlinked_by_many_write_backs_are_linked_anew_when_read():
    """Compiled cuts leave the face adjacency to be linked when read; once their log would
    outgrow the mesh it is dropped (memory stays bounded in a long session) and the faces of
    the live elements are linked anew on the next read: the adjacency is then still that of
    the elements, and the Python operators work on it."""
    mesh = beam(6, 3, 3, size=(0.6, 0.3, 0.3))
    topo = TetTopology(mesh)
    assert topo.face_tets and not topo._faces_stale  # a new topology's faces: linked when first read
    topo.unlinked_log_limit = lambda: 400  # a few cuts' worth (the default: the mesh's size)
    volume = float(tet_volumes(mesh.vertices, mesh.tets).sum())
    cutter = Cutter(topo, epsilon=0.1)
    for x in (0.13, 0.27, 0.41, 0.52):
        cutter.cut(Plane([x, 0.0, 0.0], [1.0, 0.2, 0.1]))
        if topo._faces_stale:
            break
    assert topo._faces_stale and not topo._unlinked_faces
    check_topology(topo, volume)  # reads the faces: linked anew
    assert not topo._faces_stale
    Cutter(topo, epsilon=0.1, compiled=False).cut(Plane([0.2, 0.15, 0.0], [0.1, 1.0, 0.2]))
    check_topology(topo, volume)


@settings(max_examples=20, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(steps=st.lists(st.tuples(st.floats(0.04, 0.15), st.floats(0.02, 0.28)), min_size=3, max_size=5),
       epsilon=st.sampled_from([0.1, 0.2]))
# a zigzag whose third increment reaches a split vertex duplicated by the second: its copies
# must all count as split vertices (the compiled and Python disconnections keep the number on
# different copies)
@example(steps=[(0.125, 0.0625), (0.0625, 0.25), (0.125, 0.0625), (0.125, 0.25)], epsilon=0.1)
# the first increment ends inside the beam: the faces it opens are not duplicated yet, and their
# vertices are on the wound all the same
@example(steps=[(0.140625, 0.0625), (0.0859375, 0.1953125), (0.046875, 0.0625)], epsilon=0.1)
def test_compiled_progressive_cut_equals_the_python_operators(steps, epsilon):
    """A blade through the beam's height moving forward along a kinked path (x grows, y
    jumps), cut increment by increment (``progressive``): the compiled insertion gives the
    mesh, the counts and the vertices on the wound and made by splits (by rest position) of
    the Python operators after every increment. An element the blade has only partly crossed
    waits, but it is around a crossed edge, so the compiled region must hold it for the edge's
    general flip (as the Python operators see it); without it the flips were refused and the
    cut left slivers. A general flip's equally good triangulations (within 1e-12) tie, and its
    ring starts at its first vertex by rest position, so ties break alike whatever numbers the
    two insertions give out; the improvement still visits elements of equal quality in the
    order of their numbers, so the beam's inner vertices are perturbed (a regular beam's
    symmetric elements tie exactly)."""
    from wcut.cut.surface import strip

    mesh = perturbed(beam(6, 3, 3, size=(0.6, 0.3, 0.3)), 0.1)
    x = 0.02 + np.cumsum([dx for dx, _ in steps])
    blades = [np.array([[xi, y, -0.05], [xi, y, 0.35]]) for xi, (_, y) in zip(x, steps)]
    runs = []
    with canonical_general_flips():
        for compiled in (False, True):
            topo = TetTopology(mesh)
            cutter = Cutter(topo, epsilon=epsilon, compiled=compiled)
            after_each = []
            for before, after in zip(blades, blades[1:]):
                piece = strip(before, after)
                if piece is None:
                    continue
                stats = dataclasses.asdict(cutter.cut(piece, progressive=True, rest=True).stats)
                check_topology(topo)
                stats["refused"] = len(stats["refused"])
                marked = [sorted(map(tuple, np.round(topo.rest_positions[sorted(vertices)], 12).tolist()))
                          for vertices in (cutter.wound_vertices, cutter.split_vertices)]  # (as element_set)
                after_each.append((element_set(topo.to_mesh()), stats, marked))
            runs.append(after_each)
    assert runs[0] == runs[1]
