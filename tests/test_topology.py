"""Tests of wcut.topology: the local operators, the adjacency they keep and the change record (thesis 5.1)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from wcut.errors import WcutError
from wcut.mesh import TET_FACES, TetMesh, beam
from wcut.topology import (TetTopology, TopologyError, bisect_edge, check_topology, connected_components,
                           contract_edge, duplicate_vertex, face_key, flip23, move_vertex, remove_edge, sew_unopened,
                           split_face, split_tet, tet_qualities, tet_quality, unsew_face, vertex_fans)
from wcut.topology.mesh import POSITION, REST, VELOCITY, signed_volume
from wcut.topology.operators import _link_condition

from conftest import nonconvex_pair, pyramid, ring, single_tet, two_tets

# ---------------------------------------------------------------------------------------------
# shared helpers

#: positions = rest @ POS_MAP.T + POS_SHIFT (a rotation times a stretch-and-shear), velocities
#: = rest @ VEL_MAP.T + VEL_SHIFT: affine maps, so barycentric interpolation must reproduce them.
_ANGLE = 0.7
_AXIS = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)
_K = np.array([[0, -_AXIS[2], _AXIS[1]], [_AXIS[2], 0, -_AXIS[0]], [-_AXIS[1], _AXIS[0], 0]])
ROTATION = np.eye(3) + np.sin(_ANGLE) * _K + (1 - np.cos(_ANGLE)) * _K @ _K
POS_MAP = ROTATION @ np.array([[1.2, 0.1, 0.0], [0.0, 0.9, 0.05], [0.0, 0.0, 1.1]])
POS_SHIFT = np.array([0.3, -0.2, 1.5])
VEL_MAP = np.array([[0.1, -0.4, 0.2], [0.3, 0.0, 0.1], [-0.2, 0.5, 0.3]])
VEL_SHIFT = np.array([1.0, -2.0, 0.5])

BEAM_SIZE = (1.0, 0.8, 0.6)
FAST = dict(deadline=None, derandomize=True, database=None, suppress_health_check=[HealthCheck.too_slow])


MESHES = {
    "tet": single_tet,
    "pair": two_tets,
    "ring4": lambda: ring(4),
    "ring6": lambda: ring(6),
    "beam": lambda: beam(2, 2, 2, size=BEAM_SIZE),
    "kuhn": lambda: beam(3, 2, 2, size=BEAM_SIZE, tets_per_hex=6),
}
BEAMS = ["beam", "kuhn"]


def make_topology(mesh: TetMesh) -> TetTopology:
    """A topology whose positions and velocities are the affine maps of the rest positions."""
    x = mesh.vertices
    return TetTopology(mesh, positions=x @ POS_MAP.T + POS_SHIFT, velocities=x @ VEL_MAP.T + VEL_SHIFT)


def topology(name: str) -> TetTopology:
    return make_topology(MESHES[name]())


def volume(topo: TetTopology) -> float:
    return float(topo.to_mesh().volumes().sum())


def assert_affine(topo: TetTopology) -> None:
    """Positions and velocities are still the affine maps of the rest positions."""
    x = topo.rest_positions
    np.testing.assert_allclose(topo.positions, x @ POS_MAP.T + POS_SHIFT, rtol=0, atol=1e-12)
    np.testing.assert_allclose(topo.velocities, x @ VEL_MAP.T + VEL_SHIFT, rtol=0, atol=1e-12)


def snapshot(topo: TetTopology) -> dict:
    """A deep copy of everything an operator may change."""
    return dict(
        tets=topo.tets[: topo.slot_count].copy(), alive=topo.alive[: topo.slot_count].copy(),
        slot_count=topo.slot_count, free=list(topo._free), vertex_count=topo.vertex_count,
        vertex_data=topo.vertex_data[: topo.vertex_count].copy(),
        face_tets={k: list(v) for k, v in topo.face_tets.items()},
        vertex_tets=[set(s) for s in topo.vertex_tets], unsewn=set(topo.unsewn),
    )


def assert_unchanged(topo: TetTopology, snap: dict) -> None:
    now = snapshot(topo)
    assert now.keys() == snap.keys()
    for key, value in snap.items():
        if isinstance(value, np.ndarray):
            assert np.array_equal(now[key], value), key
        else:
            assert now[key] == value, key


def assert_refused(topo: TetTopology, operator, *args, match: str | None = None, **kwargs) -> None:
    """The operator raises TopologyError and leaves the mesh exactly as it was."""
    snap = snapshot(topo)
    with pytest.raises(TopologyError, match=match):
        operator(topo, *args, **kwargs)
    assert_unchanged(topo, snap)


def applied(topo: TetTopology, operator, *args, tets: int | None = None, vertices: int = 0, **kwargs):
    """Apply an operator that must succeed; check the mesh, the counts and the attributes."""
    v0, n0, t0 = volume(topo), topo.vertex_count, topo.tet_count
    result = operator(topo, *args, **kwargs)
    check_topology(topo, v0)
    if tets is not None:
        assert topo.tet_count == t0 + tets
    assert topo.vertex_count == n0 + vertices
    assert_affine(topo)
    return result


def attempt(topo: TetTopology, operator, *args, **kwargs):
    """Apply an operator that may refuse: True if applied (mesh valid), False if refused (untouched)."""
    v0, snap = volume(topo), snapshot(topo)
    try:
        operator(topo, *args, **kwargs)
    except TopologyError:
        assert_unchanged(topo, snap)
        return False
    check_topology(topo, v0)
    assert_affine(topo)
    return True


def barycentric(corners: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of ``point`` in the tetrahedron with (4, 3) ``corners``."""
    lam = np.linalg.solve((corners[1:] - corners[0]).T, point - corners[0])
    return np.concatenate([[1 - lam.sum()], lam])


def edges(topo: TetTopology) -> list[tuple[int, int]]:
    return [tuple(e) for e in topo.to_mesh().edges().tolist()]


def boundary_edges(topo: TetTopology) -> set[tuple[int, int]]:
    """Edges of boundary faces, computed from the boundary triangles."""
    out = set()
    for tri in topo.boundary_faces().tolist():
        for i in range(3):
            out.add(tuple(sorted((tri[i], tri[(i + 1) % 3]))))
    return out


def interior_faces(topo: TetTopology) -> list[tuple[int, int, int]]:
    return sorted(k for k, owners in topo.face_tets.items() if len(owners) == 2)


def exterior_faces(topo: TetTopology) -> list[tuple[int, int, int]]:
    return sorted(k for k, owners in topo.face_tets.items() if len(owners) == 1)


def first_applied(topo: TetTopology, candidates, operator):
    """Apply ``operator(topo, c)`` to the first candidate it accepts; return that candidate."""
    for c in candidates:
        if attempt(topo, operator, *c):
            return c
    raise AssertionError("no candidate accepted")


def before_change(topo: TetTopology):
    """What check_change needs of the mesh before a change."""
    return topo.vertex_data[: topo.vertex_count].copy(), topo.tets[topo.live_tets()].copy()


def check_change(change, before, topo: TetTopology, *, parents: bool = True) -> None:
    """The change expresses the mesh now in the mesh ``before`` (with ``parents``: parents contain children)."""
    old_data, old_tets = before
    new_data = topo.vertex_data[: topo.vertex_count]
    new_tets = topo.tets[topo.live_tets()]
    assert (change.vertex_count_before, change.vertex_count_after) == (len(old_data), len(new_data))
    assert (change.element_count_before, change.element_count_after) == (len(old_tets), len(new_tets))
    # vertices: every attribute is the weighted sum of old ones
    sources, weights = change.vertex_sources, change.vertex_weights
    assert sources.shape == weights.shape and sources.shape[0] == len(new_data)
    assert sources.min() >= 0 and sources.max() < len(old_data)
    np.testing.assert_allclose(weights.sum(axis=1), 1.0, rtol=0, atol=1e-12)
    interpolated = np.einsum("vk,vkj->vj", weights, old_data[sources])
    np.testing.assert_allclose(interpolated[:, REST], new_data[:, REST], rtol=0, atol=1e-12)
    np.testing.assert_allclose(interpolated[:, POSITION], new_data[:, POSITION], rtol=0, atol=1e-12)
    np.testing.assert_allclose(interpolated[:, VELOCITY], new_data[:, VELOCITY], rtol=0, atol=1e-12)
    assert np.array_equal(change.new_vertices, np.arange(len(old_data), max(len(old_data), len(new_data))))
    for v, parent in enumerate(change.vertex_parent_element.tolist()):
        if parent >= 0 and parents:
            lam = barycentric(old_data[old_tets[parent], REST], new_data[v, REST])
            assert lam.min() >= -1e-9, f"vertex {v} is not in its parent element {parent}: {lam}"
    # elements
    added = set(change.added_elements.tolist())
    parent, changed = change.element_parent, change.element_rest_changed
    assert len(parent) == len(changed) == len(new_tets)
    assert len(new_tets) == len(old_tets) - len(change.removed_elements) + len(added)
    assert all(changed[i] for i in added)
    kept = [i for i in range(len(new_tets)) if i not in added]
    assert len({int(parent[i]) for i in kept}) == len(kept)
    assert set(range(len(old_tets))) - {int(parent[i]) for i in kept} == set(change.removed_elements.tolist())
    for i in kept:
        if not changed[i]:
            assert np.array_equal(new_data[new_tets[i], REST], old_data[old_tets[parent[i]], REST]), \
                f"element {i} changed its rest shape but is not flagged"
    for i in sorted(added) if parents else ():
        centroid = new_data[new_tets[i], REST].mean(axis=0)
        lam = barycentric(old_data[old_tets[parent[i]], REST], centroid)
        assert lam.min() >= -1e-9, f"added element {i} {new_tets[i].tolist()} is not in its parent " \
                                   f"{int(parent[i])} {old_tets[parent[i]].tolist()}: {lam}"


