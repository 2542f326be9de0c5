"""Corotational P2 element kernels (kernels/tet_p2.py) and the quadratic Model and solver:
against the independently assembled reference (wcut/reference_p2.py), patch test, rigid
invariance, masses, and a static solve through the dynamic solver."""

import numpy as np
import pytest
import warp as wp
from scipy.spatial.transform import Rotation

import wcut
from conftest import assert_listed_product
from wcut import p2, reference_p2
from wcut.errors import ModelError
from wcut.kernels import tet_p2
from wcut.model import Model
from wcut.quadratic import to_quadratic
from wcut.solver import SolverCorotational
from wcut.stress import element_stress

E, NU, RHO = 1.0e5, 0.3, 1000.0
CENTER = np.array([0.15, 0.1, 0.1])


@pytest.fixture(scope="module")
def curved():
    """A 3x2x2-cell block with its boundary curved onto an ellipsoid."""
    ellipsoid = lambda x: np.linalg.norm((x - CENTER) / [0.25, 0.17, 0.17], axis=1) - 1.0  # noqa: E731
    return to_quadratic(wcut.beam(3, 2, 2, size=(0.3, 0.2, 0.2)), ellipsoid)


@pytest.fixture(scope="module")
def straight():
    """3x3x3 cells in a 0.3 m cube: interior nodes exist (corners and edge nodes)."""
    return to_quadratic(wcut.beam(3, 3, 3, size=(0.3, 0.3, 0.3)))


def element_pass(model, x, v=None, velocity_scale=0.0, matrix_scale=1.0, rotation_stiffness=False):
    """Launch tet_forces from identity rotations, iterated to convergence; float64 results
    (``"tangent"``: the rotation stiffness, zero unless ``rotation_stiffness``)."""
    n = model.particle_count
    zeros = np.zeros((n, 3))
    out = {name: wp.zeros(n, dtype=wp.vec3) for name in ("f", "diag")}
    q = wp.full(model.tet_rotation_shape, wp.quat_identity(), dtype=wp.quat)
    g = wp.zeros(model.tet_rotation_shape, dtype=wp.mat33)
    tangent = wp.zeros(model.tet_rotation_shape, dtype=wp.mat33)
    wp.launch(tet_p2.tet_forces, model.tet_count,
              inputs=[model.tet_indices, model.tet_poses, model.tet_stiffness, wp.array(x, dtype=wp.vec3),
                      wp.array(zeros if v is None else v, dtype=wp.vec3), q, velocity_scale, matrix_scale, 60, 1e-8,
                      int(rotation_stiffness)],
              outputs=[q, g, tangent, out["f"], out["diag"]])
    return ({k: a.numpy().astype(np.float64) for k, a in out.items()}
            | {"gradients": g, "rotation": q, "tangent": tangent})


def product(model, terms, p, scale=1.0):
    """``scale K_t p`` with the rotated gradients and rotation stiffness of ``element_pass``."""
    y = wp.zeros(model.particle_count, dtype=wp.vec3)
    wp.launch(tet_p2.tet_matvec, model.tet_count,
              inputs=[model.tet_indices, terms["gradients"], terms["tangent"], model.tet_stiffness,
                      wp.array(p, dtype=wp.vec3), scale], outputs=[y])
    return y.numpy().astype(np.float64)


def deformed(rest, seed=0, angle=0.7, noise=0.01):
    rng = np.random.default_rng(seed)
    R = Rotation.from_rotvec(angle * np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])).as_matrix()
    return (rest @ R.T + noise * rng.standard_normal(rest.shape)).astype(np.float32).astype(np.float64)


def test_forces_match_the_reference(curved):
    model = Model(curved, youngs_modulus=E, poisson_ratio=NU)
    rest = model.particle_q.numpy().astype(np.float64)
    x = deformed(rest)
    f = element_pass(model, x)["f"]
    ref = reference_p2.internal_forces(x, rest, curved.tets, E, NU)
    assert np.abs(f - ref).max() < 1e-5 * np.abs(ref).max()


