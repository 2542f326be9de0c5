"""The 6-node triangle's host-side data (wcut.shell) and shell models: quadrature, rest frames,
lumped masses and loads, normals, and a shell Model run by the solver."""

from __future__ import annotations

import numpy as np
import pytest

from wcut import shell
from wcut.errors import ModelError
from wcut.mesh import ShellMesh, beam, rectangle_sheet
from wcut.model import Model
from wcut.solver import SolverCorotational


def _consistent_mass_diagonal_and_load():
    """Diagonal of the consistent mass matrix and the load vector of the reference element,
    per unit area, by the degree-5 area rule (exact for these degree-4 and degree-2 integrands)."""
    N = shell.shape_functions(shell.AREA_POINTS)
    w = shell.AREA_WEIGHTS / 0.5
    return (w[:, None] * N * N).sum(axis=0), (w[:, None] * N).sum(axis=0)


def test_lumped_masses_and_loads_are_the_consistent_ones():
    diagonal, load = _consistent_mass_diagonal_and_load()
    assert np.allclose(diagonal[:3], 1 / 30) and np.allclose(diagonal[3:], 8 / 45)
    assert np.allclose(shell.HRZ_FRACTIONS, diagonal / diagonal.sum())
    assert np.allclose(shell.LOAD_FRACTIONS, load, atol=1e-15)
    assert (shell.HRZ_FRACTIONS > 0).all() and shell.HRZ_FRACTIONS.sum() == pytest.approx(1.0)


def test_shape_gradients_are_the_derivatives_of_the_shape_functions():
    rng = np.random.default_rng(0)
    L = rng.dirichlet(np.ones(3), size=5)
    eps = 1e-6
    for k, direction in enumerate(([-1.0, 1.0, 0.0], [-1.0, 0.0, 1.0])):
        step = eps * np.array(direction)
        numeric = (shell.shape_functions(L + step) - shell.shape_functions(L - step)) / (2 * eps)
        assert np.allclose(shell.shape_gradients(L)[:, :, k], numeric, atol=1e-8)


def test_rest_frames_of_a_curved_sheet():
    flat = rectangle_sheet(4, 2, (0.4, 0.2))
    x, y = flat.vertices[:, 0], flat.vertices[:, 1]
    radius = 0.3
    mesh = ShellMesh(np.column_stack([radius * np.sin(x / radius), y, radius * (1 - np.cos(x / radius))]),
                     flat.triangles)
    poses, areas, frames = shell.rest_frames(mesh.vertices, mesh.triangles)
    assert (areas > 0).all()
    assert areas.sum() == pytest.approx(mesh.area(), rel=1e-3)  # degree 2 on a curved surface
    assert np.allclose(np.swapaxes(frames, -1, -2) @ frames, np.eye(3), atol=1e-12)
    # the rest Jacobian maps the reference tangents onto the tangent basis: J^-1 undoes it
    T = np.einsum("mai,gaj->mgij", mesh.vertices[mesh.triangles], shell.shape_gradients(shell.GAUSS_POINTS))
    assert np.allclose(T @ poses, frames[..., :2], atol=1e-9)


def test_vertex_normals_of_a_cylinder_point_outwards_from_its_axis():
    flat = rectangle_sheet(6, 2, (0.6, 0.2))
    angle = flat.vertices[:, 0] / 0.3
    points = np.column_stack([0.3 * np.sin(angle), flat.vertices[:, 1], -0.3 * np.cos(angle)])
    normals = shell.vertex_normals(points, flat.triangles)
    radial = points * np.array([1.0, 0.0, 1.0]) / 0.3
    cosine = -np.einsum("ij,ij->i", normals, radial)  # the sheet runs counter-clockwise seen from +z
    edge = (flat.vertices[:, 0] < 1e-9) | (flat.vertices[:, 0] > 0.6 - 1e-9)
    assert cosine[~edge].min() > 1 - 5e-4
    assert cosine[edge].min() > 1 - 5e-3  # one-sided: half a sub-triangle's turn, 4.8 degrees


def test_shell_model_arrays():
    mesh = rectangle_sheet(3, 2, (0.3, 0.2))
    model = Model(mesh, density=1200.0, thickness=2e-3, gravity=(0.0, 0.0, -9.81))
    assert (model.tet_count, model.tri_count) == (0, 12)
    # every edge of the 4 x 12 sub-triangles is a hinge except the 2 halves of each boundary edge
    assert model.edge_count == (3 * 4 * 12 - 2 * len(mesh.boundary_edges())) // 2
    mass = model.particle_mass.numpy()
    assert (mass > 0).all() and mass.sum() == pytest.approx(1200.0 * 2e-3 * 0.06, rel=1e-6)
    assert model.particle_load_mass.numpy().sum() == pytest.approx(mass.sum(), rel=1e-6)
    assert np.allclose(model.tri_rest_area.numpy(), 0.005)
    with pytest.raises(ModelError, match="thickness"):
        Model(mesh, thickness=0.0)
    with pytest.raises(ModelError, match="a shell model is rebuilt from a ShellMesh"):
        model.rebuild(beam(1, 1, 1), None)


def test_a_sheet_hung_by_two_corners_droops_and_stays_finite_over_1000_steps():
    mesh = rectangle_sheet(6, 6, (0.3, 0.3))
    corners = [int(np.argmin(np.linalg.norm(mesh.vertices - c, axis=1))) for c in ([0, 0.3, 0], [0.3, 0.3, 0])]
    model = Model(mesh, density=500.0, youngs_modulus=1e6, poisson_ratio=0.3, thickness=5e-4,
                  gravity=(0.0, 0.0, -9.81), fixed=corners, rayleigh_mass=0.5, rayleigh_stiffness=1e-3)
    solver = SolverCorotational(model, cg_iterations=50)
    state, scratch = model.state(), model.state()
    for _ in range(1000):
        solver.step(state, scratch, None, 1.0 / 120.0)
        state, scratch = scratch, state
    solver.check()
    q = state.particle_q.numpy()
    assert q[:, 2].min() < -0.2  # it hangs: the free edge fell by most of the sheet's height
    spans = np.linalg.norm(q[mesh.triangles[:, 1]] - q[mesh.triangles[:, 0]], axis=1)
    rest = np.linalg.norm(mesh.vertices[mesh.triangles[:, 1]] - mesh.vertices[mesh.triangles[:, 0]], axis=1)
    assert np.abs(spans / rest - 1.0).max() < 0.05  # a membrane this stiff barely stretches
    assert np.abs(state.particle_qd.numpy()).max() < 1.0  # and it settles
