"""Rotation extraction (kernels/rotation.py): the polar iteration measured against the SVD."""

import numpy as np
import pytest
import warp as wp
from scipy.spatial.transform import Rotation

from wcut.kernels import rotation


def polar(F, q_start=None, iterations=100, tolerance=1e-7):
    F = np.asarray(F, dtype=np.float32)
    q0 = np.tile([0.0, 0.0, 0.0, 1.0], (len(F), 1)) if q_start is None else q_start
    out = wp.empty(len(F), dtype=wp.mat33)
    wp.launch(rotation.extract_rotations, len(F),
              inputs=[wp.array(F, dtype=wp.mat33), wp.array(q0, dtype=wp.quat), iterations, tolerance], outputs=[out])
    return out.numpy()


def svd(F):
    out = wp.empty(len(F), dtype=wp.mat33)
    wp.launch(rotation.extract_rotations_svd, len(F), inputs=[wp.array(np.asarray(F, np.float32), dtype=wp.mat33)],
              outputs=[out])
    return out.numpy()


def closest_rotation(F):
    """float64 numpy reference: maximiser of tr(R^T F) over proper rotations."""
    U, _, Vt = np.linalg.svd(F)
    D = np.ones((len(F), 3))
    D[:, 2] = np.sign(np.linalg.det(U @ Vt))
    return U @ (D[:, :, None] * Vt)


def assert_proper_rotations(R, atol=1e-5):
    eye = np.broadcast_to(np.eye(3), R.shape)
    np.testing.assert_allclose(np.einsum("nji,njk->nik", R, R), eye, atol=atol)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=atol)


def random_deformations(rng, count, stretch=(0.5, 2.0)):
    Q = Rotation.random(count, random_state=rng.integers(1 << 31)).as_matrix()
    S = rng.uniform(*stretch, size=(count, 3))
    V = Rotation.random(count, random_state=rng.integers(1 << 31)).as_matrix()
    return Q @ V @ (S[:, :, None] * V.transpose(0, 2, 1))  # F = Q (V S V^T): polar rotation Q


def test_polar_matches_svd_and_analytic_rotation():
    rng = np.random.default_rng(1)
    F = random_deformations(rng, 500)
    R = polar(F)
    assert_proper_rotations(R)
    np.testing.assert_allclose(R, closest_rotation(F), atol=2e-6)
    # warp's svd3 runs a fixed number of Jacobi sweeps: two orders of magnitude less accurate
    np.testing.assert_allclose(svd(F), closest_rotation(F), atol=1e-3)


def test_cold_start_on_inverted_elements_gives_a_proper_rotation():
    rng = np.random.default_rng(2)
    F = random_deformations(rng, 300)
    F[:, :, 0] *= -1.0  # a reflection: det F < 0
    assert np.all(np.linalg.det(F) < 0)
    R, R_ref = polar(F), closest_rotation(F)
    assert np.isfinite(R).all()
    assert_proper_rotations(R)
    # From the identity, the iteration reaches the trace maximiser for nearly all inverted
    # matrices (98% here) and another stationary point for the rest; the simulation never
    # starts cold (next test).
    assert np.mean(np.all(np.abs(R - R_ref) < 1e-3, axis=(1, 2))) > 0.95
    assert_proper_rotations(svd(F), atol=1e-3)


def test_warm_start_tracks_an_element_through_flattening_and_inversion():
    """An element squashed through zero thickness into inversion, one step at a time."""
    Q = Rotation.from_rotvec([0.3, -1.1, 0.7]).as_matrix()
    q = Rotation.from_matrix(Q).as_quat()[None]  # the element's rotation before squashing
    for s in np.linspace(1.0, -0.6, 33):  # includes s = 0 (flat)
        F = (Q @ np.diag([1.2, 0.9, s]))[None]
        R = polar(F, q_start=q, iterations=4)
        np.testing.assert_allclose(R[0], Q, atol=2e-5)  # the maximiser flips the smallest direction
        q = Rotation.from_matrix(R[0].astype(np.float64)).as_quat()[None]


@pytest.mark.parametrize("rank", [0, 1, 2])
def test_flat_and_collapsed_elements_give_a_finite_proper_rotation(rank):
    rng = np.random.default_rng(3 + rank)
    F = random_deformations(rng, 100)
    U, s, Vt = np.linalg.svd(F)
    s[:, rank:] = 0.0
    F = U @ (s[:, :, None] * Vt)
    R = polar(F)
    assert np.isfinite(R).all()
    assert_proper_rotations(R)


def test_warm_start_at_the_answer_needs_one_check():
    rng = np.random.default_rng(5)
    F = random_deformations(rng, 50)
    q = Rotation.from_matrix(closest_rotation(F)).as_quat()  # (x, y, z, w) like warp
    R = polar(F, q_start=q, iterations=1)
    np.testing.assert_allclose(R, closest_rotation(F), atol=2e-5)
