"""Tests of wcut.mesh: the beam generator, TetMesh validation, boundary extraction and meshio I/O."""

from __future__ import annotations

import collections

import meshio
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import wcut
from wcut.errors import MeshError, MeshNotice, WcutError
from wcut.mesh import TET_FACES, TetMesh, beam, tet_volumes, unique_rows

# One positively oriented unit-corner tetrahedron and a second one glued to its face (1, 2, 3).
TET_X = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], dtype=np.float64)
TWO_TETS = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])

BEAMS = [
    # (nx, ny, nz, size, origin, tets_per_hex)
    (1, 1, 1, (1.0, 1.0, 1.0), (0.0, 0.0, 0.0), 5),
    (1, 1, 1, (1.0, 1.0, 1.0), (0.0, 0.0, 0.0), 6),
    (4, 2, 2, (0.2, 0.05, 0.05), (0.0, 0.0, 0.0), 5),
    (4, 2, 2, (0.2, 0.05, 0.05), (0.0, 0.0, 0.0), 6),
    (3, 4, 5, (0.3, 0.2, 0.1), (1.0, -2.0, 0.5), 5),
    (2, 3, 3, (0.02, 0.07, 0.04), (-0.5, 0.25, 3.0), 6),
]
BEAM_IDS = [f"{b[0]}x{b[1]}x{b[2]}-t{b[5]}" for b in BEAMS]


def _make(spec) -> TetMesh:
    nx, ny, nz, size, origin, per_hex = spec
    return beam(nx, ny, nz, size=size, origin=origin, tets_per_hex=per_hex)


def _face_counts(tets: np.ndarray) -> collections.Counter:
    return collections.Counter(tuple(sorted(f)) for f in tets[:, TET_FACES].reshape(-1, 3).tolist())


# ---------------------------------------------------------------------------------------------
# beam()


@pytest.mark.parametrize("spec", BEAMS, ids=BEAM_IDS)
def test_beam_counts_and_volume(spec):
    nx, ny, nz, size, origin, per_hex = spec
    mesh = _make(spec)
    assert mesh.vertex_count == (nx + 1) * (ny + 1) * (nz + 1)
    assert mesh.tet_count == per_hex * nx * ny * nz
    assert mesh.vertices.shape == (mesh.vertex_count, 3) and mesh.vertices.dtype == np.float64
    assert mesh.tets.shape == (mesh.tet_count, 4)
    volumes = mesh.volumes()
    assert np.all(volumes > 0)
    box_volume = float(np.prod(size))
    assert volumes.sum() == pytest.approx(box_volume, rel=1e-12)
    # bounding box and the documented vertex numbering
    assert np.allclose(mesh.vertices.min(axis=0), origin)
    assert np.allclose(mesh.vertices.max(axis=0), np.add(origin, size))
    i, j, k = nx, 0, nz
    assert np.allclose(mesh.vertices[(i * (ny + 1) + j) * (nz + 1) + k], np.add(origin, (size[0], 0.0, size[2])))


@pytest.mark.parametrize("spec", BEAMS, ids=BEAM_IDS)
def test_beam_faces_conform(spec):
    """Every face is shared by one (boundary) or two (interior) elements, and the boundary faces
    are exactly the two triangles per cell face on the box's surface."""
    nx, ny, nz, *_ = spec
    mesh = _make(spec)
    counts = _face_counts(mesh.tets)
    assert set(counts.values()) <= {1, 2}
    boundary_faces = sum(1 for c in counts.values() if c == 1)
    interior_faces = sum(1 for c in counts.values() if c == 2)
    assert boundary_faces == 4 * (nx * ny + ny * nz + nx * nz)
    assert boundary_faces + 2 * interior_faces == 4 * mesh.tet_count
    assert len(mesh.boundary().triangles) == boundary_faces