def test_product_and_diagonal_match_the_assembled_corotated_matrix(curved):
    model = Model(curved, youngs_modulus=E, poisson_ratio=NU)
    rest = model.particle_q.numpy().astype(np.float64)
    x = deformed(rest, seed=1)
    terms = element_pass(model, x, matrix_scale=0.5)
    K = reference_p2.stiffness_matrix(rest, curved.tets, E, NU, reference_p2.polar_rotations(x, rest, curved.tets))
    p = np.random.default_rng(2).standard_normal(rest.shape).astype(np.float32)
    expected = (K @ p.astype(np.float64).ravel()).reshape(-1, 3)
    assert np.abs(product(model, terms, p, 2.0) - 2.0 * expected).max() < 2e-5 * np.abs(expected).max()
    np.testing.assert_allclose(terms["diag"], 0.5 * K.diagonal().reshape(-1, 3), rtol=2e-5,
                               atol=1e-6 * K.diagonal().max())


def test_operator_is_symmetric_and_positive(curved):
    model = Model(curved, youngs_modulus=E, poisson_ratio=NU)
    x = deformed(model.particle_q.numpy().astype(np.float64), seed=3)
    rng = np.random.default_rng(4)
    a, b = rng.standard_normal((2, model.particle_count, 3)).astype(np.float32)
    products = []
    for with_tangent in (False, True):
        terms = element_pass(model, x, rotation_stiffness=with_tangent)
        Ka, Kb = product(model, terms, a), product(model, terms, b)
        assert np.vdot(b, Ka) == pytest.approx(np.vdot(a, Kb), rel=1e-5)
        assert np.vdot(a, Ka) > 0
        products.append(Ka)
    plain_Ka, tangent_Ka = products
    assert np.vdot(a, tangent_Ka) >= np.vdot(a, plain_Ka) * (1 - 1e-6)  # the rotation stiffness adds u.K_G u >= 0


def test_tangent_with_rotation_stiffness_matches_finite_differences_in_tension(curved):
    """Stretched (15% along a tilted axis, 5% across) and rotated, every Gauss point is in
    tension: R K R^T + K_G is the force's exact derivative; R K R^T alone misses K_G."""
    model = Model(curved, youngs_modulus=E, poisson_ratio=NU)
    rest = model.particle_q.numpy().astype(np.float64)
    axis = np.array([1.0, 0.4, -0.2]) / np.linalg.norm([1.0, 0.4, -0.2])
    U = np.eye(3) + 0.15 * np.outer(axis, axis) + 0.05 * (np.eye(3) - np.outer(axis, axis))
    x = rest @ (Rotation.from_rotvec([0.5, -0.7, 0.2]).as_matrix() @ U).T
    direction = np.random.default_rng(17).standard_normal(rest.shape)
    h = 1e-4  # m
    fd = (element_pass(model, x + h * direction)["f"] - element_pass(model, x - h * direction)["f"]) / (2 * h)
    errors = {}
    for with_tangent in (True, False):
        Kd = product(model, element_pass(model, x, rotation_stiffness=with_tangent), direction)
        errors[with_tangent] = np.abs(fd + Kd).max() / np.abs(Kd).max()
    assert errors[True] < 3e-3, errors
    assert errors[False] > 10 * errors[True], errors
    terms = element_pass(model, x, rotation_stiffness=True, matrix_scale=0.5)
    for node in (0, 5, model.particle_count - 1):  # the preconditioner's diagonal includes K_G
        for axis in range(3):
            unit = np.zeros_like(rest)
            unit[node, axis] = 1.0
            column = product(model, terms, unit, 0.5)
            assert terms["diag"][node, axis] == pytest.approx(column[node, axis], rel=1e-4)


def test_damping_terms(curved):
    """The velocity term adds -c_v K v to the force."""
    model = Model(curved, youngs_modulus=E, poisson_ratio=NU)
    rest = model.particle_q.numpy().astype(np.float64)
    x = deformed(rest, seed=5)
    rng = np.random.default_rng(6)
    v = rng.standard_normal((model.particle_count, 3)).astype(np.float32)
    terms = element_pass(model, x, v=v, velocity_scale=0.1, matrix_scale=0.3)
    f0 = element_pass(model, x)["f"]
    Kv = product(model, terms, v, 0.1)
    np.testing.assert_allclose(terms["f"], f0 - Kv, atol=2e-5 * np.abs(Kv).max())


