"""SolverCorotational: the implicit step against scipy, statics against beam theory,
conservation, dissipation, determinism, embedding in a user's Warp loop, stability at any
stiffness with the default settings, and blow-ups reported as errors."""

import numpy as np
import pytest
import warp as wp
from conftest import mechanical_energy

import wcut
from wcut.cut import Cutter, Plane
from wcut.errors import SimulationError
from wcut.model import Model, Attachments
from wcut.reference import ScipyCorotationalStep
from wcut.quadratic import to_quadratic
from wcut.solver import SolverCorotational
from wcut.topology import TetTopology


def clamped_beam(cells=(8, 2, 2), **material):
    mesh = wcut.beam(*cells, size=(0.4, 0.1, 0.1))
    params = dict(density=1000.0, youngs_modulus=1.0e5, poisson_ratio=0.3, gravity=(0.0, 0.0, -9.81)) | material
    return mesh, Model(mesh, fixed=mesh.vertices_in_box((-1, -1, -1), (1e-9, 1, 1)), **params), params


@pytest.fixture
def split_products(monkeypatch):
    """Split the CG products over the threads too, however small the model."""
    from wcut import solver as solver_module

    monkeypatch.setattr(solver_module, "PRODUCT_ELEMENTS_PER_THREAD", {1: 1, 2: 1})


def run(model, solver, steps, dt, control=None, state=None):
    state = state or model.state()
    scratch = model.state()
    for _ in range(steps):
        solver.step(state, scratch, control, dt)
        state, scratch = scratch, state
    return state


def test_step_matches_the_scipy_reference_solved_with_spsolve():
    mesh, model, params = clamped_beam()
    fixed = model.particle_fixed.numpy().astype(bool)
    attached = Attachments.at_points(mesh, [[0.35, 0.05, 0.05]], 50.0)
    model = Model(mesh, fixed=fixed, attachments=attached, rayleigh_mass=0.5, rayleigh_stiffness=0.01, **params)
    ref = ScipyCorotationalStep(mesh.vertices, mesh.tets, fixed=fixed, rayleigh_mass=0.5, rayleigh_stiffness=0.01,
                                spring_indices=attached.indices, spring_weights=attached.weights,
                                spring_stiffness=attached.stiffness, rotation_stiffness=True, **params)
    control = model.control()
    target = np.array([[0.45, 0.0, 0.1]])
    control.attachment_target.assign(target)
    rng = np.random.default_rng(0)
    f_ext = 0.01 * rng.standard_normal((model.particle_count, 3))
    state, out = model.state(), model.state()
    for s in (state, out):
        s.particle_f.assign(f_ext)
    solver = SolverCorotational(model, cg_iterations=400, cg_tolerance=1e-7, rotation_iterations=30)
    x, v = mesh.vertices.copy(), np.zeros_like(mesh.vertices)
    for _ in range(5):
        solver.step(state, out, control, 0.01)
        state, out = out, state
        x, v = ref.step(x, v, 0.01, f_ext=f_ext, spring_targets=target, direct=True)
    assert solver.last_relative_residual < 1e-6
    np.testing.assert_allclose(state.particle_qd.numpy(), v, atol=1e-4 * np.abs(v).max())
    np.testing.assert_allclose(state.particle_q.numpy(), x, atol=1e-5)
    assert np.array_equal(state.particle_q.numpy()[fixed], mesh.vertices[fixed].astype(np.float32))


def test_static_cantilever_converges_toward_beam_theory():
    """Tip deflection of a clamped 1 m x 0.1 m x 0.1 m beam under its weight (thesis 3.5, fig. 3.12)."""
    L, H, E, rho, g = 1.0, 0.1, 1.0e9, 1000.0, 9.81
    q, I = rho * g * H * H, H ** 4 / 12
    bending = q * L ** 4 / (8 * E * I)
    shear = q * L ** 2 / (2 * (5 / 6) * (E / 2) * H * H)  # Timoshenko correction, nu = 0
    exact = bending + shear
    errors, sizes = [], []
    for n in (1, 2, 3, 4):
        mesh = wcut.beam(10 * n, n, n, size=(L, H, H))
        model = Model(mesh, density=rho, youngs_modulus=E, poisson_ratio=0.0, gravity=(0, 0, -g),
                      fixed=mesh.vertices_in_box((-1, -1, -1), (1e-9, 1, 1)))
        solver = SolverCorotational(model, cg_iterations=3000, cg_tolerance=1e-7)
        state = run(model, solver, 2, dt=1.0e3)  # quasi-static: the mass term vanishes next to dt^2 K
        tip = mesh.vertices[:, 0] > L - 1e-9
        deflection = -(state.particle_q.numpy()[tip, 2] - mesh.vertices[tip, 2]).mean()
        errors.append(abs(deflection - exact) / exact)
        sizes.append(H / n)
    assert all(a > b for a, b in zip(errors, errors[1:])), errors
    order = np.log(errors[-2] / errors[-1]) / np.log(sizes[-2] / sizes[-1])
    assert 1.0 < order < 2.5, (errors, order)  # linear tets: order approaching 2 in displacement
    assert errors[-1] < 0.15, errors


def test_linear_momentum_is_conserved_without_constraints_and_gravity():
    mesh = wcut.beam(4, 2, 2, size=(0.2, 0.1, 0.1))
    model = Model(mesh, youngs_modulus=1e5, gravity=(0, 0, 0))
    rng = np.random.default_rng(1)
    state = model.state()
    state.particle_qd.assign(rng.standard_normal((model.particle_count, 3)))
    mass = model.particle_mass.numpy()[:, None]
    before = (mass * state.particle_qd.numpy()).sum(axis=0)
    solver = SolverCorotational(model, cg_iterations=300, cg_tolerance=1e-7)
    state = run(model, solver, 40, 0.005, state=state)
    after = (mass * state.particle_qd.numpy()).sum(axis=0)
    speed_scale = np.sum(mass * np.linalg.norm(state.particle_qd.numpy(), axis=1, keepdims=True))
    np.testing.assert_allclose(after, before, atol=1e-6 * speed_scale)
    assert np.abs(state.particle_qd.numpy()).max() > 0.1  # it did move