@pytest.mark.parametrize("spec", BEAMS, ids=BEAM_IDS)
def test_beam_boundary_is_closed_and_outward(spec):
    _, _, _, size, origin, _ = spec
    mesh = _make(spec)
    surface = mesh.boundary()
    tris = surface.triangles
    # closed: every undirected boundary edge is shared by exactly two boundary triangles ...
    undirected = collections.Counter(tuple(sorted(e)) for t in tris.tolist() for e in zip(t, t[1:] + t[:1]))
    assert set(undirected.values()) == {2}
    # ... and consistently oriented: each directed edge appears once, its reverse once.
    directed = collections.Counter(e for t in tris.tolist() for e in zip(t, t[1:] + t[:1]))
    assert set(directed.values()) == {1}
    assert all((b, a) in directed for a, b in directed)
    # outward: the divergence theorem gives the (positive) volume
    a, b, c = (mesh.vertices[tris[:, m]] for m in range(3))
    enclosed = np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0
    box_volume = float(np.prod(size))
    assert enclosed == pytest.approx(box_volume, rel=1e-9)
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()
    sx, sy, sz = size
    assert area == pytest.approx(2.0 * (sx * sy + sy * sz + sx * sz), rel=1e-12)
    # every boundary vertex lies on the box's surface; vertex_ids / local_triangles agree
    lo, hi = np.asarray(origin), np.add(origin, size)
    on = mesh.vertices[surface.vertex_ids]
    assert np.all(np.isclose(on, lo).any(axis=1) | np.isclose(on, hi).any(axis=1))
    assert np.array_equal(surface.vertex_ids, np.unique(tris))
    assert np.array_equal(surface.vertex_ids[surface.local_triangles], tris)


def test_beam_boundary_vertices_of_interior_grid(small_beam):
    """A 4x2x2 grid has exactly three vertices off the surface: (i, 1, 1) for i = 1, 2, 3."""
    surface = small_beam.boundary()
    interior = sorted(set(range(small_beam.vertex_count)) - set(surface.vertex_ids.tolist()))
    assert interior == [(i * 3 + 1) * 3 + 1 for i in (1, 2, 3)]
    assert np.allclose(small_beam.vertices[interior], [[x, 0.025, 0.025] for x in (0.05, 0.1, 0.15)])


def test_edges_and_vertices_in_box(small_beam):
    edges = small_beam.edges()
    assert np.all(edges[:, 0] < edges[:, 1])
    assert len(np.unique(edges, axis=0)) == len(edges)
    # each cell edge appears; no edge is longer than a cell diagonal
    lengths = np.linalg.norm(small_beam.vertices[edges[:, 0]] - small_beam.vertices[edges[:, 1]], axis=1)
    assert lengths.min() == pytest.approx(0.025)
    assert lengths.max() <= np.sqrt(0.05**2 + 0.025**2 + 0.025**2) + 1e-12
    assert small_beam.mean_edge_length() == pytest.approx(lengths.mean())
    clamp = small_beam.vertices_in_box((-1e-3, -1, -1), (1e-3, 1, 1))
    assert len(clamp) == 9 and np.all(small_beam.vertices[clamp, 0] == 0.0)
    assert len(small_beam.vertices_in_box((0, 0, 0), (0.2, 0.05, 0.05))) == 45  # closed box
    assert len(small_beam.vertices_in_box((1, 1, 1), (2, 2, 2))) == 0


@pytest.mark.parametrize(
    "args, kwargs, words",
    [
        ((0, 2, 2), {}, "at least 1"),
        ((2, -1, 2), {}, "at least 1"),
        ((2, 2, 2), {"tets_per_hex": 4}, "tets_per_hex"),
        ((2, 2, 2), {"size": (1.0, 0.0, 1.0)}, "size"),
        ((2, 2, 2), {"size": (1.0, -1.0, 1.0)}, "size"),
        ((2, 2, 2), {"size": (1.0, 1.0)}, "size"),
    ],
)
def test_beam_rejects_bad_arguments(args, kwargs, words):
    with pytest.raises(MeshError, match=words):
        beam(*args, **kwargs)


# ---------------------------------------------------------------------------------------------
# TetMesh validation


def test_two_tets_are_valid():
    mesh = TetMesh(TET_X, TWO_TETS)
    assert mesh.tet_count == 2 and mesh.vertex_count == 5
    assert np.allclose(mesh.volumes(), [1 / 6, 1 / 3])
    assert len(mesh.boundary().triangles) == 6


def _error(vertices, tets, name="m") -> str:
    with pytest.raises(MeshError) as info:
        TetMesh(vertices, tets, name=name)
    assert isinstance(info.value, WcutError)
    return str(info.value)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_coordinate_names_the_vertex(bad):
    x = TET_X.copy()
    x[3, 1] = bad
    message = _error(x, TWO_TETS, name="organ.msh")
    assert message.startswith("organ.msh:")
    assert "vertex 3" in message and "non-finite" in message


def test_index_out_of_range_names_the_element():
    assert "element 1" in _error(TET_X, [[0, 1, 2, 3], [1, 3, 2, 5]])
    assert "element 0" in _error(TET_X, [[0, 1, 2, -1], [1, 3, 2, 4]])


