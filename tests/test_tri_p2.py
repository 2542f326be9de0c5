"""The 6-node corotational membrane (wcut.kernels.tri_p2): forces are the gradient of the
corotational energy, zero for rigid motions, pass the patch test; the solver's matrix is
symmetric, positive semi-definite, the force's derivative at rest, and its diagonal and warm
start product are consistent with its product."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from conftest import axis_angle_rotation

from wcut import shell
from wcut.kernels import tri_p2
from wcut.mesh import ShellMesh, rectangle_sheet
from wcut.model import Model

YOUNG, NU, THICKNESS = 1.0e5, 0.3, 1.0e-3


def _curved_sheet() -> ShellMesh:
    """A 3x2 sheet bent over a cylinder of radius 0.5 m (curved 6-node triangles)."""
    flat = rectangle_sheet(3, 2, (0.3, 0.2))
    x, y = flat.vertices[:, 0], flat.vertices[:, 1]
    return ShellMesh(np.column_stack([0.5 * np.sin(x / 0.5), y, 0.5 * (1 - np.cos(x / 0.5))]), flat.triangles)


def _model(mesh) -> Model:
    return Model(mesh, youngs_modulus=YOUNG, poisson_ratio=NU, thickness=THICKNESS)


class _Pass:
    """One launch of tri_forces at positions q and velocities v."""

    def __init__(self, model: Model, q, v=None, velocity_scale=0.0, matrix_scale=1.0):
        n, m = model.particle_count, model.tri_count
        zero = np.zeros((n, 3))
        self.f, self.diagonal = (wp.zeros(n, dtype=wp.vec3) for _ in range(2))
        self.rotation = wp.zeros((m, 3), dtype=tri_p2.mat32)
        self.tension = wp.zeros((m, 3), dtype=wp.mat22)
        wp.launch(tri_p2.tri_forces, m,
                  inputs=[model.tri_indices, model.tri_poses, model.tri_stiffness, wp.array(q, dtype=wp.vec3),
                          wp.array(zero if v is None else v, dtype=wp.vec3), velocity_scale, matrix_scale],
                  outputs=[self.rotation, self.tension, self.f, self.diagonal])
        self.model = model

    def matvec(self, x) -> np.ndarray:
        m = self.model
        y = wp.zeros(m.particle_count, dtype=wp.vec3)
        wp.launch(tri_p2.tri_matvec, m.tri_count,
                  inputs=[m.tri_indices, m.tri_poses, m.tri_stiffness, self.rotation, self.tension,
                          wp.array(x, dtype=wp.vec3), 1.0], outputs=[y])
        return y.numpy().astype(np.float64)


def membrane_energy(model: Model, q: np.ndarray) -> float:
    """``sum_g A_g h (mu |S - I|^2 + lambda*/2 tr(S - I)^2)`` (J), S the polar stretch."""
    tris = model.tri_indices.numpy().reshape(-1, 6)
    dN = shell.shape_gradients(shell.GAUSS_POINTS)
    F = np.einsum("mai,gaj->mgij", q[tris], dN) @ model.tri_poses.numpy()
    w, V = np.linalg.eigh(np.swapaxes(F, -1, -2) @ F)
    E = V @ (np.sqrt(w)[..., None] * np.swapaxes(V, -1, -2)) - np.eye(2)
    c = model.tri_stiffness.numpy()
    return float(np.sum(c[..., 0] * np.sum(E * E, axis=(-1, -2)) + 0.5 * c[..., 1] * np.trace(E, axis1=-2, axis2=-1) ** 2))


@pytest.mark.parametrize("curved", [False, True])
def test_rest_and_rigid_motions_are_force_free(curved):
    mesh = _curved_sheet() if curved else rectangle_sheet(3, 2, (0.3, 0.2))
    model = _model(mesh)
    scale = YOUNG * THICKNESS * 0.1  # N: the force of a unit strain on a 0.1 m edge
    X = mesh.vertices
    assert np.abs(_Pass(model, X).f.numpy()).max() < 1e-5 * scale
    moved = X @ axis_angle_rotation([1.0, 2.0, 0.5], 2.5).T + np.array([0.3, -1.0, 2.0])
    assert np.abs(_Pass(model, moved).f.numpy()).max() < 1e-5 * scale


def test_forces_are_the_gradient_of_the_corotational_energy():
    mesh = _curved_sheet()
    model = _model(mesh)
    rng = np.random.default_rng(1)
    q = mesh.vertices + 0.02 * rng.standard_normal(mesh.vertices.shape)
    f = _Pass(model, q).f.numpy()
    eps, expected = 1e-6, np.zeros_like(q)
    for i in range(len(q)):
        for k in range(3):
            step = np.zeros_like(q)
            step[i, k] = eps
            expected[i, k] = -(membrane_energy(model, q + step) - membrane_energy(model, q - step)) / (2 * eps)
    assert np.abs(f - expected).max() < 1e-4 * np.abs(expected).max()


def test_patch_test_affine_stretch_gives_uniform_stress_and_interior_equilibrium():
    """A tilted sheet stretched by an in-plane affine map: every Gauss point carries the
    analytic plane stress, and every interior node is in equilibrium (thesis 3.5's patch test)."""
    mesh = rectangle_sheet(4, 3, (0.4, 0.3))
    rng = np.random.default_rng(2)
    inner = mesh.vertices[:, 0] * (mesh.vertices[:, 0] - 0.4) * mesh.vertices[:, 1] * (mesh.vertices[:, 1] - 0.3) != 0
    jitter = 0.004 * rng.standard_normal(mesh.vertices.shape) * np.array([1.0, 1.0, 0.0])
    flat = mesh.vertices + jitter * inner[:, None]  # irregular interior, including curved elements
    tilt = axis_angle_rotation([1.0, -1.0, 0.3], 0.7)
    mesh = ShellMesh(flat @ tilt.T, mesh.triangles)
    model = _model(mesh)
    strain = np.array([[0.02, 0.005], [0.005, -0.01]])  # symmetric: no rotation part
    stretch = np.eye(3)
    stretch[:2, :2] += strain
    q = (flat @ stretch.T) @ tilt.T
    stress = wp.zeros((model.tri_count, 3), dtype=wp.mat33)
    wp.launch(tri_p2.tri_stress, model.tri_count,
              inputs=[model.tri_indices, model.tri_poses, model.tri_lame, wp.array(q, dtype=wp.vec3)],
              outputs=[stress])
    mu, lam = shell.plane_stress_lame(YOUNG, NU)
    plane = 2 * mu * strain + lam * np.trace(strain) * np.eye(2)
    expected = tilt[:, :2] @ plane @ tilt[:, :2].T
    assert np.abs(stress.numpy() - expected).max() < 1e-4 * np.abs(plane).max()
    f = _Pass(model, q).f.numpy()
    scale = np.abs(f).max()
    assert np.abs(f[inner]).max() < 1e-4 * scale


def test_matrix_is_symmetric_psd_and_the_force_derivative_at_rest():
    mesh = _curved_sheet()
    model = _model(mesh)
    rng = np.random.default_rng(3)
    X = mesh.vertices
    at_rest = _Pass(model, X)
    a, b = rng.standard_normal(X.shape), rng.standard_normal(X.shape)
    Ka, Kb = at_rest.matvec(a), at_rest.matvec(b)
    assert abs(np.sum(a * Kb) - np.sum(b * Ka)) < 1e-4 * np.abs(Ka).max() * np.abs(b).sum()
    eps = 1e-4
    derivative = -(_Pass(model, X + eps * a).f.numpy() - _Pass(model, X - eps * a).f.numpy()) / (2 * eps)
    assert np.abs(derivative - Ka).max() < 1e-2 * np.abs(Ka).max()


def test_tension_adds_positive_stiffness_out_of_the_plane():
    """A flat sheet resists moving a node out of its plane only when it is in tension (the
    geometric stiffness); stretched, the matrix stays positive semi-definite."""
    mesh = rectangle_sheet(3, 2, (0.3, 0.2))
    model = _model(mesh)
    X = mesh.vertices
    at_rest, stretched = _Pass(model, X), _Pass(model, X * np.array([1.05, 1.03, 1.0]))
    normal = np.zeros_like(X)
    normal[len(X) // 2] = [0.0, 0.0, 1.0]
    alternating = np.zeros_like(X)
    alternating[::2, 0] = 1.0
    in_plane = at_rest.matvec(alternating)  # the scale of the membrane stiffness
    assert abs(np.sum(normal * at_rest.matvec(normal))) < 1e-6 * np.abs(in_plane).max()
    assert np.sum(normal * stretched.matvec(normal)) > 1e-3 * np.abs(in_plane).max()
    rng = np.random.default_rng(6)
    for _ in range(5):
        x = rng.standard_normal(X.shape)
        assert np.sum(x * stretched.matvec(x)) > 0.0


def test_diagonal_agrees_with_the_product():
    mesh = rectangle_sheet(2, 1, (0.2, 0.1))
    model = _model(mesh)
    rng = np.random.default_rng(4)
    X = mesh.vertices
    q = X * np.array([1.04, 0.99, 1.0]) + 0.002 * rng.standard_normal(X.shape)
    one = _Pass(model, q, matrix_scale=0.5)
    diagonal = np.zeros_like(X)
    for i in range(len(X)):
        for k in range(3):
            e = np.zeros_like(X)
            e[i, k] = 1.0
            diagonal[i, k] = one.matvec(e)[i, k]
    assert np.allclose(one.diagonal.numpy(), 0.5 * diagonal, rtol=1e-4, atol=1e-6 * diagonal.max())


def test_velocity_term_is_the_matrix_times_velocity():
    """``particle_f`` carries ``f(x) - c_v K v`` (the implicit right-hand side's damping term)."""
    mesh = rectangle_sheet(2, 2, (0.2, 0.2))
    model = _model(mesh)
    rng = np.random.default_rng(5)
    q = mesh.vertices * np.array([1.03, 1.02, 1.0])
    v = rng.standard_normal(q.shape)
    still, moving = _Pass(model, q), _Pass(model, q, v=v, velocity_scale=0.01)
    expected = still.f.numpy() - 0.01 * still.matvec(v)
    assert np.abs(moving.f.numpy() - expected).max() < 1e-4 * np.abs(expected).max()
