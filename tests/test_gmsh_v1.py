"""gmsh's first file format (``$NOD``/``$ELM``), as SOFA ships its meshes."""

import numpy as np
import pytest

from wcut.errors import MeshError
from wcut.mesh import TetMesh, beam
from wcut.quadratic import QuadraticTetMesh, to_quadratic


def _write_v1(path, vertices, cells, labels=None):
    """A gmsh format-1 file: ``cells`` is [(gmsh type, rows)], nodes numbered by ``labels``."""
    labels = np.arange(1, len(vertices) + 1) if labels is None else np.asarray(labels)
    lines = ["$NOD", str(len(vertices))]
    lines += [f"{label} {x:.17g} {y:.17g} {z:.17g}" for label, (x, y, z) in zip(labels, vertices)]
    lines += ["$ENDNOD", "$ELM", str(sum(len(rows) for _, rows in cells))]
    number = 1
    for kind, rows in cells:
        for row in rows:
            lines.append(f"{number} {kind} 1 1 {len(row)} " + " ".join(str(labels[i]) for i in row))
            number += 1
    lines.append("$ENDELM")
    path.write_text("\n".join(lines) + "\n")


def test_a_linear_mesh_reads_with_sparse_labels_and_surface_cells(tmp_path):
    mesh = beam(1, 1, 2)
    labels = 10 + 7 * np.arange(mesh.vertex_count)[::-1]  # descending, not contiguous
    path = tmp_path / "liver.msh"
    _write_v1(path, mesh.vertices, [(2, mesh.boundary().triangles[:3]), (4, mesh.tets)], labels)
    loaded = TetMesh.load(path)
    assert np.allclose(loaded.vertices, mesh.vertices)
    assert np.array_equal(loaded.tets, mesh.tets)


def test_a_quadratic_mesh_reads_with_gmsh_node_order(tmp_path):
    mesh = to_quadratic(beam(1, 1, 1))
    gmsh_rows = mesh.tets[:, [0, 1, 2, 3, 4, 5, 6, 7, 9, 8]]  # gmsh: edge (2,3) before (1,3)
    path = tmp_path / "p2.msh"
    _write_v1(path, mesh.vertices, [(11, gmsh_rows)])
    loaded = QuadraticTetMesh.load(path)
    assert np.array_equal(loaded.tets, mesh.tets)


@pytest.mark.parametrize("edit, message", [
    (lambda s: s.replace("$ENDELM\n", ""), "ends before"),
    (lambda s: s.replace("$NOD\n9", "$NOD\n10", 1), "line 12: a node"),
    (lambda s: s.replace(" 4 1 1 4 1 ", " 4 1 1 4 99 ", 1), "node 99"),
    (lambda s: s.replace(" 4 1 1 4 ", " 4 1 1 5 ", 1), "element type 4 with 5 nodes"),
])
def test_a_broken_file_names_the_fault(tmp_path, edit, message):
    mesh = beam(1, 1, 1)
    mesh = TetMesh(np.vstack([mesh.vertices, [[2.0, 2.0, 2.0]]]), np.vstack([mesh.tets, [[1, 3, 5, 8]]]))
    path = tmp_path / "broken.msh"
    _write_v1(path, mesh.vertices, [(4, mesh.tets)])
    path.write_text(edit(path.read_text()))
    with pytest.raises(MeshError, match="broken.msh: cannot read mesh") as info:
        TetMesh.load(path)
    assert message in str(info.value)