def test_repeated_vertex_names_the_element():
    message = _error(TET_X, [[0, 1, 2, 3], [1, 3, 2, 4], [4, 1, 4, 0]])
    assert "element 2" in message and "repeats" in message


def test_unreferenced_vertex_is_named():
    x = np.vstack([TET_X[:3], [[9.0, 9.0, 9.0]], TET_X[3:]])  # vertex 3 unused
    message = _error(x, [[0, 1, 2, 4], [1, 4, 2, 5]])
    assert "vertex 3" in message and "not used" in message


def test_flat_element_is_degenerate():
    x = np.vstack([TET_X, [[0.5, 0.5, 0.0]]])  # vertex 5 lies in the plane of 0, 1, 2
    message = _error(x, [[0, 1, 2, 3], [1, 3, 2, 4], [0, 1, 2, 5]])
    assert "element 2" in message and "degenerate" in message


def test_degeneracy_is_relative_to_element_size():
    """A tiny but well-shaped element is fine; a sliver at machine precision is not."""
    TetMesh(TET_X[:4] * 1e-4, [[0, 1, 2, 3]])
    x = TET_X[:4].copy()
    x[3] = [0.3, 0.3, 1e-13]
    assert "degenerate" in _error(x, [[0, 1, 2, 3]])


def test_face_shared_by_three_elements_is_non_manifold():
    x = np.vstack([TET_X, [[-1.0, -1.0, -1.0]], [[1.0, 1.0, 0.2]]])
    # face (1, 2, 3) is shared by elements 0, 1 and 2
    message = _error(x, [[0, 1, 2, 3], [1, 3, 2, 4], [1, 3, 2, 6], [0, 1, 2, 5]])
    assert "non-manifold" in message
    assert "[1, 2, 3]" in message and "[0, 1, 2]" in message


@pytest.mark.parametrize(
    "vertices, tets, words",
    [
        (TET_X[:, :2], TWO_TETS, "vertices must have shape"),
        (TET_X.ravel(), TWO_TETS, "vertices must have shape"),
        (TET_X, TWO_TETS[:, :3], "must have shape \\(M, 4\\)"),
        (TET_X, TWO_TETS.ravel(), "must have shape \\(M, 4\\)"),
        (TET_X, TWO_TETS.astype(float), "integers"),
        (np.zeros((0, 3)), np.zeros((0, 4), dtype=int), "no tetrahedra"),
        (TET_X, np.zeros((0, 4), dtype=int), "no tetrahedra"),
        ([], [], "shape"),
    ],
)
def test_bad_shapes_and_empty_meshes(vertices, tets, words):
    with pytest.raises(MeshError, match=words):
        TetMesh(vertices, tets)


def test_negative_elements_are_reoriented():
    tets = np.array([[0, 2, 1, 3], [1, 2, 3, 4]])  # element 0 inverted
    mesh = TetMesh(TET_X, tets)
    assert mesh.reoriented_count == 1
    assert np.all(mesh.volumes() > 0)
    assert np.allclose(mesh.volumes(), [1 / 6, 1 / 3])
    assert [sorted(t) for t in mesh.tets.tolist()] == [sorted(t) for t in tets.tolist()]
    assert np.array_equal(tets, [[0, 2, 1, 3], [1, 2, 3, 4]])  # the caller's array is untouched


@settings(max_examples=60, deadline=None, derandomize=True)
@given(data=st.data())
def test_random_orientations_load_valid(data):
    base = beam(3, 2, 2, size=(0.3, 0.1, 0.2), tets_per_hex=data.draw(st.sampled_from([5, 6])))
    m = base.tet_count
    chosen = data.draw(st.lists(st.integers(0, m - 1), unique=True, max_size=m))
    perms = data.draw(st.lists(st.permutations(range(4)), min_size=len(chosen), max_size=len(chosen)))
    tets = base.tets.copy()
    odd = 0
    for e, perm in zip(chosen, perms):
        tets[e] = base.tets[e][list(perm)]
        odd += int(np.linalg.det(np.eye(4)[list(perm)]) < 0)
    assert (tet_volumes(base.vertices, tets) < 0).sum() == odd
    mesh = TetMesh(base.vertices, tets)
    assert mesh.reoriented_count == odd
    assert np.all(mesh.volumes() > 0)
    assert mesh.volumes().sum() == pytest.approx(base.volumes().sum(), rel=1e-12)
    assert np.array_equal(np.sort(mesh.tets, axis=1), np.sort(base.tets, axis=1))
    assert len(mesh.boundary().triangles) == len(base.boundary().triangles)