def plane_vertices(topo: TetTopology, axis: int, value: float) -> list[int]:
    return np.flatnonzero(np.isclose(topo.rest_positions[:, axis], value, rtol=0, atol=1e-12)).tolist()


def cut_along_plane(topo: TetTopology, axis: int, value: float, limit: float = np.inf) -> dict[int, list[int]]:
    """Unsew the faces in plane x[axis] = value (partial: next coordinate < limit), duplicate; copies per vertex."""
    on = set(plane_vertices(topo, axis, value))
    rest = topo.rest_positions
    for key in interior_faces(topo):
        if set(key) <= on and rest[list(key), (axis + 1) % 3].mean() < limit:
            unsew_face(topo, key)
    return {v: duplicate_vertex(topo, v) for v in sorted(on)}


# ---------------------------------------------------------------------------------------------
# split 1-4


@pytest.mark.parametrize("name", MESHES)
def test_split_tet_adds_three_elements_and_one_vertex(name):
    """1-4 split: +3 elements, +1 vertex at the weighted combination of all attributes."""
    topo = topology(name)
    weights = np.array([0.1, 0.2, 0.3, 0.4])
    for t in topo.live_tets()[:6].tolist():
        tet = topo.tet(t)
        expected = weights @ topo.vertex_data[tet]
        p, new = applied(topo, split_tet, t, weights, tets=3, vertices=1)
        np.testing.assert_allclose(topo.vertex_data[p], expected, rtol=0, atol=1e-14)
        assert len(new) == 4 and all(p in topo.tet(s) for s in new)
        assert topo.vertex_tets[p] == set(new)
        assert {v for s in new for v in topo.tet(s)} == set(tet) | {p}


# ---------------------------------------------------------------------------------------------
# face split 1-3 (boundary) and 2-6 (interior)


@pytest.mark.parametrize("name", MESHES)
def test_split_boundary_face_is_one_to_three(name):
    """Split of a boundary face: +2 elements, vertex on the face, volume kept."""
    base = topology(name)
    weights = np.array([0.5, 0.3, 0.2])
    for key in exterior_faces(base)[:8]:
        topo = topology(name)
        expected = weights @ topo.vertex_data[list(key)]
        p, new = applied(topo, split_face, key, weights, tets=2, vertices=1)
        np.testing.assert_allclose(topo.vertex_data[p], expected, rtol=0, atol=1e-14)
        assert len(new) == 3 and key not in topo.face_tets
        assert topo.is_boundary_vertex(p)


@pytest.mark.parametrize("name", MESHES)
def test_split_interior_face_is_two_to_six(name):
    """Split of an interior face: both elements split, +4 elements, the face gone."""
    base = topology(name)
    weights = np.array([0.25, 0.35, 0.4])
    for key in interior_faces(base)[:8]:
        topo = topology(name)
        expected = weights @ topo.vertex_data[list(key)]
        p, new = applied(topo, split_face, key, weights, tets=4, vertices=1)
        np.testing.assert_allclose(topo.vertex_data[p], expected, rtol=0, atol=1e-14)
        assert len(new) == 6 and key not in topo.face_tets
        assert not topo.is_boundary_vertex(p)


# ---------------------------------------------------------------------------------------------
# flip 2-3


def test_flip23_on_convex_pair():
    """Flip 2-3 of a convex pair: three elements around the new edge between the apices."""
    topo = make_topology(two_tets())
    new = applied(topo, flip23, (0, 1, 2), tets=1)
    assert len(new) == 3 and (0, 1, 2) not in topo.face_tets
    assert topo.edge_tets(3, 4) == set(new)


def test_flip23_quality_drop_refuses_a_flip_that_loses_too_much_quality():
    """With ``quality_drop``, a flip whose worst element falls below that fraction of the worse
    replaced element's quality is refused (mesh untouched); just above it, it is made."""
    probe = make_topology(two_tets())
    rest = probe.rest_positions
    before = tet_qualities(rest[probe.tets[probe.face_tets[(0, 1, 2)]]]).min()
    new = flip23(probe, (0, 1, 2))
    ratio = tet_qualities(probe.rest_positions[probe.tets[new]]).min() / before
    assert_refused(make_topology(two_tets()), flip23, (0, 1, 2), quality_drop=1.01 * ratio, match="quality")
    applied(make_topology(two_tets()), flip23, (0, 1, 2), quality_drop=0.99 * ratio, tets=1)


def test_tet_quality_matches_tet_qualities_to_the_last_bit():
    """The plain-float quality of one element is the numpy batch's, bit for bit (the operators
    use one, the checks the other)."""
    rng = np.random.default_rng(3)
    corners = rng.normal(size=(200, 4, 3)) * 10.0 ** rng.integers(-3, 3, size=(200, 1, 1))
    batch = tet_qualities(np.concatenate([corners, corners]))  # > SMALL_BATCH: the numpy path
    assert [tet_quality(*c) for c in corners.tolist()] == batch[:200].tolist()


@pytest.mark.parametrize("name", BEAMS)
def test_flip23_on_every_interior_face(name):
    """Flip 2-3 of each beam face: +1 element or untouched (Kuhn: apex segments hit edges, all refused)."""
    accepted = 0
    for key in interior_faces(topology(name)):
        topo = topology(name)
        owners = topo.face_tets[key]
        d, e = (next(v for v in topo.tet(t) if v not in key) for t in owners)
        n0 = topo.tet_count
        if attempt(topo, flip23, key):
            accepted += 1
            assert topo.tet_count == n0 + 1 and len(topo.edge_tets(d, e)) == 3
    assert (accepted > 0) == (name == "beam")


# ---------------------------------------------------------------------------------------------
# general flip (edge removal)


@pytest.mark.parametrize("n", [3, 4, 5, 6])
def test_remove_interior_edge_of_ring(n):
    """General flip of an interior edge with n elements: 2(n - 2) elements, the edge gone."""
    topo = make_topology(ring(n))
    new = applied(topo, remove_edge, 0, 1, tets=2 * (n - 2) - n)
    assert len(new) == 2 * (n - 2) and not topo.edge_tets(0, 1)


@pytest.mark.parametrize("name", BEAMS)
def test_remove_every_edge_of_beam(name):
    """General flip of each beam edge: n -> 2(m - 2) for an m-gon when accepted, else untouched."""
    accepted = {True: 0, False: 0}
    for a, b in edges(topology(name)):
        topo = topology(name)
        ring_tets, polygon, closed = topo.edge_ring(a, b)
        n0 = topo.tet_count
        if attempt(topo, remove_edge, a, b):
            accepted[closed] += 1
            assert topo.tet_count == n0 - len(ring_tets) + 2 * (len(polygon) - 2)
            assert not topo.edge_tets(a, b)
    assert accepted[True] > 0 and accepted[False] > 0


def test_remove_boundary_edge_with_coplanar_faces_keeps_volume():
    """General flip of a boundary edge between coplanar faces: accepted, volume kept (2 -> 2)."""
    topo = make_topology(pyramid(0.0))
    ring_tets, polygon, closed = topo.edge_ring(0, 1)
    assert not closed and len(polygon) == len(ring_tets) + 1 == 3
    new = applied(topo, remove_edge, 0, 1, tets=0)
    assert len(new) == 2 and not topo.edge_tets(0, 1) and topo.edge_tets(2, 3)