def elastic_energy(model, state):
    """Corotational strain energy sum V (mu eps:eps + lambda/2 tr(eps)^2), eps = sym(R^T F) - I,
    with R the polar rotation of F computed here in float64."""
    from wcut.model import lame_parameters

    x = state.particle_q.numpy().astype(np.float64)[model.mesh.tets]
    Ds = np.stack([x[:, 0] - x[:, 3], x[:, 1] - x[:, 3], x[:, 2] - x[:, 3]], axis=2)
    F = Ds @ model.tet_poses.numpy().astype(np.float64)
    U, _, Vt = np.linalg.svd(F)
    S = np.einsum("nji,njk->nik", U @ Vt, F)
    eps = 0.5 * (S + S.transpose(0, 2, 1)) - np.eye(3)
    mu, lam = lame_parameters(model.tet_youngs_modulus.numpy(), model.tet_poisson_ratio.numpy())
    tr = np.trace(eps, axis1=1, axis2=2)
    return float(np.sum(model.tet_rest_volume.numpy() * (mu * np.sum(eps * eps, axis=(1, 2)) + 0.5 * lam * tr ** 2)))


def total_energy(model, state):
    kinetic = 0.5 * np.sum(model.particle_mass.numpy()[:, None] * state.particle_qd.numpy() ** 2)
    return kinetic + elastic_energy(model, state)


@pytest.mark.parametrize("damping", [dict(rayleigh_mass=20.0), dict(rayleigh_stiffness=0.02)])
def test_damping_dissipates_energy(damping):
    """A stretched free beam is released: energy decreases monotonically, faster with damping."""
    finals = {}
    for name, params in (("undamped", {}), ("damped", damping)):
        mesh = wcut.beam(6, 2, 2, size=(0.3, 0.1, 0.1))
        model = Model(mesh, youngs_modulus=1e4, gravity=(0, 0, 0), **params)
        solver = SolverCorotational(model, cg_iterations=300, cg_tolerance=1e-7)
        state, scratch = model.state(), model.state()
        state.particle_q.assign(mesh.vertices * np.array([1.1, 0.97, 0.97]))
        energies = []
        for _ in range(60):
            solver.step(state, scratch, None, 0.001)
            state, scratch = scratch, state
            energies.append(total_energy(model, state))
        assert all(b <= a * (1 + 1e-5) for a, b in zip(energies, energies[1:])), name
        finals[name] = energies[-1] / energies[0]
    assert finals["damped"] < 0.5 * finals["undamped"]


def test_two_runs_give_identical_results():
    results = []
    for _ in range(2):
        _, model, _ = clamped_beam(rayleigh_mass=0.5)
        solver = SolverCorotational(model, cg_iterations=20, cg_tolerance=1e-6)
        state = run(model, solver, 20, 0.01)
        results.append((state.particle_q.numpy().copy(), state.particle_qd.numpy().copy()))
    assert np.array_equal(results[0][0], results[1][0]) and np.array_equal(results[0][1], results[1][1])


@wp.kernel
def lift_tip(particle_q: wp.array(dtype=wp.vec3), particle_qd: wp.array(dtype=wp.vec3), x_min: float, speed: float):
    i = wp.tid()
    if particle_q[i][0] > x_min:
        particle_qd[i] = wp.vec3(0.0, 0.0, speed)


def test_embedding_user_kernels_and_two_models_in_one_loop():
    _, beam_a, _ = clamped_beam()
    _, beam_b, _ = clamped_beam(cells=(6, 2, 2), youngs_modulus=3e5)
    solver_a = SolverCorotational(beam_a, cg_iterations=100, cg_tolerance=1e-6)
    solver_b = SolverCorotational(beam_b, cg_iterations=100, cg_tolerance=1e-6)
    a, a_next, b, b_next = beam_a.state(), beam_a.state(), beam_b.state(), beam_b.state()
    sagged = run(beam_a, SolverCorotational(beam_a, cg_iterations=100, cg_tolerance=1e-6), 30, 0.01)
    for _ in range(30):
        wp.launch(lift_tip, beam_a.particle_count, inputs=[a.particle_q, a.particle_qd, 0.35, 0.5])
        solver_a.step(a, a_next, None, 0.01)
        solver_b.step(b, b_next, None, 0.01)
        a, a_next, b, b_next = a_next, a, b_next, b
    # the user's kernel lifted beam a against gravity; beam b sags as if alone
    tip = beam_a.mesh.vertices[:, 0] > 0.35
    assert a.particle_q.numpy()[tip, 2].mean() > sagged.particle_q.numpy()[tip, 2].mean() + 0.2
    alone = run(beam_b, SolverCorotational(beam_b, cg_iterations=100, cg_tolerance=1e-6), 30, 0.01)
    assert np.array_equal(alone.particle_q.numpy(), b.particle_q.numpy())
    assert b.particle_q.numpy()[:, 2].min() < -0.001