# ---------------------------------------------------------------------------------------------
# I/O


def _write_meshio(path, mesh: TetMesh, **kwargs):
    meshio.write(path, meshio.Mesh(mesh.vertices, [("tetra", mesh.tets)]), **kwargs)


@pytest.mark.parametrize(
    "name, kwargs",
    [
        ("beam.vtu", {}),
        ("beam.vtk", {}),
        ("beam.msh", {"file_format": "gmsh22", "binary": False}),
        ("beam.msh", {}),  # meshio's default gmsh version
        ("beam.mesh", {}),
    ],
    ids=["vtu", "vtk", "gmsh22", "gmsh-default", "medit"],
)
def test_load_round_trips(tmp_path, small_beam, name, kwargs):
    path = tmp_path / name
    _write_meshio(path, small_beam, **kwargs)
    loaded = TetMesh.load(path)
    assert loaded.name == name
    assert np.allclose(loaded.vertices, small_beam.vertices, rtol=0, atol=1e-12)
    assert np.array_equal(loaded.tets, small_beam.tets)
    assert loaded.reoriented_count == 0


def test_load_ignores_other_cells_and_drops_their_vertices(tmp_path, small_beam):
    extra = np.vstack([small_beam.vertices, [[5.0, 5.0, 5.0], [6.0, 5.0, 5.0]]])
    n = small_beam.vertex_count
    cells = [("triangle", np.array([[n, n + 1, 0]])), ("tetra", small_beam.tets), ("line", np.array([[n, n + 1]]))]
    path = tmp_path / "mixed.vtu"
    meshio.write(path, meshio.Mesh(extra, cells))
    loaded = TetMesh.load(path)
    assert loaded.vertex_count == n
    assert np.allclose(loaded.vertices, small_beam.vertices)
    assert np.array_equal(loaded.tets, small_beam.tets)


def test_load_drops_a_vertex_no_cell_uses_with_a_notice(tmp_path):
    """SOFA's raptors hold vertices no cell uses: they are dropped, said in one notice, and the
    file's numbering kept for scene indices."""
    x = np.vstack([TET_X[:2], [[7.0, 7.0, 7.0]], TET_X[2:]])
    path = tmp_path / "gap.vtu"
    meshio.write(path, meshio.Mesh(x, [("tetra", np.array([[0, 1, 3, 4], [1, 3, 4, 5]]))]))
    with pytest.warns(MeshNotice, match=r"gap.vtu: 1 vertices no cell uses are dropped \(file indices 2\)"):
        loaded = TetMesh.load(path)
    assert np.allclose(loaded.vertices, TET_X)
    assert loaded.vertex_from_source(2) == -1 and loaded.vertex_from_source(3) == 2


def test_an_unreadable_file_keeps_meshio_s_reason(tmp_path):
    path = tmp_path / "short.vtk"
    path.write_text("# vtk DataFile Version 2.0\nx\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 float\n0 0 0\n")
    with pytest.raises(MeshError, match="short.vtk: cannot read mesh: ") as info:
        TetMesh.load(path)
    assert "malformed file" not in str(info.value) and len(str(info.value)) > len(f"{path}: cannot read mesh: ") + 5


def test_load_drops_vertices_of_other_cells_and_keeps_the_file_numbering(tmp_path):
    x = np.vstack([TET_X[:2], [[7.0, 7.0, 7.0]], TET_X[2:]])
    path = tmp_path / "with_line.vtu"
    meshio.write(path, meshio.Mesh(x, [("tetra", np.array([[0, 1, 3, 4], [1, 3, 4, 5]])),
                                       ("line", np.array([[2, 0]]))]))
    loaded = TetMesh.load(path)
    assert np.allclose(loaded.vertices, TET_X)
    assert np.array_equal(loaded.tets, TWO_TETS)
    assert loaded.source_vertex_ids.tolist() == [0, 1, 3, 4, 5]
    assert [loaded.vertex_from_source(i) for i in range(7)] == [0, 1, -1, 2, 3, 4, -1]


def test_repeated_element_is_rejected():
    with pytest.raises(MeshError, match="element 1 repeats element 0"):
        TetMesh(TET_X[:4], [[0, 1, 2, 3], [1, 0, 3, 2]])


