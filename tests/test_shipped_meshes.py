"""The tetrahedral meshes shipped in scenes/meshes/ (made by tools/make_meshes.py with gmsh,
which is not needed here): they load, are closed, connected, conforming and well shaped."""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from wcut.mesh import TET_FACES, TetMesh

MESHES = Path(__file__).resolve().parents[1] / "scenes" / "meshes"

#: name -> (vertex range, tetrahedron range, minimum dihedral angle (deg) reported in the README)
EXPECTED = {
    "organ": ((600, 1600), (2500, 5000), 22.8),
    "beam371": ((118, 144), (334, 408), 31.2),  # thesis fig. 5.10: 131 nodes, 371 elements (+-10%)
    "beam712": ((200, 260), (640, 790), 17.2),  # thesis table 6.4: 712 elements
    "beam4621": ((1100, 1400), (4150, 5100), 18.9),  # thesis table 6.4: 4621 elements
}


def load(name: str) -> TetMesh:
    return TetMesh.load(MESHES / f"{name}.vtu")


def dihedral_angles(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(M, 6) interior dihedral angles in degrees."""
    p = points[tets]
    out = []
    for a, b, c, d in ((0, 1, 2, 3), (0, 2, 1, 3), (0, 3, 1, 2), (1, 2, 0, 3), (1, 3, 0, 2), (2, 3, 0, 1)):
        e = p[:, b] - p[:, a]
        n1 = np.cross(e, p[:, c] - p[:, a])
        n2 = np.cross(e, p[:, d] - p[:, a])
        cos = np.einsum("ij,ij->i", n1, n2) / (np.linalg.norm(n1, axis=1) * np.linalg.norm(n2, axis=1))
        out.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return np.stack(out, axis=1)


def ellipsoid_deviation(points: np.ndarray) -> np.ndarray:
    """Radial distance (m) of ``points`` from their least-squares (general, rotated) ellipsoid,
    measured along rays from the ellipsoid's centre."""
    x, y, z = points.T
    design = np.stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, 2 * x, 2 * y, 2 * z], axis=1)
    q = np.linalg.lstsq(design, np.ones(len(points)), rcond=None)[0]
    A = np.array([[q[0], q[3], q[4]], [q[3], q[1], q[5]], [q[4], q[5], q[2]]])
    assert np.all(np.linalg.eigvalsh(A) > 0), "the best-fit quadric is not an ellipsoid"
    centre = -np.linalg.solve(A, q[6:9])
    level = 1.0 + centre @ A @ centre  # (p - c)^T A (p - c) = level on the ellipsoid
    d = points - centre
    r = np.linalg.norm(d, axis=1)
    u = d / r[:, None]
    return r - np.sqrt(level / np.einsum("ij,jk,ik->i", u, A, u))


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_file_holds_only_tetrahedra_and_is_small(name):
    path = MESHES / f"{name}.vtu"
    assert path.stat().st_size < 1_000_000
    data = meshio.read(path)
    assert [block.type for block in data.cells] == ["tetra"]
    mesh = load(name)
    assert mesh.source_vertex_ids is None  # no unused points in the file
    assert mesh.reoriented_count == 0  # written positively oriented


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_counts(name):
    (v_lo, v_hi), (t_lo, t_hi), _ = EXPECTED[name]
    mesh = load(name)
    assert v_lo <= mesh.vertex_count <= v_hi
    assert t_lo <= mesh.tet_count <= t_hi


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_boundary_is_closed_and_consistently_oriented(name):
    mesh = load(name)
    tris = mesh.boundary().triangles
    undirected = np.sort(tris[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    _, counts = np.unique(undirected, axis=0, return_counts=True)
    assert np.all(counts == 2), "a boundary edge is not shared by exactly two boundary triangles"
    directed = tris[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)
    _, counts = np.unique(directed, axis=0, return_counts=True)
    assert np.all(counts == 1), "boundary triangles are not consistently oriented"
    # Euler characteristic of a closed sphere-like surface
    v = len(mesh.boundary().vertex_ids)
    assert v - len(undirected) // 2 + len(tris) == 2


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_single_connected_component(name):
    mesh = load(name)
    faces = np.sort(mesh.tets[:, TET_FACES].reshape(-1, 3), axis=1)
    _, inverse = np.unique(faces, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    owner = np.repeat(np.arange(mesh.tet_count), 4)
    order = np.argsort(inverse, kind="stable")
    same = inverse[order][1:] == inverse[order][:-1]
    a, b = owner[order][:-1][same], owner[order][1:][same]
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(mesh.tet_count, mesh.tet_count))
    count, _ = connected_components(graph, directed=False)
    assert count == 1


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_volume_equals_volume_enclosed_by_boundary(name):
    mesh = load(name)
    tri = mesh.vertices[mesh.boundary().triangles]
    enclosed = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0
    total = mesh.volumes().sum()
    assert np.all(mesh.volumes() > 0)
    assert total == pytest.approx(enclosed, rel=1e-9)


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_quality(name):
    *_, min_dihedral = EXPECTED[name]
    mesh = load(name)
    angles = dihedral_angles(mesh.vertices, mesh.tets)
    assert angles.min() > min_dihedral
    assert angles.max() < 150.0
    assert 65.0 < angles.mean() < 75.0  # 70.5 deg for the regular tetrahedron


@pytest.mark.parametrize("name", ("beam371", "beam712", "beam4621"))
def test_beam_is_the_box(name):
    mesh = load(name)
    np.testing.assert_allclose(mesh.vertices.min(axis=0), [0.0, -0.02, -0.02], atol=1e-12)
    np.testing.assert_allclose(mesh.vertices.max(axis=0), [0.16, 0.02, 0.02], atol=1e-12)
    assert mesh.volumes().sum() == pytest.approx(0.16 * 0.04 * 0.04, rel=1e-9)


def test_organ_size_and_placement():
    mesh = load("organ")
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    np.testing.assert_allclose(hi - lo, [0.16, 0.10, 0.07], rtol=0.12)
    assert np.all(np.abs((lo + hi) / 2) < 0.01)  # centred near the origin (metres)
    # flat-ish bottom facing -z: more nearly horizontal surface faces down than up
    tri = mesh.vertices[mesh.boundary().triangles]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]) / 2.0
    area = np.linalg.norm(normals, axis=1)
    nz = normals[:, 2] / area
    assert area[nz < -0.9].sum() > area[nz > 0.9].sum()


