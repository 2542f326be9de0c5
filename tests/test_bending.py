"""Hinge bending of thin shells (wcut.kernels.bending, wcut.shell.hinges): force-free at rest
and under rigid motions (flat and curved rest shapes), forces and matrix of the energy, the
plate energy of a cylinder, and a cantilever strip that sags as Euler-Bernoulli predicts."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from conftest import axis_angle_rotation

from wcut import shell
from wcut.kernels import attachments, bending
from wcut.mesh import rectangle_sheet
from wcut.model import Model
from wcut.solver import SolverCorotational


def _cylinder(points: np.ndarray, radius: float, angle_deg: float = 0.0) -> np.ndarray:
    """Points of the xy-plane wrapped isometrically on a cylinder whose axis is at
    ``angle_deg + 90`` degrees to the x axis."""
    c, s = np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))
    u = points[:, 0] * c + points[:, 1] * s
    v = -points[:, 0] * s + points[:, 1] * c
    return np.column_stack([radius * np.sin(u / radius), v, radius * (1.0 - np.cos(u / radius))])


class _Hinges:
    def __init__(self, rest: np.ndarray, triangles: np.ndarray, rigidity: float = 1.0):
        self.data = shell.hinges(rest, triangles, np.full(len(triangles), rigidity))
        indices, weights, stiffness, curvature = self.data
        self.arrays = [wp.array(indices.astype(np.int32), dtype=wp.vec4i), wp.array(weights, dtype=wp.vec4),
                       wp.array(stiffness, dtype=float)]
        self.curvature = wp.array(curvature, dtype=wp.vec3)
        self.count = len(indices)

    def forces(self, q, matrix_scale=1.0):
        n = len(q)
        f, diagonal = (wp.zeros(n, dtype=wp.vec3) for _ in range(2))
        zero = wp.zeros(n, dtype=wp.vec3)
        wp.launch(bending.hinge_forces, self.count,
                  inputs=[*self.arrays, self.curvature, wp.array(q, dtype=wp.vec3), zero, 0.0, matrix_scale],
                  outputs=[f, diagonal])
        return f.numpy().astype(np.float64), diagonal.numpy()

    def matvec(self, x) -> np.ndarray:
        y = wp.zeros(len(x), dtype=wp.vec3)
        wp.launch(attachments.attachment_matvec, self.count,
                  inputs=[*self.arrays, wp.array(x, dtype=wp.vec3), 1.0], outputs=[y])
        return y.numpy().astype(np.float64)


def test_hinge_weights_annihilate_affine_fields_and_measure_the_fold_angle():
    mesh = rectangle_sheet(2, 2, (0.2, 0.2))
    indices, weights, stiffness, curvature = shell.hinges(mesh.vertices, mesh.triangles, np.ones(8))
    assert np.allclose(weights.sum(axis=1), 0.0, atol=1e-9)
    assert np.abs(np.einsum("hi,hij->hj", weights, mesh.vertices[indices])).max() < 1e-9
    assert np.abs(curvature).max() < 1e-9 and (stiffness > 0).all()
    # folding one hinge by phi about its edge gives |sum w x| = 2 sin(phi / 2) ~ phi
    X = mesh.vertices[indices[0]].copy()
    axis, phi = X[1] - X[0], 0.01
    X[3] = X[0] + axis_angle_rotation(axis, phi) @ (X[3] - X[0])
    assert np.linalg.norm(weights[0] @ X) == pytest.approx(2 * np.sin(phi / 2), rel=1e-9)


@pytest.mark.parametrize("curved", [False, True])
def test_rest_and_rigid_motions_are_force_free(curved):
    mesh = rectangle_sheet(3, 2, (0.3, 0.2))
    rest = _cylinder(mesh.vertices, 0.3) if curved else mesh.vertices
    hinges = _Hinges(rest, mesh.triangles)
    assert (np.abs(hinges.data[3]).max() > 1e-3) == curved
    bent = _cylinder(mesh.vertices, 0.5, 20.0) if not curved else mesh.vertices
    scale = np.abs(hinges.forces(bent)[0]).max()  # the force of a comparable bend
    assert np.abs(hinges.forces(rest)[0]).max() < 1e-4 * scale  # float32 rounding of the points
    moved = rest @ axis_angle_rotation([0.3, -1.0, 2.0], 2.0).T + np.array([0.3, -0.2, 0.1])
    assert np.abs(hinges.forces(moved)[0]).max() < 1e-4 * scale


def test_forces_diagonal_and_product_of_the_flat_energy():
    """For a flat rest shape the energy is the quadratic ``1/2 sum k |w.x|^2``: the force is its
    exact gradient, and the matrix and its diagonal are its Hessian."""
    mesh = rectangle_sheet(2, 2, (0.2, 0.2))
    hinges = _Hinges(mesh.vertices, mesh.triangles, rigidity=0.01)
    rng = np.random.default_rng(7)
    q = mesh.vertices + 0.01 * rng.standard_normal(mesh.vertices.shape)
    f, diagonal = hinges.forces(q, matrix_scale=0.25)
    eps, expected = 1e-6, np.zeros_like(q)
    for i in range(len(q)):
        for k in range(3):
            step = np.zeros_like(q)
            step[i, k] = eps
            expected[i, k] = -(shell.bending_energy(q + step, *hinges.data) -
                               shell.bending_energy(q - step, *hinges.data)) / (2 * eps)
    assert np.abs(f - expected).max() < 1e-4 * np.abs(expected).max()
    assert np.allclose(-hinges.matvec(q), f, rtol=1e-4, atol=1e-4 * np.abs(f).max())
    probe = np.zeros_like(q)
    probe[5, 2] = 1.0
    assert diagonal[5, 2] == pytest.approx(0.25 * hinges.matvec(probe)[5, 2], rel=1e-5)


def test_a_cylinder_stores_the_plate_bending_energy():
    """``D/2 (1/r)^2 A`` for a sheet bent about a mesh line, converging as the mesh refines (the
    free boundary's hinges are missing); within a factor 1.8 at any angle (hinge anisotropy)."""
    radius, size = 0.5, 0.4
    exact = 0.5 * size * size / radius ** 2  # D = 1
    ratios = []
    for n in (4, 8, 16):
        mesh = rectangle_sheet(n, n, (size, size), origin=(-size / 2, -size / 2, 0.0))
        data = shell.hinges(mesh.vertices, mesh.triangles, np.ones(mesh.triangle_count))
        ratios.append(shell.bending_energy(_cylinder(mesh.vertices, radius), *data) / exact)
        if n == 16:
            oblique = [shell.bending_energy(_cylinder(mesh.vertices, radius, a), *data) / exact for a in (30, 45, 60)]
    assert ratios[0] < ratios[1] < ratios[2] <= 1.0
    assert ratios[2] > 0.96
    assert 1.0 < min(oblique) and max(oblique) < 1.8


def test_cantilever_strip_sags_as_euler_bernoulli_predicts():
    """A clamped 10 cm strip (nu = 0) under its weight: tip deflection ``1.5 rho g L^4 / (E h^2)``
    of a beam of rigidity ``E b h^3 / 12``; error under 5% on 8 elements, smaller than on 4."""
    length, width, h, young, rho, g = 0.1, 0.02, 1e-3, 1e9, 1000.0, 9.81
    expected = 1.5 * rho * g * length ** 4 / (young * h * h)  # 1.5 mm: small deflection
    errors = []
    for n in (4, 8):
        mesh = rectangle_sheet(n, max(1, n // 4), (length, width))
        clamp = mesh.vertices_in_box((-1.0, -1.0, -1.0), (1.0001 * length / (2 * n), 1.0, 1.0))  # two node rows
        model = Model(mesh, density=rho, youngs_modulus=young, poisson_ratio=0.0, thickness=h,
                      gravity=(0.0, 0.0, -g), fixed=clamp, rayleigh_mass=20.0)
        solver = SolverCorotational(model, cg_iterations=500, cg_tolerance=1e-8)
        state, scratch = model.state(), model.state()
        for _ in range(60):  # heavily damped large steps: the static solution
            solver.step(state, scratch, None, 0.05)
            state, scratch = scratch, state
        solver.check()
        tip = -state.particle_q.numpy()[mesh.vertices[:, 0] > length - 1e-9, 2].mean()
        errors.append(abs(tip / expected - 1.0))
    assert errors[1] < 0.05 and errors[1] < errors[0]
