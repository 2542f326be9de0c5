"""The public blade (wcut.Blade) in a user's own loop, with wcut.apply_change."""

from pathlib import Path

import numpy as np
import pytest

import wcut
from wcut.cut import CutError, SweptBlade
from wcut.scene import Simulation, blade_path, load_scene
from wcut.topology import check_topology

SWINGING = """
name = "swing"

[mesh]
generator = "beam"
cells = [8, 2, 2]
size = [0.16, 0.04, 0.04]

[material]
density = 1000.0
youngs_modulus = 3.0e5
poisson_ratio = 0.35

[constraints]
fixed_boxes = [[[-0.001, -1.0, -1.0], [0.001, 1.0, 1.0]]]

[simulation]
fps = 30

[cut]
method = "paulus"
epsilon = 0.1
frames = [10, 40]
blade = [[[0.081, -0.01, 0.05], [0.081, 0.05, 0.05]], [[0.081, -0.01, -0.01], [0.081, 0.05, -0.01]]]
"""

FRAMES = 45


def test_a_blade_in_a_user_loop_cuts_a_swinging_beam_as_the_scene_runner_does(tmp_path, write_scene):
    """The beam sags and swings under gravity while the blade goes down through it; the user's
    loop (Model, SolverCorotational, Blade, apply_change) gives the scene runner's mesh and
    motion."""
    scene = load_scene(write_scene(tmp_path, SWINGING, "swing.toml"))
    runner = Simulation(scene)
    for _ in range(FRAMES):
        runner.advance()

    model, control, _ = wcut.scene.build_model(scene)
    solver = wcut.SolverCorotational(model)
    state, next_state = model.state(), model.state()
    blade = wcut.Blade(model.mesh, method="paulus", epsilon=0.1)
    path = SweptBlade(blade_path(scene.cut)).blade
    blade.samples = runner.blade.samples  # the scene samples by its blade's longest position
    cuts = 0
    for frame in range(1, FRAMES + 1):
        solver.step(state, next_state, control, None, np.float64(runner.dt))  # Newton's signature, a NumPy dt
        state, next_state = next_state, state
        if 10 <= frame < 10 + len(path):
            change = blade.cut(state, *path[frame - 10])
            if change is not None:
                cuts += 1
                model, solver, (state, next_state), control = wcut.apply_change(
                    blade.mesh(), change, model, solver, (state, next_state), control)
    assert cuts == runner.cut_events >= 2
    check_topology(blade.topology, 0.16 * 0.04 * 0.04)
    mesh = blade.mesh()
    assert (mesh.vertex_count, mesh.tet_count) == (runner.model.particle_count, runner.model.tet_count)
    np.testing.assert_allclose(state.particle_q.numpy(), runner.state.particle_q.numpy(), atol=1e-5)
    assert state.particle_q.numpy()[:, 2].min() < -0.05  # the free half has fallen away


def test_apply_change_keeps_targets_forces_and_solver_settings():
    """A beam held by two attachment springs whose targets the user moved, with a load on its
    tip, cut through the middle: the model, both states, the control and the solver come over
    in one call, nothing reset to rest."""
    mesh = wcut.beam(6, 2, 2, size=(0.12, 0.04, 0.04))
    held = [0, 1]
    springs = wcut.model.Attachments(indices=np.repeat(np.array(held)[:, None], 4, axis=1),
                                     weights=np.tile([1.0, 0.0, 0.0, 0.0], (2, 1)), stiffness=[50.0, 50.0])
    model = wcut.Model(mesh, youngs_modulus=1e5, attachments=springs)
    solver = wcut.SolverCorotational(model, cg_tolerance=1e-3, preconditioner="jacobi", rotation_iterations=3)
    state, next_state, control = model.state(), model.state(), model.control()
    targets = control.attachment_target.numpy() + np.float32([0.0, 0.0, 0.01])
    control.attachment_target.assign(targets)
    tip = int(np.argmax(mesh.vertices[:, 0]))
    load = np.zeros((model.particle_count, 3), dtype=np.float32)
    load[tip] = [0.0, 0.0, -0.5]
    state.particle_f.assign(load)
    for _ in range(3):
        solver.step(state, next_state, control, 0.01)
        state, next_state = next_state, state
        state.particle_f.assign(load)
    topo = wcut.TetTopology(mesh, positions=state.particle_q.numpy().astype(np.float64))
    change = wcut.Cutter(topo).cut(wcut.Plane([0.061, 0.0, 0.0], [1.0, 0.1, 0.0])).change
    before = state.particle_q.numpy()
    model, solver, (state, next_state), control = wcut.apply_change(
        topo.to_mesh(), change, model, solver, (state, next_state), control)
    assert model.particle_count == topo.vertex_count > mesh.vertex_count
    np.testing.assert_array_equal(control.attachment_target.numpy(), targets)
    for each in (state, next_state):
        forces = each.particle_f.numpy()
        assert np.allclose(forces[: mesh.vertex_count][tip], [0.0, 0.0, -0.5]) and np.abs(forces).sum() == 0.5
    np.testing.assert_allclose(state.particle_q.numpy()[: mesh.vertex_count], before, atol=1e-6)
    assert (solver.cg_tolerance, solver.rotation_iterations, solver.preconditioner) == (1e-3, 3, None)
    solver.step(state, next_state, control, 0.01)  # and it runs on
    solver.check()


def test_the_blade_refuses_bad_positions_and_stale_states():
    mesh = wcut.beam(4, 2, 2, size=(0.08, 0.04, 0.04))
    model = wcut.Model(mesh, youngs_modulus=1e5)
    blade = wcut.Blade(mesh)
    with pytest.raises(CutError, match="start must be three finite coordinates"):
        blade.cut(model.state(), [0.0, np.nan, 0.0], [0.0, 0.0, 0.0])
    small = wcut.Model(wcut.beam(1, 1, 1), youngs_modulus=1e5)
    with pytest.raises(CutError, match="a state of the model after the last change"):
        blade.cut(small.state(), [0.04, -0.01, 0.05], [0.04, 0.05, 0.05])
    with pytest.raises(CutError, match="samples"):
        wcut.Blade(mesh, samples=1)
    from wcut.quadratic import to_quadratic

    curved = wcut.QuadraticTetMesh.load(Path(__file__).resolve().parents[1] / "scenes" / "meshes" / "organ_p2.vtu")
    with pytest.raises(CutError, match="improve needs straight quadratic elements"):
        wcut.Blade(curved, improve=True)
    # the improvement by default, where it applies
    assert blade.cutter.improve and wcut.Blade(to_quadratic(mesh)).cutter.improve
    assert not wcut.Blade(curved).cutter.improve and not wcut.Blade(mesh, improve=False).cutter.improve
    state = model.state()
    assert blade.cut(state, [0.041, -0.01, 0.05], [0.041, 0.05, 0.05]) is None  # placed
    blade.lift()
    assert blade.cut(state, [0.041, -0.01, -0.01], [0.041, 0.05, -0.01]) is None  # placed again: no stroke
    assert blade.cut(state, [0.041, -0.01, 0.05], [0.041, 0.05, 0.05]) is not None  # through the beam
