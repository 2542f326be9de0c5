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


def test_rebuild_keeps_what_a_fresh_model_of_the_new_mesh_computes(clamped):
    """Model.rebuild copies the rows a cut left alone and recomputes the others (rest frames
    of reshaped elements, masses of the vertices around changed elements): every array must
    agree with a Model built from scratch on the mesh after, with each element's material."""
    mesh, ends = clamped
    rng = np.random.default_rng(5)
    material = dict(density=rng.uniform(500.0, 2000.0, mesh.tet_count),
                    youngs_modulus=rng.uniform(1e4, 1e6, mesh.tet_count),
                    poisson_ratio=rng.uniform(0.1, 0.45, mesh.tet_count))
    model = Model(mesh, fixed=ends, **material)
    topo = TetTopology(mesh)
    change = Cutter(topo, epsilon=0.1).cut(Plane([0.21, 0.0, 0.0], [1.0, 0.2, 0.3])).change
    assert len(change.added_elements) > 50
    after = topo.to_mesh()
    rebuilt, _ = model.rebuild(after, change)
    parent = change.element_parent
    fresh = Model(after, fixed=np.flatnonzero(rebuilt.particle_fixed.numpy()),
                  **{key: value[parent] for key, value in material.items()})
    for name in ("tet_indices", "tet_density", "tet_youngs_modulus", "tet_poisson_ratio", "particle_fixed"):
        assert np.array_equal(getattr(rebuilt, name).numpy(), getattr(fresh, name).numpy()), name
    for name in ("particle_mass", "particle_load_mass", "tet_rest_volume", "tet_stiffness"):
        assert np.allclose(getattr(rebuilt, name).numpy(), getattr(fresh, name).numpy(), rtol=1e-6, atol=0), name
    assert np.allclose(rebuilt.tet_poses.numpy(), fresh.tet_poses.numpy(), rtol=1e-5, atol=1e-3)


MODEL_ARRAYS = ("particle_q", "particle_qd", "particle_mass", "particle_load_mass", "particle_fixed", "tet_indices",
                "tet_poses", "tet_rest_volume", "tet_stiffness", "tet_density", "tet_youngs_modulus",
                "tet_poisson_ratio", "attachment_indices", "attachment_weights", "attachment_stiffness",
                "attachment_rest_points")
STATE_ARRAYS = ("particle_q", "particle_qd", "particle_f", "tet_rotation")


def test_rebuild_in_place_equals_rebuild_by_copies(clamped):
    """``rebuild(in_place=True)`` writes the rows a cut changes into the model's and state's own
    buffers (their spare rows take what the cut adds) and must give, bit for bit, what the
    copying rebuild gives, over successive cuts, including one that outgrows the spare rows."""
    from wcut.model import Attachments

    mesh, ends = clamped
    rng = np.random.default_rng(3)
    make = dict(fixed=ends, density=rng.uniform(500.0, 2000.0, mesh.tet_count),
                attachments=Attachments.at_vertices([40, 41], 10.0))
    copied, in_place = Model(mesh, **make), Model(mesh, **make)
    states = []
    for model in (copied, in_place):
        state = model.state()
        state.particle_q.assign(state.particle_q.numpy() + rng.normal(0.0, 1e-3, (model.particle_count, 3)))
        state.particle_qd.assign(rng.normal(0.0, 1e-2, (model.particle_count, 3)))
        state.particle_f.assign(rng.normal(0.0, 1.0, (model.particle_count, 3)))
        states.append(state)
    copied_state, in_place_state = states
    in_place_state.particle_q.assign(copied_state.particle_q)
    in_place_state.particle_qd.assign(copied_state.particle_qd)
    in_place_state.particle_f.assign(copied_state.particle_f)
    topo = TetTopology(mesh, positions=copied_state.particle_q.numpy(), velocities=copied_state.particle_qd.numpy())
    cutter, deleter = Cutter(topo, epsilon=0.2), Cutter(topo, method="delete")
    cuts = [(cutter, Plane([0.13, 0.0, 0.0], [1.0, 0.1, 0.2])), (cutter, Plane([0.27, 0.0, 0.0], [1.0, -0.3, 0.1])),
            (deleter, Plane([0.025, 0.0, 0.0], [1.0, 0.0, 0.0])),  # drops vertices: the others are renumbered
            (cutter, Plane([0.2, 0.05, 0.0], [0.1, 1.0, 0.3]))]
    reused = []
    for method, plane in cuts:
        change = method.cut(plane).change
        if method is deleter:
            assert change.vertex_count_after < change.vertex_count_before  # renumbered
        after = topo.to_mesh()
        buffer = in_place._buffers["tet_poses"]
        copied, copied_state = copied.rebuild(after, change, copied_state)
        in_place, in_place_state = in_place.rebuild(after, change, in_place_state, in_place=True)
        reused.append(in_place._buffers["tet_poses"] is buffer)
        for name in MODEL_ARRAYS:
            assert np.array_equal(getattr(in_place, name).numpy(), getattr(copied, name).numpy()), name
        for name in STATE_ARRAYS:
            assert np.array_equal(getattr(in_place_state, name).numpy(), getattr(copied_state, name).numpy()), name
        # the masses, updated by the shares of the changed elements (in float64), are those summed
        # from scratch to float32 rounding, even where a vertex is left with a sliver's mass
        fresh = Model(after, density=in_place.tet_density.numpy().astype(np.float64))
        assert np.allclose(in_place.particle_mass.numpy(), fresh.particle_mass.numpy(), rtol=3e-7, atol=0)
    assert reused[0] and not all(reused)  # in place while the spare rows last, then a new buffer