def test_a_stiff_attachment_drags_its_point_to_the_target():
    mesh, _, params = clamped_beam()
    attached = Attachments.at_points(mesh, [[0.4, 0.05, 0.05]], 1.0e4)
    model = Model(mesh, fixed=mesh.vertices_in_box((-1, -1, -1), (1e-9, 1, 1)), attachments=attached,
                  rayleigh_mass=5.0, **params)
    control = model.control()
    target = np.array([0.4, 0.05, 0.15])
    control.attachment_target.assign(target[None])
    state = run(model, SolverCorotational(model, cg_iterations=200, cg_tolerance=1e-6), 100, 0.01, control)
    point = attached.weights[0] @ state.particle_q.numpy()[attached.indices[0]]
    assert np.linalg.norm(point - target) < 0.01  # within 1 cm of a 10 cm pull


def test_bad_input_raises_errors_that_say_what():
    _, model, _ = clamped_beam()
    SolverCorotational(model)  # valid defaults
    with pytest.raises(SimulationError, match="cg_iterations"):
        SolverCorotational(model, cg_iterations=0)
    mesh = wcut.beam(2, 1, 1)
    sprung = Model(mesh, attachments=Attachments.at_vertices([0], 1.0))
    with pytest.raises(SimulationError, match="Control"):
        SolverCorotational(sprung).step(sprung.state(), sprung.state(), None, 0.01)


def test_divergence_is_reported():
    _, model, _ = clamped_beam()
    solver = SolverCorotational(model, cg_iterations=5)
    state = model.state()
    q = state.particle_q.numpy()
    q[5] = np.nan
    state.particle_q.assign(q)
    solver.step(state, model.state(), None, 0.01)
    with pytest.raises(SimulationError, match="diverged"):
        solver.check()


@pytest.mark.parametrize("cpu_threads, products_too", [(1, False), (2, False), (2, True)])
def test_step_allocates_nothing(cpu_threads, products_too, request):
    import io
    import re

    if products_too:
        request.getfixturevalue("split_products")
    mesh = wcut.beam(4, 2, 2, size=(0.2, 0.05, 0.05))
    model = Model(mesh, fixed=[0, 1, 2], attachments=Attachments.at_vertices([40], 10.0), rayleigh_mass=0.1)
    solver = SolverCorotational(model, cg_iterations=10, cpu_threads=cpu_threads)
    assert solver.split_product == products_too
    a, b, control = model.state(), model.state(), model.control()
    solver.step(a, b, control, 0.01)  # the first step of a dt factors the preconditioner
    a, b = b, a
    report = io.StringIO()
    with wp.ScopedMemoryTracker("step", print=False) as tracker:
        tracker.clear()  # the totals are global: drop those of an earlier tracker in this process
        for _ in range(3):  # the first step records the conjugate-gradient launches
            solver.step(a, b, control, 0.01)
            a, b = b, a
        tracker.report(file=report)
    assert not re.search(r"^\s+(cpu|cuda:\d+)\s+\d+ \(", report.getvalue(), re.MULTILINE), report.getvalue()
    # the tracker does see allocations (the assertion above could fail)
    report = io.StringIO()
    with wp.ScopedMemoryTracker("control", print=False) as tracker:
        tracker.clear()
        model.control()  # a Warp allocation (a CPU State wraps numpy buffers instead)
        tracker.report(file=report)
    assert re.search(r"^\s+cpu\s+\d+ \(", report.getvalue(), re.MULTILINE)


@pytest.mark.parametrize("degrees", [90, 150, 180])
def test_an_object_placed_rotated_feels_no_false_forces(degrees):
    """The warm-start rotations are the identity; the rest shape is turned by up to half a turn."""
    from scipy.spatial.transform import Rotation

    mesh = wcut.beam(4, 2, 2, size=(0.2, 0.05, 0.05))
    model = Model(mesh, gravity=(0, 0, 0), youngs_modulus=1e5)
    solver = SolverCorotational(model, cg_iterations=50)
    Q = Rotation.from_rotvec(np.radians(degrees) * np.array([0.0, 0.0, 1.0])).as_matrix()
    state = model.state()
    state.particle_q.assign(mesh.vertices @ Q.T)
    state = run(model, solver, 3, 0.01, state=state)
    assert np.abs(state.particle_qd.numpy()).max() < 1e-4  # m/s; a wrong rotation gives ~1-10 m/s


def test_a_thin_element_far_from_the_origin_rests_in_float32():
    """Rest frames come from the float32 positions the kernels see: thin elements stay at rest."""
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 0.3, 1e-4]]) * 0.1 + 10.0
    model = Model(wcut.TetMesh(x, [[0, 1, 2, 3]]), gravity=(0, 0, 0), youngs_modulus=1e6)
    state = run(model, SolverCorotational(model), 10, 0.01)
    assert np.abs(state.particle_qd.numpy()).max() < 1e-6


def test_a_state_or_control_of_another_model_is_refused():
    _, small, _ = clamped_beam(cells=(2, 1, 1))
    _, large, _ = clamped_beam(cells=(8, 2, 2))
    solver = SolverCorotational(large)
    with pytest.raises(SimulationError, match="state_in does not belong"):
        solver.step(small.state(), large.state(), None, 0.01)
    with pytest.raises(SimulationError, match="state_out does not belong"):
        solver.step(large.state(), small.state(), None, 0.01)
    mesh = wcut.beam(2, 1, 1)
    attached = Model(mesh, attachments=Attachments.at_vertices([0, 1], 1.0))
    other = Model(mesh, attachments=Attachments.at_vertices([0], 1.0))
    with pytest.raises(SimulationError, match="control does not belong"):
        SolverCorotational(attached).step(attached.state(), attached.state(), other.control(), 0.01)


