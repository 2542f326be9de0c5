"""Model.rebuild: the flat arrays laid out again after a cut, the state carried over."""

from __future__ import annotations

import numpy as np
import pytest

from wcut.cut import Cutter, Plane
from wcut.errors import ModelError
from wcut.mesh import beam
from wcut.model import Model
from wcut.solver import SolverCorotational
from wcut.topology import TetTopology


@pytest.fixture(scope="module")
def clamped():
    mesh = beam(8, 3, 3, size=(0.4, 0.1, 0.1))
    ends = np.concatenate([mesh.vertices_in_box([-1e-3, -1, -1], [1e-3, 1, 1]),
                           mesh.vertices_in_box([0.4 - 1e-3, -1, -1], [0.4 + 1e-3, 1, 1])])
    return mesh, ends


def _settled(model, steps=20, dt=0.01):
    solver = SolverCorotational(model)
    a, b, control = model.state(), model.state(), model.control()
    for _ in range(steps):
        solver.step(a, b, control, dt)
        a, b = b, a
    return a


def test_rebuild_carries_state_and_keeps_running(clamped):
    mesh, ends = clamped
    model = Model(mesh, youngs_modulus=1e5, rayleigh_stiffness=0.01, fixed=ends)
    state = _settled(model)
    topo = TetTopology(mesh, positions=state.particle_q.numpy(), velocities=state.particle_qd.numpy())
    change = Cutter(topo, epsilon=0.1).cut(Plane([0.21, 0.0, 0.0], [1.0, 0.0, 0.3])).change
    after = topo.to_mesh()
    new_model, new_state = model.rebuild(after, change, state)
    assert (new_model.particle_count, new_model.tet_count) == (after.vertex_count, after.tet_count)
    # positions of every vertex, old or new, are the cutter's interpolated current positions
    assert np.allclose(new_state.particle_q.numpy(), topo.positions, atol=1e-6)
    assert np.allclose(new_state.particle_qd.numpy(), topo.velocities, atol=1e-6)
    assert new_model.fixed_count == model.fixed_count  # the clamped ends were not cut
    assert np.isclose(new_model.particle_mass.numpy().sum(), model.particle_mass.numpy().sum(), rtol=1e-6)
    assert np.isclose(new_model.tet_rest_volume.numpy().sum(), mesh.volumes().sum(), rtol=1e-5)
    # kept elements keep their rest frames, new ones get exact ones
    fresh = Model(after, youngs_modulus=1e5, fixed=np.flatnonzero(new_model.particle_fixed.numpy()))
    assert np.allclose(new_model.tet_poses.numpy(), fresh.tet_poses.numpy(), rtol=1e-4, atol=1e-3)
    solver = SolverCorotational(new_model)
    a, b, control = new_state, new_model.state(), new_model.control()
    energies = []
    for i in range(500):
        solver.step(a, b, control, 0.01)
        a, b = b, a
        if i % 50 == 49:
            v = a.particle_qd.numpy()
            energies.append(0.5 * float((new_model.particle_mass.numpy() * (v * v).sum(axis=1)).sum()))
    assert np.isfinite(a.particle_q.numpy()).all()
    assert max(energies[-3:]) < 1e-3  # damped: settles, no energy blow-up


def test_rebuild_rejects_a_change_of_another_mesh(clamped):
    mesh, ends = clamped
    model = Model(mesh, fixed=ends)
    other = beam(2, 2, 2)
    topo = TetTopology(other)
    change = Cutter(topo).cut(Plane([0.5, 0.5, 0.5], [1.0, 0.1, 0.0])).change
    with pytest.raises(ModelError, match="change is from a mesh"):
        model.rebuild(topo.to_mesh(), change)