def test_rigid_motion_of_curved_elements_is_stress_free(curved):
    model = Model(curved, youngs_modulus=E, poisson_ratio=NU)
    rest = model.particle_q.numpy().astype(np.float64)
    R = Rotation.from_rotvec([1.1, -0.4, 2.0]).as_matrix()
    f = element_pass(model, rest @ R.T + [0.3, -2.0, 0.5])["f"]
    scale = E * model.tet_rest_volume.numpy().mean() ** (2 / 3)  # force of a unit strain on a face
    assert np.abs(f).max() < 1e-4 * scale


def test_patch_test_constant_stress(straight):
    """An affine deformation (rotation times a small symmetric stretch) gives a constant
    stress: interior nodes are in equilibrium and the forces balance as a whole."""
    model = Model(straight, youngs_modulus=E, poisson_ratio=NU)
    rest = model.particle_q.numpy().astype(np.float64)
    stretch = np.eye(3) + 0.01 * np.array([[1.0, 0.3, -0.2], [0.3, -0.5, 0.4], [-0.2, 0.4, 0.8]])
    R = Rotation.from_rotvec([0.2, 0.9, -0.4]).as_matrix()
    x = rest @ (R @ stretch).T
    inside = np.all((rest > 1e-6) & (rest < 0.3 - 1e-6), axis=1)
    assert inside.sum() > 20
    exact = reference_p2.internal_forces(x, rest, straight.tets, E, NU)  # float64: the discretisation
    typical = np.abs(exact[~inside]).max()
    assert np.abs(exact[inside]).max() < 1e-10 * typical
    f = element_pass(model, x)["f"]  # float32: strains of 1e-2 from positions rounded to 1e-7 relative
    assert np.abs(f[inside]).max() < 1e-3 * typical
    assert np.abs(f.sum(axis=0)).max() < 1e-3 * typical
    np.testing.assert_allclose(f, exact, atol=1e-3 * typical)
    state = model.state()
    state.particle_q.assign(x.astype(np.float32))
    state.tet_rotation.assign(element_pass(model, x)["rotation"])
    stress, _ = element_stress(model, state)
    mu, lam = E / (2 * (1 + NU)), E * NU / ((1 + NU) * (1 - 2 * NU))
    strain = stretch - np.eye(3)
    expected = R @ (2 * mu * strain + lam * np.trace(strain) * np.eye(3)) @ R.T
    np.testing.assert_allclose(stress, np.broadcast_to(expected, stress.shape), atol=1e-3 * np.abs(expected).max())


def test_masses_are_hrz_positive_and_loads_consistent(curved):
    model = Model(curved, density=RHO, youngs_modulus=E, poisson_ratio=NU)
    mass, load = model.particle_mass.numpy(), model.particle_load_mass.numpy()
    volume = curved.volumes().sum()
    assert mass.min() > 0
    assert mass.sum() == pytest.approx(RHO * volume, rel=1e-6)
    assert load.sum() == pytest.approx(RHO * volume, rel=1e-3)  # the Gauss rule's volume of curved elements
    np.testing.assert_allclose(model.tet_rest_volume.numpy(), curved.volumes(), rtol=1e-6)
    straight = Model(to_quadratic(wcut.beam(1, 1, 1)), density=RHO)
    corner_load = straight.particle_load_mass.numpy()[:8]
    assert (corner_load < 0).all()  # the consistent load: corners -1/20 of each element's mass


