"""Corotational P1 element kernels (kernels/tet_p1.py): patch test, invariance, derivatives,
and the matrix-free product against an independently assembled scipy matrix."""

import numpy as np
import pytest
import warp as wp
from scipy.spatial.transform import Rotation

import wcut
from conftest import assert_listed_product
from wcut.kernels import tet_p1
from wcut.model import Model, lame_parameters
from wcut.reference import ScipyCorotationalStep
from wcut.stress import element_stress

E, NU = 1.0e5, 0.3


@pytest.fixture(scope="module")
def cube_mesh():
    """3x3x3 cells of 5 tets in a 0.3 m cube: 8 interior vertices."""
    return wcut.beam(3, 3, 3, size=(0.3, 0.3, 0.3))


def element_terms(model, x, v=None, rotation_iterations=60, velocity_scale=0.0, matrix_scale=1.0,
                  rotation_stiffness=False):
    """Launch tet_forces; returns forces, rotated gradients and diagonal (float64), and the
    rotation stiffness ``"tangent"`` (zero unless ``rotation_stiffness``)."""
    n = model.particle_count
    zeros = np.zeros((n, 3))
    arrays = {name: wp.zeros(n, dtype=wp.vec3) for name in ("f", "diag")}
    q = wp.full(model.tet_count, wp.quat_identity(), dtype=wp.quat)
    g = wp.zeros(model.tet_count, dtype=wp.mat33)
    tangent = wp.zeros(model.tet_count, dtype=wp.mat33)
    wp.launch(tet_p1.tet_forces, model.tet_count,
              inputs=[model.tet_indices, model.tet_poses, model.tet_stiffness, model.particle_q,
                      wp.array(x, dtype=wp.vec3), wp.array(zeros if v is None else v, dtype=wp.vec3), q,
                      velocity_scale, matrix_scale, rotation_iterations, 1e-7, int(rotation_stiffness)],
              outputs=[q, g, tangent, arrays["f"], arrays["diag"]])
    return ({name: a.numpy().astype(np.float64) for name, a in arrays.items()}
            | {"gradients": g, "rotation": q, "tangent": tangent})


def stiffness_product(model, terms, p, scale=1.0):
    """``scale K_t p`` with the rotated gradients and rotation stiffness of ``element_terms``."""
    y = wp.zeros(model.particle_count, dtype=wp.vec3)
    wp.launch(tet_p1.tet_matvec, model.tet_count,
              inputs=[model.tet_indices, terms["gradients"], terms["tangent"], model.tet_stiffness,
                      wp.array(p, dtype=wp.vec3), scale],
              outputs=[y])
    return y.numpy().astype(np.float64)


def interior(mesh):
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    return np.flatnonzero(np.all((mesh.vertices > lo + 1e-9) & (mesh.vertices < hi - 1e-9), axis=1))


@pytest.mark.parametrize("rotated", [False, True])
def test_patch_test_affine_displacement_gives_exact_strain_and_no_interior_force(cube_mesh, rotated):
    """x = Q (I + H) X + c with H symmetric: strain H in the rotated frame, stress Q sigma(H) Q^T."""
    model = Model(cube_mesh, youngs_modulus=E, poisson_ratio=NU)
    H = np.array([[0.02, 0.005, -0.004], [0.005, -0.01, 0.003], [-0.004, 0.003, 0.015]])
    Q = Rotation.from_rotvec([0.3, -1.2, 0.8]).as_matrix() if rotated else np.eye(3)
    x = cube_mesh.vertices @ (Q @ (np.eye(3) + H)).T + np.array([0.1, -0.2, 0.05])
    terms = element_terms(model, x)
    inner = interior(cube_mesh)
    assert len(inner) == 8
    scale = np.abs(terms["f"]).max()
    assert np.abs(terms["f"][inner]).max() < 1e-4 * scale
    state = model.state()
    state.particle_q.assign(x)
    state.tet_rotation.assign(terms["rotation"])
    stress, von_mises = element_stress(model, state)
    mu, lam = lame_parameters(E, NU)
    local = 2 * mu * H + lam * np.trace(H) * np.eye(3)
    # float32 positions carry ~1e-7 strain noise against 1e-2 strain
    np.testing.assert_allclose(stress, np.broadcast_to(Q @ local @ Q.T, stress.shape), atol=1e-4 * np.abs(local).max())
    deviator = local - np.trace(local) / 3 * np.eye(3)
    np.testing.assert_allclose(von_mises, np.sqrt(1.5 * np.sum(deviator ** 2)), rtol=1e-4)


def test_rigid_motion_gives_no_ghost_forces(cube_mesh):
    model = Model(cube_mesh, youngs_modulus=E, poisson_ratio=NU)
    Q = Rotation.from_rotvec([0.4, -2.0, 1.1]).as_matrix()  # a large rotation
    x = cube_mesh.vertices @ Q.T + np.array([1.0, 2.0, -0.5])
    f = element_terms(model, x)["f"]
    reference_scale = np.abs(element_terms(model, cube_mesh.vertices * 1.01)["f"]).max()  # 1% stretch
    # float32 positions 2 m from the origin carry ~1e-6 strain noise; a linear (not corotated)
    # element would give forces about 100x the reference here
    assert np.abs(f).max() < 1e-3 * reference_scale