def test_remove_boundary_edge_with_bent_faces_changes_volume_only_when_allowed():
    """General flip of a boundary feature edge: refused, unless a volume change is allowed."""
    topo = make_topology(pyramid(0.3))
    assert_refused(topo, remove_edge, 0, 1, match="volume")
    v0 = volume(topo)
    remove_edge(topo, 0, 1, allow_volume_change=True)
    check_topology(topo)
    assert abs(volume(topo) - v0) > 1e-3 * v0


# ---------------------------------------------------------------------------------------------
# edge bisection


@pytest.mark.parametrize("name", MESHES)
def test_bisect_edge_splits_every_element_around_it(name):
    """Bisection of an edge in k elements: +k elements, +1 vertex on the edge."""
    for a, b in edges(topology(name))[:12]:
        topo = topology(name)
        k = len(topo.edge_tets(a, b))
        expected = 0.7 * topo.vertex_data[a] + 0.3 * topo.vertex_data[b]
        m, new = applied(topo, bisect_edge, a, b, 0.3, tets=k, vertices=1)
        np.testing.assert_allclose(topo.vertex_data[m], expected, rtol=0, atol=1e-14)
        assert len(new) == 2 * k and not topo.edge_tets(a, b)
        assert len(topo.edge_tets(a, m)) == len(topo.edge_tets(m, b)) == k


# ---------------------------------------------------------------------------------------------
# vertex move


def _grid_vertex(i, j, k, ny=2, nz=2):
    """Index of grid vertex (i, j, k) of a beam of ny x nz cells in y and z."""
    return (i * (ny + 1) + j) * (nz + 1) + k


def test_move_interior_vertex():
    """Moving the beam's interior vertex toward a neighbour keeps a valid mesh and the volume."""
    topo = topology("beam")
    v, u = _grid_vertex(1, 1, 1), _grid_vertex(0, 1, 1)
    expected = 0.8 * topo.vertex_data[v] + 0.2 * topo.vertex_data[u]
    applied(topo, move_vertex, v, [v, u], [0.8, 0.2])
    np.testing.assert_allclose(topo.vertex_data[v], expected, rtol=0, atol=1e-14)


def test_move_boundary_vertex_within_its_flat_face():
    """A vertex in the middle of a flat boundary face may slide within the face."""
    topo = topology("beam")
    v, u = _grid_vertex(1, 1, 0), _grid_vertex(0, 1, 0)
    applied(topo, move_vertex, v, [v, u], [0.75, 0.25])
    assert topo.rest_positions[v, 2] == 0.0


def test_move_vertex_refusals():
    """Moves that invert an element, or push a boundary vertex off its face, are refused."""
    topo = topology("beam")
    center, left = _grid_vertex(1, 1, 1), _grid_vertex(0, 1, 1)
    assert_refused(topo, move_vertex, center, [center, left], [-0.5, 1.5])  # beyond the boundary
    assert_refused(topo, move_vertex, center, [center, left], [0.0, 1.0])  # onto a vertex: flat
    face, inner = _grid_vertex(1, 1, 0), _grid_vertex(1, 1, 1)
    assert_refused(topo, move_vertex, face, [face, inner], [0.9, 0.1], match="off its boundary")


def test_move_vertex_in_a_deformed_body_keeps_its_strain_with_current():
    """A move in the rest configuration carries the current position by the same weights. In a
    body squeezed where it is now (a neighbour pushed halfway to the vertex), that stretches an
    element of the star 12% beyond anything it had: refused with ``current``, made without it;
    in an undeformed body the same move is made either way."""
    center, left = _grid_vertex(1, 1, 1), _grid_vertex(0, 1, 1)
    for shift, refused in ((0.0, False), (0.5, True)):
        mesh = MESHES["beam"]()
        squeezed = mesh.vertices.copy()
        squeezed[left] += shift * (squeezed[center] - squeezed[left])
        topo = TetTopology(mesh, positions=squeezed)
        if refused:
            assert_refused(topo, move_vertex, center, [center, left], [0.6, 0.4], current=True,
                           match="of its rest volume in the current configuration")
        move_vertex(topo, center, [center, left], [0.6, 0.4], current=not refused)
        np.testing.assert_allclose(topo.positions[center], 0.6 * squeezed[center] + 0.4 * squeezed[left])


# ---------------------------------------------------------------------------------------------
# refusals of the other operators


REFUSALS = {
    "split_tet zero weight": (single_tet, split_tet, (0, [0.0, 0.3, 0.3, 0.4]), "flat|inverted"),
    "split_tet negative weight": (single_tet, split_tet, (0, [-0.1, 0.4, 0.4, 0.3]), "inverted"),
    "split_tet on a vertex": (single_tet, split_tet, (0, [1.0, 0.0, 0.0, 0.0]), "flat|inverted"),
    "split_tet nan": (single_tet, split_tet, (0, [np.nan, 0.3, 0.3, 0.4]), "barycentric weights"),
    "split_face on an edge": (two_tets, split_face, ((0, 1, 2), [0.5, 0.5, 0.0]), "flat|inverted"),
    "split_face outside": (two_tets, split_face, ((0, 1, 2), [-0.2, 0.6, 0.6]), "inverted"),
    "split_face boundary outside": (single_tet, split_face, ((0, 1, 2), [1.2, -0.1, -0.1]), "inverted"),
    "split_face missing face": (two_tets, split_face, ((0, 3, 4), [0.3, 0.3, 0.4]), "no such face"),
    "bisect at an end": (lambda: ring(4), bisect_edge, (0, 1, 0.0), "must be in"),
    "bisect beyond an end": (lambda: ring(4), bisect_edge, (0, 1, 1.3), "must be in"),
    "bisect missing edge": (two_tets, bisect_edge, (3, 4, 0.5), "no such edge"),
    "flip23 non-convex pair": (nonconvex_pair, flip23, ((0, 1, 2),), "does not cross"),
    "flip23 boundary face": (two_tets, flip23, ((0, 1, 3),), "not an interior face"),
    "remove_edge with one element": (single_tet, remove_edge, (0, 1), "only 2 vertices"),
    "remove_edge missing edge": (two_tets, remove_edge, (3, 4), "not in the mesh"),
    "remove_edge bent boundary": (lambda: pyramid(0.3), remove_edge, (0, 1), "volume"),
    "contract_edge missing edge": (two_tets, contract_edge, (3, 4), "no such edge"),
    "contract_edge of a vertex of before": (MESHES["beam"], contract_edge, (13, 1), "not made by the change"),
    "unsew boundary face": (two_tets, unsew_face, ((0, 1, 3),), "not an interior face"),
}


@pytest.mark.parametrize("case", REFUSALS)
def test_refusal_leaves_mesh_untouched(case):
    """A refused operator raises TopologyError (a WcutError) and changes nothing."""
    factory, operator, args, reason = REFUSALS[case]
    assert issubclass(TopologyError, WcutError)
    assert_refused(make_topology(factory()), operator, *args, match=reason)


# ---------------------------------------------------------------------------------------------
# edge ring


def assert_ring(topo: TetTopology, a: int, b: int) -> bool:
    """Check the structure of edge_ring(a, b); return whether it is closed."""
    tets, polygon, closed = topo.edge_ring(a, b)
    assert set(tets) == topo.edge_tets(a, b) and len(set(tets)) == len(tets)
    assert len(polygon) == len(tets) + (0 if closed else 1)
    rest = topo.rest_positions
    for i, t in enumerate(tets):
        p, q = polygon[i], polygon[(i + 1) % len(polygon)]
        assert set(topo.tet(t)) == {a, b, p, q}
        assert signed_volume(rest[a], rest[b], rest[p], rest[q]) > 0
    for i in range(len(tets) if closed else len(tets) - 1):  # consecutive elements share a face
        s, t = tets[i], tets[(i + 1) % len(tets)]
        assert sorted(topo.face_tets[face_key(a, b, polygon[(i + 1) % len(polygon)])]) == sorted((s, t))
    return closed


@pytest.mark.parametrize("n", [3, 4, 6])
def test_edge_ring_of_ring_mesh(n):
    """The axis of a ring is a closed ring of n elements; a spoke is an open ring of two."""
    topo = make_topology(ring(n))
    assert assert_ring(topo, 0, 1) and assert_ring(topo, 1, 0)
    assert len(topo.edge_ring(0, 1)[0]) == n
    assert not assert_ring(topo, 0, 2) and len(topo.edge_ring(0, 2)[0]) == 2
    assert not assert_ring(topo, 2, 3) and len(topo.edge_ring(2, 3)[0]) == 1