def test_changing_damping_or_tolerance_between_steps_takes_effect():
    _, model, _ = clamped_beam()
    solver = SolverCorotational(model, cg_iterations=200, cg_tolerance=1e-6)
    state = run(model, solver, 3, 0.01)
    model.rayleigh_stiffness = 0.05
    changed = run(model, solver, 1, 0.01, state=state)
    fresh = run(model, SolverCorotational(model, cg_iterations=200, cg_tolerance=1e-6), 1, 0.01, state=state)
    moved = np.abs(fresh.particle_q.numpy() - state.particle_q.numpy()).max()
    # different warm starts: equal to the solver tolerance (a stale damping term gave 70% of `moved`)
    assert np.abs(changed.particle_q.numpy() - fresh.particle_q.numpy()).max() < 1e-3 * moved
    solver.cg_tolerance = 1e-2
    run(model, solver, 1, 0.01, state=state)
    loose = solver.last_cg_iterations
    solver.cg_tolerance = 1e-7
    run(model, solver, 1, 0.01, state=state)
    assert solver.last_cg_iterations > loose
    assert solver.last_relative_residual <= 1e-7 * 1.01


def test_early_stop_equals_running_exactly_that_many_iterations():
    _, model, _ = clamped_beam()
    state = run(model, SolverCorotational(model, cg_iterations=200, cg_tolerance=1e-6), 3, 0.01)
    adaptive = SolverCorotational(model, cg_iterations=200, cg_tolerance=1e-3)
    a = run(model, adaptive, 1, 0.01, state=state)
    used = adaptive.last_cg_iterations
    assert 0 < used < 200
    assert adaptive.last_relative_residual <= 1e-3
    fixed = SolverCorotational(model, cg_iterations=used, cg_tolerance=0.0)
    b = run(model, fixed, 1, 0.01, state=state)
    assert np.array_equal(a.particle_q.numpy(), b.particle_q.numpy())
    assert fixed.last_cg_iterations == used and 0.0 < fixed.last_relative_residual < 1e-3


@pytest.mark.parametrize("chunk", [5, 64, 1000])
def test_node_kernels_in_chunks_solve_what_one_node_per_thread_solves(chunk, monkeypatch):
    """The CG's node kernels with ``chunk`` nodes per thread (81 nodes: a short last chunk, or
    one thread for all) cover every node once: the converged step equals one node per thread's
    to rounding, in the same iterations."""
    from wcut import solver as solver_module

    _, model, _ = clamped_beam()
    ends = {}
    for size in (1, chunk):
        monkeypatch.setattr(solver_module, "NODES_PER_CPU_THREAD", size)
        solver = SolverCorotational(model, cg_iterations=300, cg_tolerance=1e-6)
        ends[size] = run(model, solver, 3, 0.01).particle_q.numpy(), solver.last_cg_iterations
        assert solver.last_relative_residual <= 1e-6
    (one, one_iterations), (chunked, chunked_iterations) = ends[1], ends[chunk]
    assert abs(one_iterations - chunked_iterations) <= 1
    np.testing.assert_allclose(chunked, one, atol=1e-7)
    assert not np.array_equal(chunked, model.particle_q.numpy())  # it moved


def test_nothing_to_solve_takes_no_iteration():
    mesh = wcut.beam(2, 1, 1)
    model = Model(mesh, gravity=(0, 0, 0))
    solver = SolverCorotational(model)
    state = run(model, solver, 2, 0.01)
    assert solver.last_cg_iterations == 0 and solver.last_relative_residual == 0.0
    assert np.array_equal(state.particle_q.numpy(), model.particle_q.numpy())


def test_default_settings_follow_the_reference_on_a_soft_object():
    """20 CG iterations, two rotation iterations: close to the exact (spsolve) step."""
    mesh = wcut.beam(6, 2, 2, size=(0.3, 0.1, 0.1))
    fixed = mesh.vertices_in_box((-1, -1, -1), (1e-9, 1, 1))
    params = dict(density=1000.0, youngs_modulus=2e4, poisson_ratio=0.3, rayleigh_mass=1.0)
    model = Model(mesh, fixed=fixed, **params)
    ref = ScipyCorotationalStep(mesh.vertices, mesh.tets, fixed=fixed, gravity=(0, 0, -9.81), rotation_stiffness=True,
                                **params)
    state = run(model, SolverCorotational(model), 30, 0.01)
    x, v = mesh.vertices.copy(), np.zeros_like(mesh.vertices)
    for _ in range(30):
        x, v = ref.step(x, v, 0.01, direct=True)
    travel = np.abs(x - mesh.vertices).max()
    assert travel > 0.01
    assert np.abs(state.particle_q.numpy() - x).max() < 0.01 * travel


@pytest.mark.parametrize("kwargs, words", [
    (dict(cg_iterations=2.5), "cg_iterations"),
    (dict(cg_iterations=10 ** 9), "cg_iterations"),
    (dict(cg_tolerance=float("nan")), "cg_tolerance"),
    (dict(rotation_iterations=0), "rotation_iterations"),
])
def test_bad_solver_settings(kwargs, words):
    _, model, _ = clamped_beam(cells=(2, 1, 1))
    with pytest.raises(SimulationError, match=words):
        SolverCorotational(model, **kwargs)


@pytest.mark.parametrize("dt", [0.0, -0.01, float("inf"), float("nan")])
def test_bad_time_steps(dt):
    _, model, _ = clamped_beam(cells=(2, 1, 1))
    with pytest.raises(SimulationError, match="time step"):
        SolverCorotational(model).step(model.state(), model.state(), None, dt)