def test_forces_rotate_with_the_body(cube_mesh):
    model = Model(cube_mesh, youngs_modulus=E, poisson_ratio=NU)
    rng = np.random.default_rng(7)
    x = cube_mesh.vertices + 0.01 * rng.standard_normal(cube_mesh.vertices.shape)
    Q = Rotation.from_rotvec([1.2, 0.3, -0.8]).as_matrix()
    f = element_terms(model, x)["f"]
    f_rotated = element_terms(model, x @ Q.T + np.array([0.3, 0.0, 1.0]))["f"]
    np.testing.assert_allclose(f_rotated, f @ Q.T, atol=2e-4 * np.abs(f).max())


def test_forces_match_the_independent_scipy_reference(cube_mesh):
    model = Model(cube_mesh, youngs_modulus=E, poisson_ratio=NU)
    ref = ScipyCorotationalStep(cube_mesh.vertices, cube_mesh.tets, density=1000.0, youngs_modulus=E,
                                poisson_ratio=NU)
    rng = np.random.default_rng(8)
    Q = Rotation.from_rotvec([0.2, 0.9, -0.4]).as_matrix()
    x = (cube_mesh.vertices + 0.01 * rng.standard_normal(cube_mesh.vertices.shape)) @ Q.T
    f_ref = ref.internal_forces(x)
    np.testing.assert_allclose(element_terms(model, x)["f"], f_ref, atol=1e-4 * np.abs(f_ref).max())


def test_force_derivative_matches_finite_differences(cube_mesh):
    """At a rotated rest shape the tangent is exactly R K R^T; under strain the difference is O(strain)."""
    model = Model(cube_mesh, youngs_modulus=E, poisson_ratio=NU)
    rng = np.random.default_rng(9)
    Q = Rotation.from_rotvec([0.5, -0.7, 0.2]).as_matrix()
    direction = rng.standard_normal(cube_mesh.vertices.shape)
    h = 1e-4  # m
    for strain, tolerance in ((0.0, 2e-3), (0.02, 0.1)):
        x = (cube_mesh.vertices * (1 + strain)) @ Q.T
        terms = element_terms(model, x)
        fd = (element_terms(model, x + h * direction)["f"] - element_terms(model, x - h * direction)["f"]) / (2 * h)
        product = stiffness_product(model, terms, direction)
        error = np.abs(fd + product).max() / np.abs(product).max()
        assert error < tolerance, (strain, error)
        if strain == 0.0:
            exact_error = error
    assert exact_error < error  # the O(strain) term of the full tangent shows up only under strain


def test_matrix_free_product_is_symmetric_and_equals_the_assembled_matrix(cube_mesh):
    model = Model(cube_mesh, youngs_modulus=E, poisson_ratio=NU)
    ref = ScipyCorotationalStep(cube_mesh.vertices, cube_mesh.tets, density=1000.0, youngs_modulus=E,
                                poisson_ratio=NU)
    rng = np.random.default_rng(10)
    Q = Rotation.from_rotvec([-1.0, 0.4, 0.3]).as_matrix()
    x = (cube_mesh.vertices + 0.02 * rng.standard_normal(cube_mesh.vertices.shape)) @ Q.T
    terms = element_terms(model, x)
    K = ref.stiffness_matrix(x)
    u, w = rng.standard_normal((2, model.particle_count, 3))
    Ku = stiffness_product(model, terms, u)
    Kw = stiffness_product(model, terms, w)
    np.testing.assert_allclose(Ku.ravel(), K @ u.ravel(), atol=1e-4 * np.abs(Ku).max())
    assert abs(np.vdot(w, Ku) - np.vdot(u, Kw)) < 1e-5 * abs(np.vdot(u, Ku))
    np.testing.assert_allclose(terms["diag"].ravel(), K.diagonal(), rtol=1e-4)


def _tension_state(mesh, seed):
    """A rotated state in tension: stretched 15% along a tilted axis, 5% across, with noise."""
    rng = np.random.default_rng(seed)
    axis = np.array([1.0, 0.4, -0.2]) / np.linalg.norm([1.0, 0.4, -0.2])
    U = np.eye(3) + 0.15 * np.outer(axis, axis) + 0.05 * (np.eye(3) - np.outer(axis, axis))
    Q = Rotation.from_rotvec([0.5, -0.7, 0.2]).as_matrix()
    return (mesh.vertices @ U.T + 1e-3 * rng.standard_normal(mesh.vertices.shape)) @ Q.T