def test_organ_is_not_an_ellipsoid():
    mesh = load("organ")
    points = mesh.vertices[mesh.boundary().vertex_ids]
    size = np.ptp(points, axis=0).max()
    deviation = ellipsoid_deviation(points)
    assert np.ptp(deviation) > 0.05 * size
    # the check itself: an exact ellipsoid deviates by nothing
    u = np.random.default_rng(0).normal(size=(500, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    assert np.ptp(ellipsoid_deviation(u * [0.08, 0.05, 0.035] + [0.01, 0.0, 0.0])) < 1e-9 * size


def test_quadratic_organ_is_curved_and_closer_to_the_organ_than_its_corners():
    """organ_p2.vtu: the coarse organ as 10-node elements whose boundary follows the smooth
    surface (thesis 6.1.1): its volume is within 2% of the fine organ's, its straight corners'
    is not."""
    from wcut.quadratic import QuadraticTetMesh

    path = MESHES / "organ_p2.vtu"
    assert [block.type for block in meshio.read(path).cells] == ["tetra10"]
    mesh = QuadraticTetMesh.load(path)  # validated: det J > 0 at Gauss points and nodes
    assert 200 <= mesh.tet_count <= 400 and mesh.reoriented_count == 0
    fine = load("organ").volumes().sum()
    assert mesh.volumes().sum() == pytest.approx(fine, rel=0.02)
    assert mesh.linear().volumes().sum() < 0.95 * fine
    faces = mesh.boundary().triangles
    chord = 0.5 * (mesh.vertices[faces[:, [0, 1, 2]]] + mesh.vertices[faces[:, [1, 2, 0]]])
    bulge = np.linalg.norm(mesh.vertices[faces[:, 3:]] - chord, axis=2)
    assert np.median(bulge) > 0.01 * mesh.mean_edge_length()
