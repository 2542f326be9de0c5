"""Model, State, Control and Attachments: rest data, lumped mass, and clear errors."""

import numpy as np
import pytest
import warp as wp

import wcut
from wcut.errors import ModelError
from wcut.model import Attachments, Model


def test_rest_data_mass_and_arrays(small_beam):
    model = Model(small_beam, density=1200.0, youngs_modulus=3e5, poisson_ratio=0.25)
    volume = small_beam.volumes()
    assert np.isclose(model.particle_mass.numpy().sum(), 1200.0 * volume.sum(), rtol=1e-6)
    np.testing.assert_allclose(model.tet_rest_volume.numpy(), volume, rtol=1e-5)
    # Dm^-1 maps rest edges to the identity
    X = small_beam.vertices[small_beam.tets]
    Dm = np.stack([X[:, 0] - X[:, 3], X[:, 1] - X[:, 3], X[:, 2] - X[:, 3]], axis=2)
    np.testing.assert_allclose(model.tet_poses.numpy() @ Dm, np.broadcast_to(np.eye(3), Dm.shape), atol=1e-5)
    for name in ("particle_q", "particle_mass", "particle_fixed", "tet_indices", "tet_poses", "tet_stiffness",
                 "tet_density", "tet_youngs_modulus", "tet_poisson_ratio", "attachment_indices",
                 "attachment_rest_points"):
        assert isinstance(getattr(model, name), wp.array), name
    state = model.state()
    assert state.particle_f.shape == (model.particle_count,) and not state.particle_f.numpy().any()
    assert np.allclose(state.tet_rotation.numpy(), [0, 0, 0, 1])


def test_per_element_material(small_beam):
    E = np.linspace(1e4, 1e6, small_beam.tet_count)
    model = Model(small_beam, youngs_modulus=E, poisson_ratio=0.0)
    np.testing.assert_allclose(model.tet_stiffness.numpy()[:, 0], model.tet_rest_volume.numpy() * E / 2, rtol=1e-5)


def test_attachments_at_points_reproduce_the_point(small_beam):
    points = [[0.05, 0.01, 0.02], [0.17, 0.04, 0.03]]
    attached = Attachments.at_points(small_beam, points, [5.0, 7.0])
    assert np.allclose(attached.weights.sum(axis=1), 1.0)
    np.testing.assert_allclose(np.einsum("sj,sjk->sk", attached.weights, small_beam.vertices[attached.indices]),
                               points, atol=1e-12)
    model = Model(small_beam, attachments=attached)
    np.testing.assert_allclose(model.control().attachment_target.numpy(), points, atol=1e-6)


@pytest.mark.parametrize("kwargs, words", [
    (dict(density="abc"), "density: expected a number"),
    (dict(density=-1.0), "density"),
    (dict(youngs_modulus=[1.0, 2.0]), "youngs_modulus: expected a number or"),
    (dict(poisson_ratio=0.5), "poisson_ratio"),
    (dict(poisson_ratio=-1.0), "poisson_ratio"),
    (dict(rayleigh_mass="x"), "rayleigh_mass: expected a number"),
    (dict(rayleigh_stiffness=-0.1), "rayleigh_stiffness"),
    (dict(gravity=(0, 0)), "gravity"),
    (dict(gravity=(0, 0, float("nan"))), "gravity"),
    (dict(fixed=[0.7, 1.9]), "fixed: expected integer"),
    (dict(fixed=[10 ** 6]), "fixed: vertex index 1000000 out of range"),
    (dict(fixed=np.ones(3, dtype=bool)), "fixed: a mask needs"),
])
def test_bad_model_parameters(small_beam, kwargs, words):
    with pytest.raises(ModelError, match=words):
        Model(small_beam, **kwargs)


def test_negative_poisson_ratio_is_a_material(small_beam):
    Model(small_beam, poisson_ratio=-0.3)  # auxetic foams exist


@pytest.mark.parametrize("args, words", [
    (([[0, 1, 2]], [[1, 0, 0]], [1.0]), "shape"),
    (([[0, 1, 2, 3]], [[np.nan, 0, 0, 0]], [1.0]), "attachment 0 has a non-finite weight"),
    (([[0, 1, 2, 3]] * 2, [[1, 0, 0, 0]] * 2, [1.0, 2.0, 3.0]), "shape"),
    (([[0, 1, 2, 3]], [[1, 0, 0, 0]], [-1.0]), "negative"),
    (([[0.5, 1, 2, 3]], [[1, 0, 0, 0]], [1.0]), "integers"),
])
def test_bad_attachments(args, words):
    with pytest.raises(ModelError, match=words):
        Attachments(*args)


def test_attachment_index_out_of_range(small_beam):
    with pytest.raises(ModelError, match="attachments: vertex index"):
        Model(small_beam, attachments=Attachments.at_vertices([small_beam.vertex_count], 1.0))


def test_rest_frames_use_the_float32_positions():
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 0.3, 1e-4]]) * 0.1 + 10.0
    model = Model(wcut.TetMesh(x, [[0, 1, 2, 3]]))
    rest = model.particle_q.numpy().astype(np.float64)
    Dm = np.stack([rest[0] - rest[3], rest[1] - rest[3], rest[2] - rest[3]], axis=1)
    np.testing.assert_allclose(model.tet_poses.numpy()[0] @ Dm, np.eye(3), atol=2e-4)