def test_rotation_stiffness_keeps_a_stretched_band_stable_at_large_steps():
    """A band held at both ends stretched by 30% (tension ~2.3e4 Pa, 1 cm elements: the
    explicit limit dt ~ h sqrt(rho/sigma) is about 2 ms), bowed 2 mm, stepped at 30 ms for 1 s:
    with the rotation stiffness in the system matrix it settles straight; with R K R^T alone
    (the thesis's system) it does not settle."""
    mesh = wcut.beam(20, 2, 2, size=(0.2, 0.02, 0.02))
    rest = mesh.vertices
    ends = np.flatnonzero((rest[:, 0] < 1e-9) | (rest[:, 0] > 0.2 - 1e-9))
    start = rest * [1.3, 1.0, 1.0] + np.outer(0.002 * np.sin(np.pi * rest[:, 0] / 0.2), [0.0, 0.0, 1.0])
    speeds = {}
    for flag in (True, False):
        model = Model(mesh, density=1000.0, youngs_modulus=1.0e5, poisson_ratio=0.3, fixed=ends, gravity=(0, 0, 0))
        solver = SolverCorotational(model, cg_iterations=50, rotation_stiffness=flag)
        state, scratch = model.state(), model.state()
        state.particle_q.assign(start.astype(np.float32))
        for _ in range(33):
            solver.step(state, scratch, None, 0.03)
            state, scratch = scratch, state
        speeds[flag] = np.abs(state.particle_qd.numpy()).max()
        if flag:
            middle = np.abs(rest[:, 0] - 0.1) < 1e-9
            bow = state.particle_q.numpy()[middle, 2].mean() - rest[middle, 2].mean()
            assert abs(bow) < 1e-4  # straight again (it started 2 mm bowed)
    assert speeds[True] < 1e-3, speeds
    assert speeds[False] > 1e-2, speeds


def _pulled_beam():
    mesh, model, _ = clamped_beam(rayleigh_mass=0.5)
    tip = int(np.argmax(mesh.vertices[:, 0]))
    model = Model(mesh, density=1000.0, youngs_modulus=1.0e5, poisson_ratio=0.3, rayleigh_mass=0.5,
                  fixed=mesh.vertices_in_box((-1, -1, -1), (1e-9, 1, 1)),
                  attachments=Attachments.at_vertices([tip], 50.0))
    return mesh, model, tip


def _steps(model, solver, targets, dt, force=None):
    """Ping-pong steps with a target written in place before each; returns every position."""
    a, b, control = model.state(), model.state(), model.control()
    out = []
    for k, target in enumerate(targets):
        control.attachment_target.assign(np.asarray([target], dtype=np.float32))
        if force is not None and k == len(targets) // 2:  # a new array of external forces halfway
            a.particle_f = wp.array(force, dtype=wp.vec3, device=model.device)
        solver.step(a, b, control, dt[k] if isinstance(dt, list) else dt)
        a, b = b, a
        out.append(a.particle_q.numpy().copy())
    return out


def test_captured_steps_equal_launched_steps_bit_for_bit():
    mesh, model, tip = _pulled_beam()
    targets = [mesh.vertices[tip] + [0.0, 0.0, 0.002 * k] for k in range(12)]
    captured = SolverCorotational(model, cg_iterations=30)
    launched = SolverCorotational(model, cg_iterations=30, graph_capture=False)
    a, b = _steps(model, captured, targets, 0.01), _steps(model, launched, targets, 0.01)
    assert len(captured._graphs) == 2 and not launched._graphs  # the ping-pong's two graphs
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert np.abs(a[-1] - mesh.vertices).max() > 1e-3  # it moved


def test_a_new_time_step_or_a_replaced_array_is_captured_again():
    mesh, model, tip = _pulled_beam()
    targets = [mesh.vertices[tip]] * 12
    dt = [0.01] * 6 + [0.005] * 6
    force = np.zeros((model.particle_count, 3))
    force[tip] = [0.0, 0.5, 0.0]
    a = _steps(model, SolverCorotational(model, cg_iterations=30), targets, dt, force)
    b = _steps(model, SolverCorotational(model, cg_iterations=30, graph_capture=False), targets, dt, force)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    unforced = _steps(model, SolverCorotational(model, cg_iterations=30), targets, dt)
    assert np.abs(a[-1] - unforced[-1]).max() > 1e-5  # the new force array acted


def _p1_and_p2_beams():
    mesh, model, params = clamped_beam(cells=(6, 2, 2))
    quadratic = to_quadratic(mesh)
    return [(mesh, model), (quadratic, Model(quadratic, fixed=quadratic.vertices_in_box((-1, -1, -1), (1e-9, 1, 1)),
                                             **params))]


@pytest.mark.parametrize("order", [1, 2])
def test_element_kernels_split_over_threads_equal_one_launch(order, split_products):
    mesh, model = _p1_and_p2_beams()[order - 1]
    rng = np.random.default_rng(order)
    q, dv = mesh.vertices + 0.01 * rng.normal(size=mesh.vertices.shape), rng.normal(size=mesh.vertices.shape)
    passes = {}
    for threads in (1, 3):
        solver = SolverCorotational(model, cpu_threads=threads)
        assert solver.cpu_threads == threads
        state, out = model.state(), model.state()
        state.particle_q.assign(q)
        solver.launch_element_pass(state, out, 0.01)
        assert not any(p.numpy().any() for p in solver._partials)  # the element pass added its own
        solver._p.assign(dv)
        solver._q.zero_()
        solver._record_tet_matvec(solver.stiffness_scale(0.01)).launch()  # q += c_A K_t p; cg_apply_mass adds the rows
        product = solver._q.numpy() + solver._partials[2].numpy().sum(axis=0)
        passes[threads] = [a.numpy() for a in (solver._force, solver.particle_diagonal, out.tet_rotation,
                                               solver.tet_rotated_gradients, solver.tet_rotation_stiffness)]
        passes[threads] += [product]
    for one, split in zip(passes[1], passes[3]):
        assert np.abs(one).max() > 0.0
        np.testing.assert_allclose(split, one, rtol=0.0, atol=1e-5 * np.abs(one).max())