def test_static_sag_through_the_solver_matches_the_direct_solve():
    """Two implicit steps with dt = 1000 s are a static solve (the mass term vanishes); the
    solver's P2 kernels, HRZ masses and consistent loads reproduce the assembled solution."""
    mesh = to_quadratic(wcut.beam(6, 1, 1, size=(0.6, 0.1, 0.1)))
    fixed = mesh.vertices_in_box((-1, -1, -1), (1e-9, 1, 1))
    model = Model(mesh, density=RHO, youngs_modulus=1.0e8, poisson_ratio=NU, gravity=(0, 0, -9.81), fixed=fixed)
    solver = SolverCorotational(model, cg_iterations=4000, cg_tolerance=1e-7)
    state, scratch = model.state(), model.state()
    for _ in range(2):
        solver.step(state, scratch, None, 1.0e3)
        state, scratch = scratch, state
    solver.check()
    rest = model.particle_q.numpy().astype(np.float64)
    K = reference_p2.stiffness_matrix(rest, mesh.tets, 1.0e8, NU)
    u_ref = reference_p2.static_solve(K, reference_p2.body_load(rest, mesh.tets, RHO, (0, 0, -9.81)), fixed)
    u = state.particle_q.numpy() - rest
    assert np.abs(u_ref).max() > 1e-4  # a visible sag, still small (linear regime)
    assert np.abs(u - u_ref).max() < 2e-3 * np.abs(u_ref).max()


def test_dynamic_run_stays_finite_and_tets_lock_less_than_p1():
    """A soft beam dropping under gravity for 200 steps: finite, and the P2 beam sags further
    than the P1 beam on the same corners (P1 is too stiff in bending)."""
    linear = wcut.beam(8, 2, 2, size=(0.4, 0.05, 0.05))
    tips = []
    for mesh in (linear, to_quadratic(linear)):
        fixed = mesh.vertices_in_box((-1, -1, -1), (1e-9, 1, 1))
        model = Model(mesh, density=RHO, youngs_modulus=3.0e5, poisson_ratio=0.45, gravity=(0, 0, -9.81),
                      fixed=fixed, rayleigh_mass=2.0)
        solver = SolverCorotational(model, cg_iterations=60)
        state, scratch = model.state(), model.state()
        for _ in range(200):
            solver.step(state, scratch, None, 0.01)
            state, scratch = scratch, state
        solver.check()
        q = state.particle_q.numpy()
        tips.append(q[mesh.vertices[:, 0] > 0.4 - 1e-9, 2].mean())
    assert tips[1] < tips[0] - 0.01


def test_rebuild_needs_a_mesh_of_the_same_order(straight):
    """A quadratic model rebuilds from a quadratic mesh (tests/test_cut_quadratic.py) only."""
    from wcut.cut import Plane
    from wcut.cut.quadratic import QuadraticCutter

    model = Model(straight)
    result = QuadraticCutter(straight).cut(Plane(straight.vertices.mean(axis=0), [1.0, 0.2, 0.1]))
    with pytest.raises(ModelError, match="order 1 for a model of order 2"):
        model.rebuild(result.mesh.linear(), result.change)
    rebuilt, _ = model.rebuild(result.mesh, result.change)
    assert rebuilt.tet_order == 2 and rebuilt.tet_count == result.mesh.tet_count


def test_corner_interpolation_of_attachments(curved):
    from wcut.model import Attachments

    a = Attachments.at_points(curved, [CENTER], 100.0)
    assert set(a.indices[0]) <= set(curved.tets[:, :4].ravel())
    assert a.weights[0].sum() == pytest.approx(1.0)


def test_gauss_points_of_kernel_and_host_agree():
    L = np.array([[tet_p2.GAUSS_B] * 4])
    L[0, 0] = tet_p2.GAUSS_A
    np.testing.assert_allclose(L[0], p2.GAUSS_POINTS[0], rtol=1e-15)


def test_listed_product_is_the_product_of_the_listed_elements(curved):
    """tet_matvec_listed adds the listed elements' shares of tet_matvec, and nothing else: over
    a list and its complement, the sum is the whole product."""
    model = Model(curved, youngs_modulus=E, poisson_ratio=NU)
    rest = model.particle_q.numpy().astype(np.float64)
    terms = element_pass(model, deformed(rest), rotation_stiffness=True)
    p = np.random.default_rng(4).standard_normal((model.particle_count, 3))
    assert_listed_product(tet_p2.tet_matvec_listed, model, terms, p, product(model, terms, p, scale=0.7), 4)