@pytest.mark.parametrize("name", BEAMS)
def test_edge_ring_closed_exactly_for_interior_edges(name):
    """Every beam edge's ring is well ordered, closed iff the edge is not on the boundary."""
    topo = topology(name)
    on_boundary = boundary_edges(topo)
    for a, b in edges(topo):
        assert assert_ring(topo, a, b) == ((a, b) not in on_boundary)


# ---------------------------------------------------------------------------------------------
# unsew and duplicate


@pytest.mark.parametrize("name", BEAMS)
def test_cut_along_grid_plane_separates_in_two(name):
    """Unsewing a grid plane and duplicating its vertices: each plane vertex gets one copy, two pieces."""
    topo = topology(name)
    v0, n0 = volume(topo), topo.vertex_count
    x = BEAM_SIZE[0] / (2 if name == "beam" else 3)
    on = plane_vertices(topo, 0, x)
    assert len(on) == 9
    before = before_change(topo)
    topo.begin_change()
    copies = cut_along_plane(topo, 0, x)
    change = topo.end_change()
    assert all(len(c) == 1 for c in copies.values())
    assert topo.vertex_count == n0 + len(on)
    check_topology(topo, v0)
    assert_affine(topo)
    for v, (w,) in copies.items():
        assert np.array_equal(topo.vertex_data[w], topo.vertex_data[v])
        assert len(vertex_fans(topo, v)) == len(vertex_fans(topo, w)) == 1
    mesh = topo.to_mesh()
    labels = connected_components(mesh)
    assert labels.max() == 1
    centroids = mesh.vertices[mesh.tets].mean(axis=1)[:, 0]
    assert len(set(labels[centroids < x])) == len(set(labels[centroids > x])) == 1
    assert not topo.unsewn
    check_change(change, before, topo)
    originals = {w: v for v, (w,) in copies.items()}
    assert change.vertex_sources[n0:, 0].tolist() == [originals[w] for w in range(n0, topo.vertex_count)]


def splits_a_fan(key, on_boundary) -> bool:
    """Whether unsewing ``key`` alone splits a fan: (v, x, y) with (v, x), (v, y) boundary edges."""
    return any({tuple(sorted((v, x))) for x in key if x != v} <= on_boundary for v in key)