def test_overlapping_elements_are_rejected():
    """Two elements on the same side of a shared face: the apex mirrored back over the face."""
    base = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, 1.0], [0.3, 0.1, 0.5]], dtype=float)
    with pytest.raises(MeshError, match="overlaps"):
        TetMesh(base, [[0, 1, 2, 3], [0, 1, 2, 4]])


def test_load_reorients_inverted_elements(tmp_path):
    path = tmp_path / "inverted.vtu"
    meshio.write(path, meshio.Mesh(TET_X, [("tetra", np.array([[0, 2, 1, 3], [1, 3, 2, 4]]))]))
    loaded = TetMesh.load(path)
    assert loaded.reoriented_count == 2
    assert np.all(loaded.volumes() > 0)


def test_load_only_triangles_is_an_error(tmp_path, small_beam):
    path = tmp_path / "surface.vtu"
    meshio.write(path, meshio.Mesh(small_beam.vertices, [("triangle", small_beam.boundary().triangles)]))
    with pytest.raises(MeshError, match="no tetrahedra") as info:
        TetMesh.load(path)
    assert "surface.vtu" in str(info.value) and "triangle" in str(info.value)


def test_load_missing_file_names_the_path(tmp_path):
    path = tmp_path / "nowhere" / "organ.msh"
    with pytest.raises(MeshError, match="no such file") as info:
        TetMesh.load(path)
    assert str(path) in str(info.value)


def test_load_unknown_format_is_a_mesh_error(tmp_path):
    path = tmp_path / "garbage.xyz"
    path.write_bytes(b"this is not a mesh\n\x00\x01\x02 at all\n")
    with pytest.raises(MeshError, match="cannot read mesh") as info:
        TetMesh.load(path)
    assert str(path) in str(info.value)


def test_load_validates_the_content(tmp_path):
    x = TET_X.copy()
    x[4] = 0.5 * (x[1] + x[2])  # vertex 4 on the edge 1-2: element 1 is flat
    path = tmp_path / "flat.vtu"
    meshio.write(path, meshio.Mesh(x, [("tetra", TWO_TETS)]))
    with pytest.raises(MeshError, match="degenerate") as info:
        TetMesh.load(path)
    assert str(info.value).startswith("flat.vtu:")


@pytest.mark.parametrize("name", ["out.vtu", "out.msh", "out.vtk", "out.mesh"])
def test_save_is_atomic_and_loadable(tmp_path, small_beam, name):
    target = tmp_path / "sub" / name  # parent directories are created
    small_beam.save(target)
    assert sorted(p.name for p in target.parent.iterdir()) == [name]
    loaded = TetMesh.load(target)
    assert np.allclose(loaded.vertices, small_beam.vertices, rtol=0, atol=1e-12)
    assert np.array_equal(loaded.tets, small_beam.tets)
    # overwriting keeps exactly one file
    wcut.beam(1, 1, 1).save(target)
    assert sorted(p.name for p in target.parent.iterdir()) == [name]
    assert TetMesh.load(target).tet_count == 5


def test_failed_save_leaves_nothing(tmp_path, small_beam):
    target = tmp_path / "out.unknownformat"
    with pytest.raises(Exception):
        small_beam.save(target)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("suffix", [".vtu", ".msh", ".vtk", ".mesh"])
def test_garbage_file_with_a_mesh_extension_raises_mesh_error(tmp_path, suffix, capsys):
    """meshio calls sys.exit() on some malformed files; the loader must turn that into MeshError."""
    path = tmp_path / f"garbage{suffix}"
    path.write_text("this is not a mesh\n")
    with pytest.raises(MeshError, match="cannot read mesh"):
        TetMesh.load(path)
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == ""


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 4), st.sampled_from([1, 2, 7, 1000, 2**21, 2**40]), st.integers(0, 60), st.integers(0, 2**32))
def test_unique_rows_equal_numpy_unique_of_rows(width, base, count, seed):
    """One number per row, or numpy's row sort where it would overflow (base**width >= 2**63):
    the same rows, first indices, inverse and counts as np.unique(axis=0)."""
    rows = np.random.default_rng(seed).integers(0, base, size=(count, width))
    options = {"return_index": True, "return_inverse": True, "return_counts": True}
    for got, expected in zip(unique_rows(rows, base, **options), np.unique(rows, axis=0, **options)):
        assert np.array_equal(got, expected.reshape(got.shape))
    assert np.array_equal(unique_rows(rows, base), np.unique(rows, axis=0).reshape(-1, width))