@pytest.mark.parametrize("order", [1, 2])
def test_steps_split_over_threads_follow_single_thread_steps(order, split_products):
    mesh, model = _p1_and_p2_beams()[order - 1]
    ends = [run(model, SolverCorotational(model, cg_iterations=300, cg_tolerance=1e-6, cpu_threads=threads), 15,
                0.01).particle_q.numpy() for threads in (1, 2)]
    sag = np.abs(ends[0] - mesh.vertices).max()
    assert sag > 1e-3
    assert np.abs(ends[1] - ends[0]).max() < 1e-4 * sag


def test_cpu_threads_default_to_one_for_small_models_and_are_checked(monkeypatch):
    from wcut import solver as solver_module

    _, model = _p1_and_p2_beams()[0]
    assert model.tet_count < 1000
    assert SolverCorotational(model).cpu_threads == 1
    pinned = SolverCorotational(model, cpu_threads=8)
    assert pinned.cpu_threads == 8 and not pinned.split_product  # too small a model to split products
    monkeypatch.setitem(solver_module.FORCES_ELEMENTS_PER_THREAD, 1, 10)
    monkeypatch.setattr(solver_module, "available_cores", lambda: 3)
    auto = SolverCorotational(model)
    assert auto.cpu_threads == 3 and not auto.split_product  # one per 10 elements, at most the cores
    monkeypatch.setitem(solver_module.PRODUCT_ELEMENTS_PER_THREAD, 1, model.tet_count // 2)
    assert SolverCorotational(model).split_product  # twice as many elements as a thread's product
    for bad in (0, 9, 2.0, True):
        with pytest.raises(SimulationError, match="cpu_threads"):
            SolverCorotational(model, cpu_threads=bad)
    monkeypatch.setattr(wp.config, "mode", "debug")  # Warp's debug kernels share a pointer between threads
    assert SolverCorotational(model, cpu_threads=4).cpu_threads == 1


def test_a_split_step_inside_a_users_capture_replays_every_range(split_products):
    """Warp records launches per thread: inside a capture the ranges run on the capturing
    thread, so that the graph holds them all."""
    mesh, model = _p1_and_p2_beams()[0]
    ends = []
    for threads in (1, 2):
        solver = SolverCorotational(model, cg_iterations=40, cg_tolerance=0.0, cpu_threads=threads,
                                    graph_capture=False)
        a, b = model.state(), model.state()
        solver.step(a, b, None, 0.01)  # records the CG launches
        with wp.ScopedCapture(device=model.device) as capture:
            solver.step(b, a, None, 0.01)
            solver.step(a, b, None, 0.01)
        for _ in range(5):
            wp.capture_launch(capture.graph)
        ends.append(b.particle_q.numpy())
        assert not any(p.numpy().any() for p in solver._partials)
    sag = np.abs(ends[0] - mesh.vertices).max()
    assert sag > 1e-4
    assert np.abs(ends[1] - ends[0]).max() < 1e-5 * sag


def test_a_step_after_an_interrupted_split_launch_starts_from_clean_scratch(split_products):
    mesh, model = _p1_and_p2_beams()[1]
    clean = SolverCorotational(model, cpu_threads=2)
    dirty = SolverCorotational(model, cpu_threads=2)
    for partial in dirty._partials:  # what an interrupted launch may leave
        partial.fill_(wp.vec3(1.0, 2.0, 3.0))
    assert np.array_equal(run(model, dirty, 3, 0.01).particle_q.numpy(),
                          run(model, clean, 3, 0.01).particle_q.numpy())


def test_a_split_element_pass_before_a_captured_solve_equals_launched_steps(monkeypatch):
    """The element pass on threads (launched each step) and the rest of the step from a graph."""
    from wcut import solver as solver_module

    monkeypatch.setitem(solver_module.FORCES_ELEMENTS_PER_THREAD, 1, 10)
    monkeypatch.setattr(solver_module, "available_cores", lambda: 2)
    mesh, model, tip = _pulled_beam()
    targets = [mesh.vertices[tip] + [0.0, 0.0, 0.002 * k] for k in range(12)]
    captured = SolverCorotational(model, cg_iterations=30)
    launched = SolverCorotational(model, cg_iterations=30, graph_capture=False)
    assert captured.cpu_threads == 2 and not captured.split_product
    a, b = _steps(model, captured, targets, 0.01), _steps(model, launched, targets, 0.01)
    assert len(captured._graphs) == 2 and not launched._graphs
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    one = _steps(model, SolverCorotational(model, cg_iterations=30, cpu_threads=1), targets, 0.01)
    assert np.abs(a[-1] - one[-1]).max() < 1e-5 * np.abs(one[-1] - mesh.vertices).max()


@pytest.mark.parametrize("threads", [1, 2])
def test_a_step_inside_a_users_capture_after_captured_steps_goes_into_it(threads, monkeypatch):
    """The solver captures its own steps; inside the user's capture it launches into that one
    instead (a second capture would fail, a replay of its own graph would run at once)."""
    from wcut import solver as solver_module

    monkeypatch.setitem(solver_module.FORCES_ELEMENTS_PER_THREAD, 1, 10)  # threads for the element pass
    mesh, model, tip = _pulled_beam()
    control = model.control()
    control.attachment_target.assign(np.asarray([mesh.vertices[tip] + [0.0, 0.0, 0.01]], dtype=np.float32))
    ends = []
    for user_capture in (False, True):
        solver = SolverCorotational(model, cg_iterations=30, cpu_threads=threads)
        a, b = model.state(), model.state()
        for _ in range(4):  # its own graphs captured for both directions
            solver.step(a, b, control, 0.01)
            a, b = b, a
        if user_capture:
            with wp.ScopedCapture(device=model.device) as capture:
                solver.step(a, b, control, 0.01)
                solver.step(b, a, control, 0.01)
            for _ in range(3):
                wp.capture_launch(capture.graph)
        else:
            for _ in range(6):
                solver.step(a, b, control, 0.01)
                a, b = b, a
        ends.append(a.particle_q.numpy())
    assert np.abs(ends[0] - mesh.vertices).max() > 1e-3
    np.testing.assert_array_equal(ends[1], ends[0])


def test_the_split_element_pass_follows_a_new_time_step_and_new_settings(monkeypatch):
    """The split element pass is recorded once per states and settings: a new dt, damping or
    rotation setting records it again (compared with one thread, which records nothing)."""
    from wcut import solver as solver_module

    monkeypatch.setitem(solver_module.FORCES_ELEMENTS_PER_THREAD, 1, 10)
    mesh, model, tip = _pulled_beam()
    targets = [mesh.vertices[tip] + [0.0, 0.0, 0.002 * k] for k in range(12)]
    dt = [0.01] * 4 + [0.005] * 8
    ends = []
    for threads in (1, 2):
        solver = SolverCorotational(model, cg_iterations=200, cg_tolerance=1e-7, cpu_threads=threads)
        first = _steps(model, solver, targets[:8], dt[:8])
        model.rayleigh_stiffness = 0.05
        solver.rotation_stiffness = False
        ends.append(first + _steps(model, solver, targets[8:], dt[8:]))
        model.rayleigh_stiffness = 0.0
    assert solver.cpu_threads == 2 and len(solver._element_passes) >= 3
    scale = np.abs(ends[0][-1] - mesh.vertices).max()  # 2.5 mm; a stale pass drifts by millimetres
    assert scale > 1e-3
    for one, two in zip(*ends):
        assert np.abs(two - one).max() < 1e-4 * scale


# -- stability and accuracy at any stiffness with the default settings ------------------------


def _released_bodies():
    """A solid beam (P1 and P2) and a sheet, each to be released from a stretched and bent shape."""
    return {"p1": wcut.beam(4, 2, 2, size=(0.2, 0.05, 0.05)),
            "p2": to_quadratic(wcut.beam(2, 1, 1, size=(0.2, 0.05, 0.05))),
            "shell": wcut.rectangle_sheet(4, 4, (0.1, 0.1))}


@pytest.mark.parametrize("dt", [1.0e-4, 1.0 / 30.0])
@pytest.mark.parametrize("poisson_ratio", [0.3, 0.49])
@pytest.mark.parametrize("youngs_modulus", [1.0e3, 1.0e6, 1.0e9])
@pytest.mark.parametrize("kind", ["p1", "p2", "shell"])
def test_a_released_body_stays_finite_and_never_gains_energy(kind, youngs_modulus, poisson_ratio, dt):
    """A free, undamped body released from a stretched and bent shape, default solver settings:
    its mechanical energy (float64, conftest.mechanical_energy) never grows from one step to the
    next beyond float32 rounding (1e-6 of the start), whatever the stiffness, Poisson's ratio and
    time step: implicit Euler dissipates."""
    mesh = _released_bodies()[kind]
    model = Model(mesh, youngs_modulus=youngs_modulus, poisson_ratio=poisson_ratio, gravity=(0.0, 0.0, 0.0))
    rest = model.particle_q.numpy().astype(np.float64)
    centre, length = rest.mean(axis=0), np.ptp(rest[:, 0])
    bend = np.sin(np.pi * (rest[:, 0] - rest[:, 0].min()) / length)
    start = centre + (rest - centre) * [1.1, 1.0, 0.97] + np.outer(bend, [0.0, 0.0, 0.01 * length])
    solver = SolverCorotational(model)
    state, scratch = model.state(), model.state()
    state.particle_q.assign(start.astype(np.float32))
    energies = [mechanical_energy(model, state)]
    for _ in range(10):
        solver.step(state, scratch, None, dt)
        state, scratch = scratch, state
        energies.append(mechanical_energy(model, state))
        assert solver.last_cg_iterations < solver.cg_iterations  # converged, not stopped by the cap
    solver.check()
    assert np.isfinite(state.particle_q.numpy()).all()
    growth = np.diff(energies)
    assert growth.max() <= 1e-6 * energies[0], (energies, growth.max() / energies[0])


def test_the_benchmark_beam_settles_on_its_static_solution():
    """SOFA's benchmark beam (10x10x40, clamped at z = 0, transverse gravity, 1 MPa) with the
    default solver, one step per 1/60 s frame: it settles on the static deflection of the same
    corotational model that scipy finds by Newton's method (within 1%; the static answer of
    the linear model, 38.4 mm, is 1.6% off the corotational one)."""
    tip = _settle_beam(wcut.beam(10, 10, 40, size=(0.1, 0.1, 0.4)))
    assert abs(tip["settled"] - tip["static"]) < 0.01 * abs(tip["static"]), tip


def test_the_benchmark_beam_settles_after_a_cut_that_leaves_slivers():
    """The same beam cut into the top 30% of its depth at mid-length by a plane, with no
    snapping (epsilon 0), so the cut leaves hundreds of slivers (below 1e-3 of the median
    volume) next to the mesh's nodes: it settles on the static deflection of the cut mesh."""
    mesh = wcut.beam(10, 10, 40, size=(0.1, 0.1, 0.4))
    topo = TetTopology(mesh)
    plane = Plane([0.0, 0.0, 0.2031], [0.02, 0.03, 1.0])
    Cutter(topo, epsilon=0.0, improve=False).cut(plane, bounds=([-1.0, 0.0704, -1.0], [1.0, 1.0, 1.0]))
    cut = topo.to_mesh()
    volumes = cut.volumes()
    assert np.count_nonzero(volumes < 1e-3 * np.median(volumes)) > 100  # slivers
    tip = _settle_beam(cut)
    assert abs(tip["settled"] - tip["static"]) < 0.01 * abs(tip["static"]), tip


def test_a_small_free_piece_beside_a_body_keeps_its_shape():
    """A cut can free a piece of a few small elements. Here one free element of 0.1 mm, stretched
    by 10%, beside a clamped beam of 100 mm, under gravity: it springs back and falls with
    the beam. Stopped on the whole system's residual alone, the solve hardly saw its nodes, and
    its velocity error stretched it to 1.5e5 times its volume in two steps (inverted after
    five, at 63 m/s); with the per-node velocity test it converges too."""
    body = wcut.beam(10, 2, 2, size=(0.1, 0.02, 0.02))
    corners = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    tiny = 1e-4 * corners + [0.05, 0.05, 0.0]
    mesh = wcut.TetMesh(np.vstack([body.vertices, tiny]), np.vstack([body.tets, body.vertex_count + np.arange(4)]))
    model = Model(mesh, density=1100.0, youngs_modulus=1e5, poisson_ratio=0.3,
                  fixed=np.flatnonzero(body.vertices[:, 0] < 1e-9))
    solver = SolverCorotational(model)
    a, b = model.state(), model.state()
    q = a.particle_q.numpy()
    q[-4:] = tiny[0] + 1.1 * (tiny - tiny[0])
    a.particle_q.assign(q)
    rest = np.linalg.det(tiny[1:] - tiny[0]) / 6.0
    for _ in range(10):
        solver.step(a, b, None, None, 1.0 / 30.0)
        a, b = b, a
        p = a.particle_q.numpy()[-4:].astype(np.float64)
        volume = np.linalg.det(p[1:] - p[0]) / 6.0
        assert 0.5 * rest < volume < 2.0 * rest
    # it falls with gravity, as the beam's free end does (10 steps of 1/30 s: 1.8 m/s)
    speed = np.linalg.norm(a.particle_qd.numpy()[-4:], axis=1)
    assert np.all(np.abs(speed - 9.81 / 3.0) < 0.5)


def _settle_beam(mesh, youngs_modulus=1.0e6):
    """Tip deflection (m, along gravity) of a beam clamped at z = 0 after 2.5 s of 1/60 s steps,
    and its static deflection from the scipy reference."""
    fixed = mesh.vertices_in_box((-1.0, -1.0, -1.0), (1.0, 1.0, 1e-9))
    model = Model(mesh, density=1000.0, youngs_modulus=youngs_modulus, poisson_ratio=0.3, gravity=(0.0, -9.81, 0.0),
                  fixed=fixed)
    tip = int(np.argmax(mesh.vertices[:, 2] - 1e-3 * mesh.vertices[:, 1]))
    state = run(model, SolverCorotational(model), 150, 1.0 / 60.0)
    ref = ScipyCorotationalStep(mesh.vertices, mesh.tets, density=1000.0, youngs_modulus=youngs_modulus,
                                poisson_ratio=0.3, gravity=(0.0, -9.81, 0.0), fixed=fixed)
    static = ref.static_equilibrium()
    return {"settled": float(state.particle_q.numpy()[tip, 1] - mesh.vertices[tip, 1]),
            "static": float(static[tip, 1] - mesh.vertices[tip, 1])}


def test_a_blow_up_is_an_error_naming_the_step():
    """A vertex thrown at 1e4 m/s (far beyond the 31 m/s wave speed of the material) is a
    diverged run, not an animation: check() names the steps."""
    _, model, _ = clamped_beam()
    solver = SolverCorotational(model)
    state, scratch = model.state(), model.state()
    for _ in range(3):
        solver.step(state, scratch, None, 0.01)
        state, scratch = scratch, state
    solver.check()  # a falling beam is fine
    assert 0 < solver.speed_limit < 1e3
    qd = state.particle_qd.numpy()
    qd[-1] = [1.0e4, 0.0, 0.0]
    state.particle_qd.assign(qd)
    solver.step(state, scratch, None, 0.01)
    with pytest.raises(SimulationError, match=r"diverged in step 4 .*m/s"):
        solver.check()
    solver.check()  # reported once: the next check looks at the steps since


def test_newton_s_step_signature_and_numpy_time_steps():
    """``step(state_in, state_out, control, contacts, dt)`` as Newton's solvers take it (contacts
    None), NumPy scalars for dt; the same step as ``step(state_in, state_out, control, dt)``."""
    _, model, _ = clamped_beam()
    ours, newton = SolverCorotational(model), SolverCorotational(model)
    a, b, c, d = model.state(), model.state(), model.state(), model.state()
    for _ in range(3):
        ours.step(a, b, None, 0.01)
        newton.step(c, d, None, None, np.float64(0.01))
        a, b, c, d = b, a, d, c
    np.testing.assert_array_equal(a.particle_q.numpy(), c.particle_q.numpy())
    newton.step(c, d, None, dt=np.float32(0.01))
    newton.step(c, d, None, None, np.array(0.01))
    with pytest.raises(SimulationError, match="no contacts"):
        newton.step(c, d, None, object(), 0.01)
    for bad in (True, "0.01", np.array([0.01]), -0.01, float("nan")):
        with pytest.raises(SimulationError, match="time step must be a positive finite number"):
            newton.step(c, d, None, bad)


def test_state_and_control_take_newton_s_keywords():
    _, model, _ = clamped_beam()
    assert model.state(requires_grad=False).particle_q.shape == (model.particle_count,)
    model.control(requires_grad=None, clone_variables=False)
    with pytest.raises(wcut.ModelError, match="not differentiable"):
        model.state(requires_grad=True)