def test_change_record_lists_equal_the_scans_they_spare(clamped):
    """A change from the topology's journal lists its reparented elements, touched vertices and
    rewired elements when it can (every slot live before and after); the rebuild then scans
    nothing. They must be what the scans of every element and vertex find, and the rebuild
    the same, bit for bit, with them and without them: over compiled cuts, cuts by the Python
    operators (which swap vertices for their copies in place), a deletion (renumbering) and
    cuts after it (without the mesh improvement, whose flips free slots)."""
    import dataclasses

    from wcut.model import _reparented, _touched_vertices

    mesh, ends = clamped
    topo = TetTopology(mesh)
    compiled, python, deleter = Cutter(topo, epsilon=0.2, improve=False), \
        Cutter(topo, epsilon=0.2, compiled=False, improve=False), \
        Cutter(topo, method="delete")
    model = Model(mesh, fixed=ends)
    state = model.state()
    listed = 0
    for cutter, plane in [(compiled, Plane([0.13, 0.0, 0.0], [1.0, 0.1, 0.2])),
                          (python, Plane([0.27, 0.0, 0.0], [1.0, -0.3, 0.1])),
                          (deleter, Plane([0.025, 0.0, 0.0], [1.0, 0.0, 0.0])),
                          (compiled, Plane([0.2, 0.05, 0.0], [0.1, 1.0, 0.3])),
                          (python, Plane([0.33, 0.0, 0.05], [0.2, 0.3, 1.0]))]:
        change = cutter.cut(plane).change
        if cutter is deleter:
            assert change.vertex_count_after < change.vertex_count_before  # renumbered
        bare = dataclasses.replace(change, reparented_elements=None, touched_vertices=None, rewired_elements=None)
        if change.reparented_elements is not None:
            listed += 1
            assert np.array_equal(change.reparented_elements, _reparented(bare))
        if change.touched_vertices is not None:
            assert np.array_equal(change.touched_vertices, _touched_vertices(bare))
        if change.rewired_elements is not None:  # with the reparented and reshaped: every row that differs
            k = min(change.element_count_before, change.element_count_after)
            differ = np.flatnonzero((model.tet_indices.numpy()[:k] != topo.to_mesh().tets[:k]).any(axis=1))
            covered = np.union1d(change.rewired_elements, np.union1d(
                _reparented(bare), np.flatnonzero(change.element_rest_changed)))
            assert np.isin(differ, covered).all()
        after = topo.to_mesh()
        with_lists, with_state = model.rebuild(after, change, state)
        model, state = model.rebuild(after, bare, state)
        for name in MODEL_ARRAYS:
            assert np.array_equal(getattr(with_lists, name).numpy(), getattr(model, name).numpy()), name
        for name in STATE_ARRAYS:
            assert np.array_equal(getattr(with_state, name).numpy(), getattr(state, name).numpy()), name
    assert listed >= 3