def test_tangent_with_rotation_stiffness_matches_finite_differences_in_tension(cube_mesh):
    """In tension every eigenvalue of the rotation stiffness is positive, nothing is projected,
    so R K R^T + K_G is the exact derivative of the force; R K R^T alone misses K_G."""
    model = Model(cube_mesh, youngs_modulus=E, poisson_ratio=NU)
    rng = np.random.default_rng(11)
    direction = rng.standard_normal(cube_mesh.vertices.shape)
    x = _tension_state(cube_mesh, 12)
    h = 1e-4  # m
    errors = {}
    for with_tangent in (True, False):
        terms = element_terms(model, x, rotation_stiffness=with_tangent)
        fd = (element_terms(model, x + h * direction)["f"] - element_terms(model, x - h * direction)["f"]) / (2 * h)
        product = stiffness_product(model, terms, direction)
        errors[with_tangent] = np.abs(fd + product).max() / np.abs(product).max()
    assert errors[True] < 3e-3, errors
    assert errors[False] > 10 * errors[True], errors


def test_rotation_stiffness_is_zero_at_rest_and_under_rigid_motion(cube_mesh):
    model = Model(cube_mesh, youngs_modulus=E, poisson_ratio=NU)
    Q = Rotation.from_rotvec([0.4, -2.0, 1.1]).as_matrix()
    tangent = element_terms(model, cube_mesh.vertices @ Q.T + 0.5, rotation_stiffness=True)["tangent"].numpy()
    stretched = element_terms(model, _tension_state(cube_mesh, 13), rotation_stiffness=True)["tangent"].numpy()
    assert np.abs(tangent).max() < 1e-4 * np.abs(stretched).max()


@pytest.mark.parametrize("amplitude", [0.02, 0.2])
def test_tangent_product_is_symmetric_and_adds_a_positive_semidefinite_term(cube_mesh, amplitude):
    """Random states mix tension and compression: the projected rotation stiffness keeps the
    product symmetric, adds u.K_G u >= 0, and its diagonal (the preconditioner) is exact."""
    model = Model(cube_mesh, youngs_modulus=E, poisson_ratio=NU)
    rng = np.random.default_rng(14)
    x = cube_mesh.vertices + amplitude * 0.1 * rng.standard_normal(cube_mesh.vertices.shape)
    plain, full = (element_terms(model, x, rotation_stiffness=flag) for flag in (False, True))
    assert np.abs(full["tangent"].numpy()).max() > 0.0
    n = model.particle_count
    u, w = rng.standard_normal((2, n, 3))
    Ku, Kw = stiffness_product(model, full, u), stiffness_product(model, full, w)
    assert abs(np.vdot(w, Ku) - np.vdot(u, Kw)) < 1e-5 * abs(np.vdot(u, Ku))
    for trial in rng.standard_normal((20, n, 3)):
        extra = np.vdot(trial, stiffness_product(model, full, trial) - stiffness_product(model, plain, trial))
        assert extra >= -1e-6 * np.vdot(trial, stiffness_product(model, plain, trial))
    # each node's diagonal: the product with unit vectors
    for node in (0, n // 2, n - 1):
        for axis in range(3):
            unit = np.zeros((n, 3))
            unit[node, axis] = 1.0
            column = stiffness_product(model, full, unit)
            assert column[node, axis] == pytest.approx(full["diag"][node, axis], rel=1e-4)
    # the independently assembled reference (eigen-decomposition by numpy) agrees
    ref = ScipyCorotationalStep(cube_mesh.vertices, cube_mesh.tets, density=1000.0, youngs_modulus=E,
                                poisson_ratio=NU, rotation_stiffness=True)
    np.testing.assert_allclose(Ku.ravel(), ref.stiffness_matrix(x) @ u.ravel(), atol=2e-4 * np.abs(Ku).max())


def test_rotation_stiffness_adds_tangent_damping_to_the_force(cube_mesh):
    """The Rayleigh term of tet_forces is -c_v K_t v, the product applied to the velocity."""
    model = Model(cube_mesh, youngs_modulus=E, poisson_ratio=NU)
    x = _tension_state(cube_mesh, 15)
    v = np.random.default_rng(16).standard_normal(x.shape)
    still = element_terms(model, x, rotation_stiffness=True)
    moving = element_terms(model, x, v=v, velocity_scale=0.01, rotation_stiffness=True)
    np.testing.assert_allclose(moving["f"] - still["f"], -0.01 * stiffness_product(model, still, v),
                               atol=1e-4 * np.abs(moving["f"] - still["f"]).max())


def test_listed_product_is_the_product_of_the_listed_elements(cube_mesh):
    """tet_matvec_listed adds the listed elements' shares of tet_matvec, and nothing else: over
    a list and its complement, the sum is the whole product."""
    model = Model(cube_mesh, youngs_modulus=E, poisson_ratio=NU)
    rng = np.random.default_rng(3)
    x = cube_mesh.vertices + 0.01 * rng.standard_normal(cube_mesh.vertices.shape)
    terms = element_terms(model, x, rotation_stiffness=True)
    p = rng.standard_normal((model.particle_count, 3))
    assert_listed_product(tet_p1.tet_matvec_listed, model, terms, p, stiffness_product(model, terms, p, scale=0.7), 3)