@pytest.mark.parametrize("name", BEAMS)
def test_unsew_single_interior_face_creates_no_copy(name):
    """One unsewn face that splits no fan creates no copy; sew_unopened binds it again."""
    base = topology(name)
    on_boundary = boundary_edges(base)
    faces = [k for k in interior_faces(base) if not splits_a_fan(k, on_boundary)]
    assert len(faces) >= 10
    for key in faces[:: len(faces) // 10]:
        topo = topology(name)
        snap = snapshot(topo)
        unsew_face(topo, key)
        assert topo.unsewn == {key} and topo.neighbors(topo.face_tets[key][0], key) == []
        for v in key:
            assert len(vertex_fans(topo, v)) == 1
            assert duplicate_vertex(topo, v) == []
        check_topology(topo, volume(topo))
        assert sew_unopened(topo) == 1
        assert_unchanged(topo, snap)


# ---------------------------------------------------------------------------------------------
# the change record


def _change_split_tet(topo):
    split_tet(topo, 5, [0.1, 0.2, 0.3, 0.4])


def _change_split_faces(topo):
    split_face(topo, exterior_faces(topo)[3], [0.2, 0.3, 0.5])
    split_face(topo, interior_faces(topo)[7], [0.4, 0.3, 0.3])


def _change_flip23(topo):
    first_applied(topo, [(k,) for k in interior_faces(topo)], flip23)


def _change_remove_edge(topo):
    on_boundary = boundary_edges(topo)
    first_applied(topo, [e for e in edges(topo) if e not in on_boundary], remove_edge)


def _change_bisect(topo):
    bisect_edge(topo, *edges(topo)[10], 0.35)


def _change_move(topo):
    v = _grid_vertex(1, 1, 1)
    move_vertex(topo, v, [v, _grid_vertex(1, 2, 1), _grid_vertex(1, 1, 2)], [0.8, 0.1, 0.1])


def _change_contract(topo):
    """A 1-4 split and a face split, then the split vertex merged into a neighbour: the face
    split's vertex, the last, takes its number."""
    p, _ = split_tet(topo, 5, [0.1, 0.2, 0.3, 0.4])
    q, _ = split_face(topo, interior_faces(topo)[7], [0.4, 0.3, 0.3])
    first_applied(topo, [(p, u) for u in range(topo.vertex_count) if topo.edge_tets(p, u)], contract_edge)
    expected = topo.vertex_data[q].copy()
    assert topo.drop_orphans() == ({p}, {q: p})
    np.testing.assert_array_equal(topo.vertex_data[p], expected)
    check_topology(topo)


def test_contract_edge_keeps_a_vertex_on_its_boundary_and_its_elements_valid():
    """A vertex made on a boundary face merges into a corner of the face, but not into the
    vertex inside; dropped, it leaves the numbering as it was."""
    topo = topology("beam")
    count = topo.vertex_count
    topo.begin_change()
    face = exterior_faces(topo)[3]
    p, _ = split_face(topo, face, [0.2, 0.3, 0.5])
    inner = next(u for t in topo.vertex_tets[p] for u in topo.tet(t) if u not in face and u != p)
    assert_refused(topo, contract_edge, p, inner, match="off its boundary")
    applied(topo, contract_edge, p, face[0])
    assert not topo.vertex_tets[p]
    assert topo.drop_orphans() == ({p}, {}) and topo.vertex_count == count
    check_topology(topo)


def test_the_link_condition_refuses_a_contraction_that_would_pinch_the_body():
    """In a beam one element thick every vertex is on the boundary: an edge through the body
    joins two of its sides, and contracting it would pinch them together however its elements
    tile the star. Two elements on a face: their apex may merge into a corner of the face."""
    topo = TetTopology(beam(2, 1, 1))
    through = sorted(set(edges(topo)) - boundary_edges(topo))
    assert through and not any(_link_condition(topo, u, w) or _link_condition(topo, w, u) for u, w in through)
    assert _link_condition(TetTopology(two_tets()), 3, 0)


def _change_sequence(topo):
    """Splits, then flips and moves on the new elements, then a cut."""
    p, new = split_tet(topo, 0, [0.25, 0.25, 0.25, 0.25])
    q, _ = split_face(topo, interior_faces(topo)[0], [0.3, 0.3, 0.4])
    apex = [(k,) for k in interior_faces(topo) if {p, q} & {v for t in topo.face_tets[k] for v in topo.tet(t)} - set(k)]
    first_applied(topo, apex, flip23)
    m, _ = bisect_edge(topo, *edges(topo)[20], 0.5)
    first_applied(topo, [(p, [p, u], [0.9, 0.1]) for u in range(topo.vertex_count) if topo.edge_tets(p, u)],
                  move_vertex)
    first_applied(topo, [(m, u) for u in range(topo.vertex_count) if topo.edge_tets(m, u)], remove_edge)
    cut_along_plane(topo, 0, BEAM_SIZE[0] / 2)


CHANGES = {
    "split_tet": _change_split_tet, "split_face": _change_split_faces, "flip23": _change_flip23,
    "remove_edge": _change_remove_edge, "bisect_edge": _change_bisect, "move_vertex": _change_move,
    "contract_edge": _change_contract, "sequence": _change_sequence,
}


@pytest.mark.parametrize("case", CHANGES)
def test_change_record_expresses_new_mesh_in_old(case):
    """begin/end_change: weights reproduce every vertex, parents contain new elements, counts agree."""
    topo = topology("beam")
    before = before_change(topo)
    topo.begin_change()
    CHANGES[case](topo)
    change = topo.end_change()
    check_topology(topo, float(TetMesh.trusted(before[0][:, REST], before[1]).volumes().sum()))
    check_change(change, before, topo)
    assert not change.is_empty


def test_change_flags_elements_around_moved_vertex():
    """A vertex move flags exactly the elements around the vertex as rest-changed."""
    topo = topology("beam")
    v = _grid_vertex(1, 1, 1)
    around = {int(np.searchsorted(topo.live_tets(), t)) for t in topo.vertex_tets[v]}
    topo.begin_change()
    _change_move(topo)
    change = topo.end_change()
    assert set(np.flatnonzero(change.element_rest_changed).tolist()) == around
    assert change.moved_vertices.tolist() == [v]
    assert len(change.added_elements) == len(change.removed_elements) == 0


def test_change_flags_elements_around_moved_duplicate():
    """Moving a vertex copy made in the same change flags the (kept) elements it reshapes."""
    topo = topology("beam")
    before = before_change(topo)
    topo.begin_change()
    copies = cut_along_plane(topo, 0, BEAM_SIZE[0] / 2)
    (w,) = copies[_grid_vertex(1, 1, 1)]
    u = next(u for u in range(topo.vertex_count) if u != w and topo.edge_tets(w, u)
             and topo.rest_positions[u, 0] == topo.rest_positions[w, 0])
    move_vertex(topo, w, [w, u], [0.8, 0.2])  # slides within the flat cut face
    change = topo.end_change()
    check_topology(topo)
    check_change(change, before, topo)


def test_empty_change_and_end_without_begin():
    """An empty change is the identity; end_change() without begin_change() raises TopologyError."""
    topo = topology("beam")
    before = before_change(topo)
    topo.begin_change()
    change = topo.end_change()
    assert change.is_empty and not change.element_rest_changed.any()
    check_change(change, before, topo)
    with pytest.raises(TopologyError):
        topo.end_change()


def test_drop_unused_vertices_after_deleting_a_corner():
    """Deleting a corner element and dropping its lone vertex renumbers consistently, in the change too."""
    topo = topology("beam")
    corner = next(iter(topo.vertex_tets[0]))
    assert len(topo.vertex_tets[0]) == 1
    before = before_change(topo)
    topo.begin_change()
    topo.replace_tets([corner], [])
    assert topo.drop_unused_vertices() == 1
    change = topo.end_change()
    check_topology(topo)
    assert_affine(topo)
    assert (topo.vertex_count, topo.tet_count) == (26, 39)
    check_change(change, before, topo)
    assert change.vertex_sources[:, 0].tolist() == list(range(1, 27))
    assert change.removed_elements.tolist() == [corner] and len(change.added_elements) == 0


def test_drop_unused_vertices_refused_after_creating_vertices():
    """Dropping vertices after creating some in the same change is refused."""
    topo = topology("beam")
    topo.begin_change()
    corner = next(iter(topo.vertex_tets[0]))
    split_tet(topo, next(t for t in topo.live_tets().tolist() if t != corner), [0.25] * 4)
    topo.replace_tets([corner], [])
    assert_refused(topo, lambda t: t.drop_unused_vertices())


# ---------------------------------------------------------------------------------------------
# random sequences (hypothesis)


def _draw_weights(data, k: int, smallest: float = 0.05) -> np.ndarray:
    """Random barycentric weights of k points, each at least ``smallest``."""
    x = np.array(data.draw(st.lists(st.floats(0.01, 1.0), min_size=k, max_size=k)))
    return smallest + (1 - k * smallest) * x / x.sum()


def _draw(data, items):
    return items[data.draw(st.integers(0, len(items) - 1))]


def _random_operation(topo: TetTopology, data):
    """A random operator with random arguments on the current mesh: (name, args)."""
    kind = data.draw(st.sampled_from(["split_tet", "split_face", "flip23", "bisect_edge", "remove_edge",
                                      "move_vertex", "unsew_face", "duplicate_vertex", "sew_unopened", "cut",
                                      "contract_edge"]))
    made = [v for v in range(topo.first_new_vertex, topo.vertex_count) if topo.vertex_tets[v]]
    if kind == "contract_edge" and made:  # a vertex made in this change merged into a neighbour
        v = _draw(data, made)
        return contract_edge, (v, _draw(data, sorted({w for t in topo.vertex_tets[v] for w in topo.tet(t)} - {v})))
    if kind == "contract_edge":
        kind = "split_tet"
    if kind == "cut":  # a full or partial cut along a grid plane of the beam
        axis = data.draw(st.integers(0, 2))
        limit = data.draw(st.sampled_from([np.inf, 0.5 * BEAM_SIZE[(axis + 1) % 3]]))
        return cut_along_plane, (axis, 0.5 * BEAM_SIZE[axis], limit)
    if kind == "split_tet":
        return split_tet, (int(_draw(data, topo.live_tets())), _draw_weights(data, 4))
    if kind in ("split_face", "flip23", "unsew_face"):
        key = _draw(data, sorted(topo.face_tets))
        return {"split_face": split_face, "flip23": flip23, "unsew_face": unsew_face}[kind], \
            ((key, _draw_weights(data, 3)) if kind == "split_face" else (key,))
    if kind in ("bisect_edge", "remove_edge"):
        a, b = _draw(data, edges(topo))
        if kind == "bisect_edge":
            return bisect_edge, (a, b, data.draw(st.floats(0.05, 0.95)))
        return remove_edge, (a, b)
    used = [v for v in range(topo.vertex_count) if topo.vertex_tets[v]]
    v = _draw(data, used)
    if kind == "move_vertex":
        u = _draw(data, sorted({w for t in topo.vertex_tets[v] for w in topo.tet(t)} - {v}))
        s = data.draw(st.floats(0.05, 0.45))
        return move_vertex, (v, [v, u], [1 - s, s])
    if kind == "duplicate_vertex":
        return duplicate_vertex, (v,)
    return (lambda topo: sew_unopened(topo)), ()


@settings(max_examples=40, **FAST)
@given(data=st.data())
def test_random_operator_sequences_keep_the_mesh_valid(data):
    """Random operator sequences on a beam: valid after each step, refusals untouched, change exact."""
    topo = topology("beam")
    before = before_change(topo)
    topo.begin_change()
    for _ in range(data.draw(st.integers(5, 15))):
        operator, args = _random_operation(topo, data)
        attempt(topo, operator, *args)  # checks the mesh when applied, its integrity when refused
    orphans = {v for v in range(topo.first_new_vertex, topo.vertex_count) if not topo.vertex_tets[v]}
    count = topo.vertex_count
    dropped, moved = topo.drop_orphans()  # the vertices contractions left without elements
    assert dropped == orphans and topo.vertex_count == count - len(orphans)
    assert set(moved) <= set(range(topo.vertex_count, count)) and set(moved.values()) <= orphans
    check_topology(topo)
    assert_affine(topo)
    # parents are checked per operator by test_change_record_expresses_new_mesh_in_old
    check_change(topo.end_change(), before, topo, parents=False)


@settings(max_examples=30, **FAST)
@given(data=st.data())
def test_the_boundary_faces_at_a_vertex_are_its_faces_of_one_element(data):
    """After random operations (unsewn faces and copies among them), the boundary faces through
    each vertex, counted in its star alone, are the faces through it that one element holds,
    ordered as that element's outward face; ``is_boundary_vertex`` and ``is_boundary_edge``
    agree with them."""
    topo = topology("beam")
    for _ in range(data.draw(st.integers(0, 8))):
        operator, args = _random_operation(topo, data)
        attempt(topo, operator, *args)
    for v in range(topo.vertex_count):
        expected = {tri for t in topo.vertex_tets[v] for tri in map(tuple, topo.tets[t][TET_FACES].tolist())
                    if v in tri and topo.face_owner_count(*tri) == 1}
        found = topo.boundary_faces_at(v)
        assert len(found) == len(expected) and set(found) == expected
        assert topo.is_boundary_vertex(v) == bool(expected)
        for u in {u for tri in found for u in tri} - {v}:
            assert topo.is_boundary_edge(v, u)


@pytest.mark.parametrize("name", sorted(MESHES))
def test_new_topology_links_its_faces_when_read_as_at_once(name):
    """A new topology links its faces when they are first read (a compiled cut never reads
    them); they are then those of linking each element in order: the same keys, owners in
    element order, the dictionary in the order the faces were first met."""
    mesh = MESHES[name]()
    topo = TetTopology(mesh)
    assert [sorted(s) for s in topo.vertex_tets] == [sorted(np.flatnonzero((mesh.tets == v).any(axis=1)).tolist())
                                                     for v in range(mesh.vertex_count)]
    expected: dict = {}
    for t, tet in enumerate(mesh.tets.tolist()):
        for k in range(4):
            expected.setdefault(face_key(*(tet[:k] + tet[k + 1:])), []).append(t)
    assert sorted(topo.face_tets.items()) == sorted(expected.items())
    first_met = list(dict.fromkeys(key for keys in topo.slot_face_keys[: mesh.tet_count] for key in keys))
    assert list(topo.face_tets) == first_met
    check_topology(topo)
    unread = copy.deepcopy(TetTopology(mesh))  # faces not linked yet: a copy links them alike
    assert list(unread.face_tets.items()) == list(topo.face_tets.items())


def test_change_of_a_cut_holds_what_changed_and_lays_out_the_same_arrays(monkeypatch):
    """A change of a mesh whose slots are its elements' indices (no free slot) holds only what
    changed; read, its whole-mesh arrays are those of the laid-out record of the same journal,
    and its sparse answers the rows of those arrays: over compiled and Python cuts, where the
    Python operators free and reuse slots and swap vertices for their copies."""
    from wcut.cut import Cutter, Plane
    from wcut.topology.change import TopologyChange, _JournalChange

    journals = []
    record = TopologyChange.from_journal.__func__
    monkeypatch.setattr(TopologyChange, "from_journal",
                        classmethod(lambda cls, journal, topo: journals.append(journal) or record(cls, journal, topo)))
    topo = TetTopology(beam(6, 3, 3, size=(0.6, 0.3, 0.3)))
    rng = np.random.default_rng(5)
    sparse = 0
    for compiled, point, normal in [(True, [0.13, 0, 0], [1, 0.1, 0.2]), (False, [0.27, 0, 0], [1, -0.3, 0.1]),
                                    (True, [0.2, 0.15, 0], [0.1, 1, 0.3]), (False, [0.41, 0, 0.1], [0.2, 0.3, 1])]:
        change = Cutter(topo, epsilon=0.2, compiled=compiled).cut(Plane(point, normal)).change
        laid_out = TopologyChange._laid_out(journals[-1], topo)
        if not isinstance(change, _JournalChange):
            continue
        sparse += 1
        vertices = np.sort(rng.choice(change.vertex_count_after, 40, replace=False))
        elements = np.sort(rng.choice(change.element_count_after, 40, replace=False))
        sources, weights = change.vertex_rows(vertices)
        parents, rest_changed = change.element_parents(elements), change.rest_changed_elements()
        for name in TopologyChange.__dataclass_fields__:
            got, expected = getattr(change, name), getattr(laid_out, name)
            assert type(got) is type(expected) and np.array_equal(got, expected), name
            if isinstance(got, np.ndarray):
                assert got.dtype == expected.dtype, name
        assert np.array_equal(sources, laid_out.vertex_sources[vertices])
        assert np.array_equal(weights, laid_out.vertex_weights[vertices])
        assert np.array_equal(parents, laid_out.element_parent[elements])
        assert np.array_equal(rest_changed, np.flatnonzero(laid_out.element_rest_changed))
    assert sparse >= 2


class _FacesLinkedLater(TetTopology):
    """A topology whose every replacement leaves its faces to be linked when next read."""

    def replace_tets(self, removed, added, parents=None, qualities=None, *, link_faces=True):
        return super().replace_tets(removed, added, parents, qualities, link_faces=False)


@settings(max_examples=30, **FAST)
@given(data=st.data())
def test_faces_linked_later_equal_faces_linked_at_once(data):
    """``replace_tets(link_faces=False)`` (the compiled cutter's write-back) must leave, once the
    faces are read, exactly the adjacency that linking at once leaves: the same owners in the
    same order (later operators' choices follow it), the same face keys, the same vertex stars
    in the same iteration order, after any sequence of operators, some of which read the faces
    (and so link them) and some of which do not (so several replacements wait together)."""
    at_once = topology("beam")
    mesh = MESHES["beam"]()
    later = _FacesLinkedLater(mesh, positions=at_once.positions.copy(), velocities=at_once.velocities.copy())
    for _ in range(data.draw(st.integers(3, 12))):
        operator, args = _random_operation(at_once, data)
        outcomes = []
        for topo in (at_once, later):
            try:
                operator(topo, *args)
                outcomes.append(None)
            except TopologyError as exc:
                outcomes.append(str(exc))
        assert outcomes[0] == outcomes[1]
        assert [list(s) for s in later.vertex_tets] == [list(s) for s in at_once.vertex_tets]
        assert np.array_equal(later.tets[: later.slot_count], at_once.tets[: at_once.slot_count])
    assert list(later.face_tets.items()) == list(at_once.face_tets.items())
    live = at_once.live_tets()
    assert [later.slot_face_keys[t] for t in live] == [at_once.slot_face_keys[t] for t in live]
    assert later.unsewn == at_once.unsewn
    check_topology(later)


@settings(max_examples=60, **FAST)
@given(data=st.data())
def test_splits_near_element_boundaries_succeed_or_refuse_cleanly(data):
    """Splits with barycentric weights down to 1e-7 give a valid mesh or a clean refusal."""
    topo = topology("beam")
    n0, t0 = topo.vertex_count, topo.tet_count
    kind = data.draw(st.sampled_from(["split_tet", "split_face", "bisect_edge"]))
    k = {"split_tet": 4, "split_face": 3, "bisect_edge": 2}[kind]
    tiny = [10.0 ** -data.draw(st.floats(1, 7)) if data.draw(st.booleans()) else data.draw(st.floats(0.05, 1))
            for _ in range(k)]
    weights = np.array(tiny) / sum(tiny)
    if kind == "split_tet":
        operator, args, grow = split_tet, (int(_draw(data, topo.live_tets())), weights), 3
    elif kind == "split_face":
        key = _draw(data, sorted(topo.face_tets))
        operator, args, grow = split_face, (key, weights), 2 * len(topo.face_tets[key])
    else:
        a, b = _draw(data, edges(topo))
        operator, args, grow = bisect_edge, (a, b, float(weights[1])), len(topo.edge_tets(a, b))
    if attempt(topo, operator, *args):
        assert (topo.vertex_count, topo.tet_count) == (n0 + 1, t0 + grow)
    else:
        assert (topo.vertex_count, topo.tet_count) == (n0, t0)


# ---------------------------------------------------------------------------------------------
# rest_points: current configuration -> rest configuration


def _bend(rest: np.ndarray) -> np.ndarray:
    """A nonlinear deformation: x shifted by z^2 (a shear that grows with height), z sagging with x^2."""
    x, y, z = rest.T
    return np.c_[x + 0.8 * z**2, y + 0.1 * x * z, z - 0.5 * x**2]


def _points_in_elements(topo: TetTopology, count: int, seed: int = 0, floor: float = 0.05):
    """``count`` random (slot, weights) pairs: weights over the element's corners, each >= ``floor``."""
    rng = np.random.default_rng(seed)
    slots = rng.choice(topo.live_tets(), count)
    weights = floor + (1.0 - 4 * floor) * rng.dirichlet(np.ones(4), count)
    return slots, weights


@pytest.mark.parametrize("name", BEAMS)
def test_rest_points_is_the_identity_at_rest(name):
    topo = TetTopology(MESHES[name]())
    slots, weights = _points_in_elements(topo, 50)
    inside = np.einsum("pk,pkj->pj", weights, topo.rest_positions[topo.tets[slots]])
    outside = np.random.default_rng(1).uniform(-0.5, 1.5, (50, 3)) * BEAM_SIZE
    for points in (inside, outside, topo.rest_positions):
        np.testing.assert_allclose(topo.rest_points(points), points, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", BEAMS)
def test_rest_points_inverts_an_affine_deformation_inside_and_outside(name):
    """positions = A rest + b: every element has the same affine map, so rest_points(A X + b) = X
    wherever X is, in an element or outside the mesh (carried by a nearby element's map)."""
    topo = make_topology(MESHES[name]())
    slots, weights = _points_in_elements(topo, 60)
    inside = np.einsum("pk,pkj->pj", weights, topo.rest_positions[topo.tets[slots]])
    rng = np.random.default_rng(2)
    near = rng.uniform(-0.3, 1.3, (60, 3)) * BEAM_SIZE  # partly outside the box, some far outside
    near = near[np.any((near < 0) | (near > BEAM_SIZE), axis=1)]
    far = rng.uniform(5.0, 6.0, (10, 3))  # all far from the mesh: every element is searched
    assert len(near) > 20
    for X in (inside, near, far, np.concatenate([inside, far])):
        np.testing.assert_allclose(topo.rest_points(X @ POS_MAP.T + POS_SHIFT), X, rtol=0, atol=1e-9)
    assert topo.rest_points(inside[0] @ POS_MAP.T + POS_SHIFT).shape == (1, 3)  # one point (3,) -> (1, 3)


def test_rest_points_launches_again_when_more_elements_hold_a_point_than_it_made_room_for(monkeypatch):
    """A vertex lies in every element of its star: with room for one element per point, the
    location runs again with room for all, and maps the points as it does with room to spare."""
    import wcut.topology.mesh as mesh_module

    mesh = MESHES[BEAMS[0]]()
    topo = TetTopology(mesh, positions=_bend(mesh.vertices))
    n = topo.vertex_count
    points = np.concatenate([topo.positions, topo.positions[:5] + 1.0])  # vertices, and outside
    expected = topo.rest_points(points)
    monkeypatch.setattr(mesh_module, "HITS_PER_POINT", 1)
    np.testing.assert_array_equal(topo.rest_points(points), expected)
    np.testing.assert_allclose(expected[:n], topo.rest_positions, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", BEAMS)
def test_rest_points_keeps_barycentric_coordinates_under_a_nonlinear_deformation(name):
    """Under a bending the map is affine per element only: a point at a vertex goes to the rest
    vertex, a point inside an element to the same barycentric combination of its rest corners."""
    mesh = MESHES[name]()
    topo = TetTopology(mesh, positions=_bend(mesh.vertices))
    np.testing.assert_allclose(topo.rest_points(topo.positions), topo.rest_positions, rtol=0, atol=1e-12)
    slots, weights = _points_in_elements(topo, 80, seed=3)
    corners = topo.tets[slots]
    current = np.einsum("pk,pkj->pj", weights, topo.positions[corners])
    expected = np.einsum("pk,pkj->pj", weights, topo.rest_positions[corners])
    np.testing.assert_allclose(topo.rest_points(current), expected, rtol=0, atol=1e-12)
    # and not the exact inverse of the bending: the elements are linear
    assert np.abs(expected - current).max() > 0.05


@pytest.mark.parametrize("name", BEAMS)
def test_rest_points_carries_an_outside_point_from_its_nearest_boundary_point(name):
    """Under a bending, a point outside the mesh is carried from the nearest point q of the whole
    boundary (found here by measuring every boundary face): rest(q) + F^-1 (p - q), F the map of
    q's element. The points lie on lines through the mesh that stick out by up to twice its
    size, as a blade does: the nearest boundary point of a far end may lie beside the line."""
    from wcut.topology.mesh import _closest_on_triangles

    mesh = MESHES[name]()
    topo = TetTopology(mesh, positions=_bend(mesh.vertices))
    x, rest, live = topo.positions, topo.rest_positions, topo.live_tets()
    tris = topo.tets[live][:, TET_FACES].reshape(-1, 3)
    _, inverse, counts = np.unique(np.sort(tris, axis=1), axis=0, return_inverse=True, return_counts=True)
    alone = counts[inverse.ravel()] == 1
    faces, owners = tris[alone], np.repeat(live, 4)[alone]
    corners = x[topo.tets[live]]
    to_local = np.linalg.inv(np.transpose(corners[:, 1:] - corners[:, :1], (0, 2, 1)))
    rng = np.random.default_rng(4)
    checked = 0
    for _ in range(20):
        centre, direction = x[rng.integers(len(x))], rng.normal(size=3)
        points = centre + np.linspace(-1.0, 1.0, 13)[:, None] * rng.uniform(1.0, 3.0) * direction \
            / np.linalg.norm(direction)
        for p, mapped in zip(points, topo.rest_points(points)):
            local = np.einsum("mij,mj->mi", to_local, p - corners[:, 0])
            if np.minimum(1.0 - local.sum(axis=1), local.min(axis=1)).max() >= -1e-9:
                continue  # inside an element
            bary, gap = _closest_on_triangles(np.broadcast_to(p, (len(faces), 3)),
                                              *(x[faces[:, k]] for k in range(3)))
            f = int(gap.argmin())
            tet = topo.tets[owners[f]]
            inverse_map = (rest[tet[1:]] - rest[tet[0]]).T @ np.linalg.inv((x[tet[1:]] - x[tet[0]]).T)
            expected = bary[f] @ rest[faces[f]] + inverse_map @ (p - bary[f] @ x[faces[f]])
            np.testing.assert_allclose(mapped, expected, rtol=0, atol=1e-9)
            checked += 1
    assert checked > 100


# ---------------------------------------------------------------------------------------------
# move_vertex on a curved boundary: feature_angle


DISH_SIZE = (1.0, 1.0, 0.5)


def _dish_vertex(i, j, k):
    """Index of grid vertex (i, j, k) of :func:`dish` (4 x 4 x 2 cells)."""
    return _grid_vertex(i, j, k, ny=4, nz=2)


def dish() -> TetTopology:
    """A 4x4x2 beam whose top is a shallow bowl: z += 0.3 (z / 0.5) ((x - 0.5)^2 + (y - 0.5)^2).
    The bottom and the four sides stay flat; the top meets them at creases of about 90 degrees;
    around an inner top vertex the boundary normals differ by about 12 degrees."""
    grid = beam(4, 4, 2, size=DISH_SIZE)
    x = grid.vertices.copy()
    x[:, 2] += 0.3 * (x[:, 2] / DISH_SIZE[2]) * ((x[:, 0] - 0.5) ** 2 + (x[:, 1] - 0.5) ** 2)
    return make_topology(TetMesh(x, grid.tets, name="dish"))


def _normal_spread(topo: TetTopology, v: int) -> float:
    """Largest angle (degrees) between two boundary-face normals around vertex v."""
    n = _boundary_normals_of(topo, v)
    return float(np.degrees(np.arccos(np.clip((n @ n.T).min(), -1.0, 1.0))))


def _boundary_normals_of(topo: TetTopology, v: int) -> np.ndarray:
    """Unit normals of the boundary faces around v, from the boundary triangles (outward)."""
    rest = topo.rest_positions
    tri = topo.boundary_faces()
    tri = tri[(tri == v).any(axis=1)]
    n = np.cross(rest[tri[:, 1]] - rest[tri[:, 0]], rest[tri[:, 2]] - rest[tri[:, 0]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _neighbours(topo: TetTopology, v: int) -> list[int]:
    return sorted({u for t in topo.vertex_tets[v] for u in topo.tet(t)} - {v})


SMOOTH = _dish_vertex(1, 2, 2)  # on the curved top, away from the creases


def test_dish_boundary_is_smooth_inside_and_creased_at_the_rim():
    """The fixture is what the feature_angle tests need."""
    topo = dish()
    assert 5.0 < _normal_spread(topo, SMOOTH) < 30.0
    assert _normal_spread(topo, _dish_vertex(0, 2, 2)) > 80.0  # top meets the side x = 0
    assert _normal_spread(topo, _dish_vertex(0, 0, 2)) > 80.0  # a corner
    assert _normal_spread(topo, _dish_vertex(0, 2, 1)) < 1e-6  # middle of the flat side x = 0
    on_boundary = boundary_edges(topo)
    assert sum((min(SMOOTH, u), max(SMOOTH, u)) in on_boundary for u in _neighbours(topo, SMOOTH)) == 8


@pytest.mark.parametrize("weight", [0.1, 0.25, 0.4])
def test_move_vertex_slides_along_a_boundary_edge_of_a_smooth_curved_boundary(weight):
    """With feature_angle = 30 a vertex of the smooth curved top may slide along any of its
    boundary edges: the mesh stays valid, the attributes are interpolated, and the volume
    changes a little (the edge is a chord of the curved surface, not on it)."""
    on_boundary = boundary_edges(dish())
    slid = 0
    for u in _neighbours(dish(), SMOOTH):
        if (min(SMOOTH, u), max(SMOOTH, u)) not in on_boundary:
            continue
        topo = dish()
        v0 = volume(topo)
        expected = (1 - weight) * topo.vertex_data[SMOOTH] + weight * topo.vertex_data[u]
        move_vertex(topo, SMOOTH, [SMOOTH, u], [1 - weight, weight], feature_angle=30.0)
        np.testing.assert_allclose(topo.vertex_data[SMOOTH], expected, rtol=0, atol=1e-14)
        assert_affine(topo)
        v1 = volume(topo)
        check_topology(topo, v1)  # every other invariant holds
        change = abs(v1 - v0) / v0
        assert 1e-5 < change < 5e-3 * weight / 0.25, (u, change)
        with pytest.raises(TopologyError, match="volume"):
            check_topology(topo, v0)
        slid += 1
    assert slid == 8


def test_move_vertex_on_a_curved_boundary_is_refused_by_default():
    """feature_angle = 0 (the default): a boundary vertex never leaves the planes of its faces."""
    topo = dish()
    u = _dish_vertex(2, 2, 2)
    assert (SMOOTH, u) in boundary_edges(topo)
    assert_refused(topo, move_vertex, SMOOTH, [SMOOTH, u], [0.75, 0.25], match="off its boundary")
    assert_refused(topo, move_vertex, SMOOTH, [SMOOTH, u], [0.75, 0.25], feature_angle=0.0,
                   match="off its boundary")


def test_move_vertex_feature_angle_is_a_threshold_on_the_normals_spread():
    """Just below the spread of the normals around the vertex: refused; just above: allowed."""
    topo = dish()
    spread = _normal_spread(topo, SMOOTH)
    u = _dish_vertex(2, 2, 2)
    assert_refused(topo, move_vertex, SMOOTH, [SMOOTH, u], [0.75, 0.25], feature_angle=0.95 * spread)
    move_vertex(topo, SMOOTH, [SMOOTH, u], [0.75, 0.25], feature_angle=1.05 * spread)
    check_topology(topo)
    assert_affine(topo)
    np.testing.assert_allclose(topo.rest_positions[SMOOTH], 0.75 * dish().rest_positions[SMOOTH]
                               + 0.25 * dish().rest_positions[u], rtol=0, atol=1e-14)


def test_move_vertex_on_a_curved_boundary_is_refused_into_the_body():
    """Even with feature_angle, a boundary vertex may not move along an interior edge (into the
    body), nor to a combination of more than its edge's two ends."""
    topo = dish()
    on_boundary = boundary_edges(topo)
    inner = [u for u in _neighbours(topo, SMOOTH) if (min(SMOOTH, u), max(SMOOTH, u)) not in on_boundary]
    assert _dish_vertex(1, 2, 1) in inner and len(inner) == 5
    for u in inner:
        assert_refused(topo, move_vertex, SMOOTH, [SMOOTH, u], [0.8, 0.2], feature_angle=30.0,
                       match="off its boundary")
    a, b = _dish_vertex(2, 2, 2), _dish_vertex(1, 3, 2)  # two boundary neighbours: a point off every edge
    assert_refused(topo, move_vertex, SMOOTH, [SMOOTH, a, b], [0.8, 0.1, 0.1], feature_angle=30.0,
                   match="off its boundary")


@pytest.mark.parametrize("ijk", [(0, 2, 2), (0, 0, 2), (4, 1, 2)])
def test_move_vertex_refused_at_a_crease_even_with_feature_angle(ijk):
    """At the rim (the curved top meets a flat side, normals about 90 degrees apart) and at a
    corner, no slide along a boundary edge that leaves a face's plane is allowed."""
    topo = dish()
    v = _dish_vertex(*ijk)
    on_boundary = boundary_edges(topo)
    tried = 0
    for u in _neighbours(topo, v):
        if (min(v, u), max(v, u)) not in on_boundary:
            continue
        step = topo.rest_positions[u] - topo.rest_positions[v]
        if np.abs(_boundary_normals_of(topo, v) @ step).max() < 1e-9:
            continue  # a slide within every face's plane (along the straight bottom crease, say)
        assert_refused(topo, move_vertex, v, [v, u], [0.8, 0.2], feature_angle=30.0, match="off its boundary")
        tried += 1
    assert tried >= 2


def test_move_vertex_within_a_flat_boundary_of_the_dish_keeps_the_volume():
    """On the flat side and bottom a slide within the face plane is allowed with the default,
    and the volume is kept exactly."""
    for v, u in [(_dish_vertex(0, 2, 1), _dish_vertex(0, 1, 1)), (_dish_vertex(2, 2, 0), _dish_vertex(1, 2, 0))]:
        topo = dish()
        assert (min(v, u), max(v, u)) in boundary_edges(topo)
        applied(topo, move_vertex, v, [v, u], [0.7, 0.3], tets=0)


def test_retarget_keeps_unsewn_faces_without_the_vertex_unsewn():
    """Duplicating a vertex retargets elements; a face of such an element that does not hold
    the vertex and was unsewn (on the cut) must stay unsewn, or the fans of its own vertices
    would join across the cut when they are duplicated in turn."""
    topo = make_topology(two_tets())
    key = next(k for k, owners in topo.face_tets.items() if len(owners) == 2)
    unsew_face(topo, key)
    t = topo.face_tets[key][0]
    v = next(u for u in topo.tet(t) if u not in key)  # the apex: not on the unsewn face
    w = topo.add_vertex([v], [1.0])
    topo.retarget(t, v, w)
    assert key in topo.unsewn and len(topo.face_tets[key]) == 2 and t in topo.face_tets[key]
    assert w in topo.tet(t) and v not in topo.tet(t)


# ---------------------------------------------------------------------------------------------
# the operators' shortcuts give what the full computations give


def test_quality_is_remembered_until_the_shape_changes():
    """``TetTopology.quality`` is ``tet_quality`` of the element's vertices in slot order, to
    the last bit: after the operators store it, after a vertex moves and after rest positions
    are written and synced."""
    topo = make_topology(two_tets())

    def assert_fresh():
        rest = topo.rest_tuples
        for t in topo.live_tets().tolist():
            assert topo.quality(t) == tet_quality(*[rest[v] for v in topo.tet(t)])

    assert_fresh()
    flip23(topo, (0, 1, 2), quality_drop=0.1)
    assert_fresh()
    p, _ = split_tet(topo, int(topo.live_tets()[0]), [0.1, 0.2, 0.3, 0.4])
    assert_fresh()
    move_vertex(topo, p, [p, 3], [0.9, 0.1])
    assert_fresh()
    topo.vertex_data[: topo.vertex_count, REST] *= 1.5
    topo.sync_rest_tuples()
    assert_fresh()


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(height=st.floats(1e-7, 1e-2), offset=st.floats(0.0, 1e7), scale=st.floats(1e-3, 1e2),
       tilt=st.floats(-1.0, 1.0))
def test_check_skips_float32_qualities_only_where_they_cannot_matter(height, offset, scale, tilt):
    """``_check`` computes the float32 quality only where the float64 one is not clearly above
    the threshold: it returns (or raises) exactly what computing them all does, also for flat
    elements far from the origin, where rounding to float32 matters."""
    from wcut.topology.operators import _check, _check_all, _extra_points

    topo = make_topology(two_tets())
    base = np.array([offset, -0.5 * offset, 0.25 * offset])
    corners = base + scale * np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.3, 1.0, 0.0], [tilt, 0.2, height]])
    extra = {-(i + 1): corners[i] for i in range(4)}
    tets = [[0, 1, 2, 3], [-1, -2, -3, -4]]

    def outcome(check, *args):
        qualities: list = []
        try:
            return check(topo, tets, "check", *args, qualities), qualities
        except TopologyError as exc:
            return str(exc)

    assert outcome(_check, extra) == outcome(_check_all, *_extra_points(extra))


def test_containing_finds_the_element_the_full_search_finds():
    """The parents of a general flip's and a 2-3 flip's elements are those of the exhaustive
    search (the first removed element of largest smallest barycentric coordinate), however
    the search is started."""
    from wcut.topology import operators

    calls = []
    containing = operators._containing

    def recording(topo, removed, added, hints=None):
        result = containing(topo, removed, added, hints)
        calls.append(result == _containing_everywhere(topo, removed, added)
                     == containing(topo, removed, added, [len(removed) - 1] * len(added)))
        return result

    operators._containing = recording
    try:
        for n in (3, 4, 5, 6, 7):
            remove_edge(make_topology(ring(n)), 0, 1)
        flip23(make_topology(two_tets()), (0, 1, 2))
    finally:
        operators._containing = containing
    assert len(calls) == 6 and all(calls)


def _containing_everywhere(topo: TetTopology, removed, added) -> list[int]:
    """The exhaustive search of ``_containing``: every removed element, same arithmetic."""
    from wcut.topology.operators import _barycentric_frame

    rest = topo.rest_tuples
    frames = [_barycentric_frame(*[rest[v] for v in topo.tet(t)]) for t in removed]
    parents = []
    for tet in added:
        p = [rest[v] for v in tet]
        c = [(p[0][i] + p[1][i] + p[2][i] + p[3][i]) / 4.0 for i in range(3)]
        best, best_min = 0, -np.inf
        for i, (r0, r1, r2, det, c3) in enumerate(frames):
            d = [c[0] - c3[0], c[1] - c3[1], c[2] - c3[2]]
            x = [(r[0] * d[0] + r[1] * d[1] + r[2] * d[2]) / det for r in (r0, r1, r2)]
            smallest = min(x[0], x[1], x[2], 1.0 - (x[0] + x[1] + x[2]))
            if smallest > best_min:
                best, best_min = i, smallest
        parents.append(removed[best])
    return parents


def test_a_topology_refuses_positions_of_another_mesh():
    mesh = beam(2, 1, 1)
    with pytest.raises(TopologyError, match=r"positions must have shape \(12, 3\).*another mesh"):
        TetTopology(mesh, positions=np.zeros((20, 3)))
    with pytest.raises(TopologyError, match="velocities are not all finite"):
        TetTopology(mesh, velocities=np.full((12, 3), np.nan))
