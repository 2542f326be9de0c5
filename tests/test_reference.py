"""Tests of the numpy/scipy reference step (wcut.reference)."""

import itertools

import numpy as np
import pytest
import scipy.sparse as sp

from wcut.errors import WcutError
from wcut.reference import ScipyCorotationalStep

# ---------------------------------------------------------------------------------------
# meshes built here, independent of wcut.mesh


def _orient(X, T):
    """Swap two vertices of negatively oriented tets."""
    T = np.array(T, dtype=np.int64)
    Xe = X[T]
    det = np.linalg.det(np.transpose(Xe[:, 1:] - Xe[:, :1], (0, 2, 1)))
    neg = det < 0
    T[neg, 2], T[neg, 3] = T[neg, 3].copy(), T[neg, 2].copy()
    return T


def grid_mesh(nx, ny, nz, h=1.0, split=6):
    """Box of nx*ny*nz cubes of edge h, each split into 6 (Kuhn) or 5 tets (alternating parity)."""
    ii, jj, kk = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), np.arange(nz + 1), indexing="ij")
    X = h * np.stack([ii.ravel(), jj.ravel(), kk.ravel()], axis=1).astype(float)

    def vid(i, j, k):
        return (i * (ny + 1) + j) * (nz + 1) + k

    corners = [(a, b, c) for c in (0, 1) for b in (0, 1) for a in (0, 1)]  # v0..v7, v = a + 2b + 4c
    if split == 6:
        local = []
        for perm in itertools.permutations(range(3)):
            p = [0, 0, 0]
            path = [tuple(p)]
            for ax in perm:
                p[ax] = 1
                path.append(tuple(p))
            local.append([corners.index(q) for q in path])
        local_sets = [local, local]
    elif split == 5:
        even = [[0, 3, 5, 6], [1, 0, 3, 5], [2, 0, 3, 6], [4, 0, 5, 6], [7, 3, 5, 6]]
        odd = [[1, 2, 4, 7], [0, 1, 2, 4], [3, 1, 2, 7], [5, 1, 4, 7], [6, 2, 4, 7]]
        local_sets = [even, odd]
    else:
        raise ValueError(split)
    T = []
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                cv = [vid(i + a, j + b, k + c) for (a, b, c) in corners]
                for tet in local_sets[(i + j + k) % 2]:
                    T.append([cv[q] for q in tet])
    return X, _orient(X, T)


def random_rotation(rng):
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    return q


MAT = dict(density=1000.0, youngs_modulus=1e5, poisson_ratio=0.3)


def make(X, T, **kw):
    args = dict(MAT)
    args.update(kw)
    return ScipyCorotationalStep(X, T, **args)


def corotational_energy(sim, x):
    R = sim.rotations(x)
    d = (x[sim.tets] @ R - sim.rest_positions[sim.tets]).reshape(-1, 12)
    return 0.5 * np.einsum("mi,mij,mj->", d, sim.element_stiffness(), d)


# ---------------------------------------------------------------------------------------
# element stiffness


def test_meshes_are_conforming_and_fill_the_box():
    for split in (5, 6):
        X, T = grid_mesh(2, 3, 4, h=0.5, split=split)
        sim = make(X, T)
        assert np.isclose(sim.volumes.sum(), 2 * 3 * 4 * 0.125)
        # every interior face is shared by exactly two tets, boundary faces by one
        faces = np.sort(T[:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]].reshape(-1, 3), axis=1)
        _, counts = np.unique(faces, axis=0, return_counts=True)
        assert set(counts.tolist()) <= {1, 2}
        assert (counts == 1).sum() == 2 * 2 * (2 * 3 + 3 * 4 + 2 * 4)


def test_element_stiffness_symmetric_psd_six_rigid_modes():
    X, T = grid_mesh(2, 2, 2, h=0.1, split=5)
    rng = np.random.default_rng(0)
    X = X + 0.01 * rng.standard_normal(X.shape)  # irregular tets
    sim = make(X, T, youngs_modulus=rng.uniform(1e4, 1e6, len(T)), poisson_ratio=0.45)
    Ke = sim.element_stiffness()
    assert Ke.shape == (len(T), 12, 12)
    np.testing.assert_allclose(Ke, np.transpose(Ke, (0, 2, 1)), rtol=0, atol=1e-9 * np.abs(Ke).max())
    ev = np.linalg.eigvalsh(Ke)
    scale = ev[:, -1:]
    assert np.all(ev > -1e-10 * scale)
    assert np.all(np.sum(np.abs(ev) < 1e-10 * scale, axis=1) == 6)
    assert np.all(ev[:, 6] > 1e-6 * scale[:, 0])
    assert sim.element_stiffness() is Ke  # cached


def test_element_stiffness_matches_voigt_BtCB():
    rng = np.random.default_rng(1)
    X = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) + 0.2 * rng.standard_normal((4, 3))
    T = _orient(X, [[0, 1, 2, 3]])
    E, nu = 3e5, 0.35
    sim = make(X, T, youngs_modulus=E, poisson_ratio=nu)
    G = sim.shape_gradients[0]
    B = np.zeros((6, 12))  # engineering strain, Voigt order xx yy zz yz xz xy
    for a in range(4):
        gx, gy, gz = G[a]
        B[:, 3 * a : 3 * a + 3] = [[gx, 0, 0], [0, gy, 0], [0, 0, gz], [0, gz, gy], [gz, 0, gx], [gy, gx, 0]]
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    C = np.zeros((6, 6))
    C[:3, :3] = lam
    C[:3, :3] += 2 * mu * np.eye(3)
    C[3:, 3:] = mu * np.eye(3)
    np.testing.assert_allclose(sim.element_stiffness()[0], sim.volumes[0] * B.T @ C @ B, rtol=1e-12, atol=1e-6)


def test_shape_gradients_and_masses():
    X, T = grid_mesh(2, 2, 2, h=0.25, split=6)
    rho = np.linspace(500, 1500, len(T))
    sim = make(X, T, density=rho)
    np.testing.assert_allclose(sim.shape_gradients.sum(axis=1), 0, atol=1e-12)
    # grad N_a . (X_b - X_0) = delta_ab - delta_a0 ... check interpolation of linear fields
    Xe = X[T]
    np.testing.assert_allclose(np.einsum("mai,maj->mij", Xe, sim.shape_gradients), np.broadcast_to(np.eye(3), (len(T), 3, 3)), atol=1e-12)
    assert np.isclose(sim.masses.sum(), np.sum(rho * sim.volumes))
    assert np.all(sim.masses > 0)


# ---------------------------------------------------------------------------------------
# assembled stiffness, forces, rotations


def test_rest_stiffness_annihilates_rigid_modes():
    X, T = grid_mesh(2, 2, 3, h=0.2, split=5)
    sim = make(X, T)
    K = sim.stiffness_matrix(X)
    assert sp.issparse(K) and K.shape == (3 * len(X), 3 * len(X))
    assert abs(K - K.T).max() < 1e-9 * abs(K).max()
    scale = abs(K).max() * np.abs(X).max()
    for c in np.eye(3):
        u = np.broadcast_to(c, X.shape).ravel()
        assert np.abs(K @ u).max() < 1e-10 * scale
    for w in np.eye(3):
        u = np.cross(w, X - X.mean(axis=0)).ravel()  # infinitesimal rotation
        assert np.abs(K @ u).max() < 1e-10 * scale


def test_internal_force_zero_at_rest_and_for_rigid_motion():
    X, T = grid_mesh(2, 2, 3, h=0.2, split=6)
    sim = make(X, T)
    fscale = sim.youngs_modulus[0] * 0.2 * 0.2  # E * h^2 ~ force of unit strain
    assert np.abs(sim.internal_forces(X)).max() < 1e-10 * fscale
    rng = np.random.default_rng(2)
    for _ in range(3):
        Q = random_rotation(rng)
        x = X @ Q.T + rng.standard_normal(3)
        assert np.abs(sim.internal_forces(x)).max() < 1e-9 * fscale


def test_rotations_identity_at_rest_and_Q_for_rotated_shape():
    X, T = grid_mesh(2, 2, 2, h=0.3, split=5)
    sim = make(X, T)
    R0 = sim.rotations(X)
    np.testing.assert_allclose(R0, np.broadcast_to(np.eye(3), R0.shape), atol=1e-12)
    rng = np.random.default_rng(3)
    Q = random_rotation(rng)
    R = sim.rotations(X @ Q.T + np.array([1.0, -2.0, 0.5]))
    np.testing.assert_allclose(R, np.broadcast_to(Q, R.shape), atol=1e-12)
    # rotated stiffness is the rest stiffness rotated
    Qb = sp.kron(sp.identity(len(X)), Q)
    K0, KQ = sim.stiffness_matrix(X), sim.stiffness_matrix(X @ Q.T)
    assert abs(KQ - Qb @ K0 @ Qb.T).max() < 1e-10 * abs(K0).max()


def test_rotation_is_proper_for_inverted_element():
    X = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    sim = make(X, [[0, 1, 2, 3]])
    x = X.copy()
    x[3, 2] = -0.5  # inverted
    R = sim.rotations(x)[0]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(R), 1.0)


def test_patch_test_affine_displacement():
    X, T = grid_mesh(3, 3, 3, h=1.0 / 3.0, split=5)
    sim = make(X, T)
    rng = np.random.default_rng(4)
    H = 1e-3 * rng.standard_normal((3, 3))
    H = 0.5 * (H + H.T)  # small symmetric: polar rotation is exactly I
    c = 1e-3 * rng.standard_normal(3)
    u = X @ H.T + c
    interior = np.all((X > 1e-9) & (X < 1 - 1e-9), axis=1)
    assert interior.sum() == 8
    Ku = (sim.stiffness_matrix(X) @ u.ravel()).reshape(-1, 3)
    scale = np.abs(Ku).max()
    assert scale > 0
    assert np.abs(Ku[interior]).max() < 1e-10 * scale
    f = sim.internal_forces(X + u)
    np.testing.assert_allclose(f, -Ku, rtol=0, atol=1e-9 * scale)
    assert np.abs(f[interior]).max() < 1e-9 * scale


def test_internal_force_is_minus_gradient_of_corotational_energy():
    X, T = grid_mesh(2, 2, 2, h=0.5, split=6)
    sim = make(X, T, youngs_modulus=np.linspace(1e4, 1e5, len(T)), poisson_ratio=0.4)
    rng = np.random.default_rng(5)
    Q = random_rotation(rng)
    x = (X + 0.06 * rng.standard_normal(X.shape)) @ Q.T + 0.3
    f = sim.internal_forces(x)
    eps = 1e-6
    grad = np.zeros(x.size)
    for k in range(x.size):
        xp, xm = x.copy().ravel(), x.copy().ravel()
        xp[k] += eps
        xm[k] -= eps
        grad[k] = (corotational_energy(sim, xp.reshape(-1, 3)) - corotational_energy(sim, xm.reshape(-1, 3))) / (2 * eps)
    np.testing.assert_allclose(f.ravel(), -grad, rtol=0, atol=1e-6 * np.abs(f).max())
    assert np.abs(f).max() > 0


def test_internal_forces_sum_to_zero_and_no_net_torque():
    X, T = grid_mesh(2, 2, 2, h=0.5, split=5)
    sim = make(X, T)
    rng = np.random.default_rng(6)
    x = X + 0.1 * rng.standard_normal(X.shape)
    f = sim.internal_forces(x)
    scale = np.abs(f).max()
    assert np.abs(f.sum(axis=0)).max() < 1e-10 * scale
    assert np.abs(np.cross(x, f).sum(axis=0)).max() < 1e-9 * scale


# ---------------------------------------------------------------------------------------
# springs


def test_springs_force_and_matrix():
    X, T = grid_mesh(1, 1, 2, h=1.0, split=6)
    rng = np.random.default_rng(7)
    si = np.array([[0, 1, 2, 3], [5, 6, 0, 0], [7, 7, 7, 7]])
    sw = np.array([[0.1, 0.2, 0.3, 0.4], [0.5, 0.5, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]])
    ks = np.array([10.0, 20.0, 30.0])
    sim = make(X, T, spring_indices=si, spring_weights=sw, spring_stiffness=ks)
    t = rng.standard_normal((3, 3))
    x = X + 0.1 * rng.standard_normal(X.shape)
    KS = sim.spring_matrix()
    f = sim.spring_forces(x, t)
    # f = -K_S x + sum_s k_s w_s (x) t_s : check against an independent dense build
    Kd = np.zeros((3 * len(X), 3 * len(X)))
    fd = np.zeros_like(x)
    for s in range(3):
        p = sum(sw[s, j] * x[si[s, j]] for j in range(4))
        for j in range(4):
            fd[si[s, j]] -= ks[s] * sw[s, j] * (p - t[s])
            for k in range(4):
                Kd[3 * si[s, j] : 3 * si[s, j] + 3, 3 * si[s, k] : 3 * si[s, k] + 3] += ks[s] * sw[s, j] * sw[s, k] * np.eye(3)
    np.testing.assert_allclose(KS.toarray(), Kd, atol=1e-12)
    np.testing.assert_allclose(f, fd, atol=1e-12)
    # linear in x with Jacobian -K_S
    dx = rng.standard_normal(x.shape)
    np.testing.assert_allclose(sim.spring_forces(x + dx, t) - f, -(KS @ dx.ravel()).reshape(-1, 3), atol=1e-12)
    with pytest.raises(WcutError):
        sim.rhs(x, np.zeros_like(x), 0.01)  # targets missing


# ---------------------------------------------------------------------------------------
# the implicit step


def _scene(**kw):
    X, T = grid_mesh(2, 2, 4, h=0.05, split=6)
    rng = np.random.default_rng(8)
    fixed = X[:, 2] < 1e-9
    top = np.flatnonzero(X[:, 2] > 0.2 - 1e-9)[:2]
    args = dict(
        rayleigh_mass=0.5,
        rayleigh_stiffness=0.01,
        gravity=(0.0, 0.0, -9.81),
        fixed=fixed,
        spring_indices=[[top[0], top[1], 0, 0]],
        spring_weights=[[0.5, 0.5, 0.0, 0.0]],
        spring_stiffness=[200.0],
    )
    args.update(kw)
    sim = make(X, T, **args)
    x = X + 0.005 * rng.standard_normal(X.shape)
    x[fixed] = X[fixed]
    v = 0.1 * rng.standard_normal(X.shape)
    v[fixed] = 0.0
    f_ext = 0.01 * rng.standard_normal(X.shape)
    targets = np.array([[0.05, 0.05, 0.3]])
    return sim, x, v, f_ext, targets


def test_direct_step_solves_the_system_on_free_dofs():
    sim, x, v, f_ext, targets = _scene()
    dt = 1e-2
    x1, v1 = sim.step(x, v, dt, f_ext=f_ext, spring_targets=targets, direct=True)
    A = sim.system_matrix(x, dt)
    b = sim.rhs(x, v, dt, f_ext=f_ext, spring_targets=targets).ravel()
    assert abs(A - A.T).max() < 1e-12 * abs(A).max()
    free = np.flatnonzero(np.repeat(~sim.fixed, 3))
    dv = (v1 - v).ravel()
    res = A[free][:, free] @ dv[free] - b[free]
    assert np.linalg.norm(res) < 1e-10 * np.linalg.norm(b[free])
    np.testing.assert_allclose(x1, x + dt * v1, atol=1e-15)
    # the system matrix is the documented combination
    M = sp.diags(np.repeat(sim.masses, 3))
    K, KS = sim.stiffness_matrix(x), sim.spring_matrix()
    A_ref = (1 + dt * 0.5) * M + (dt**2 + dt * 0.01) * K + dt**2 * KS
    assert abs(A - A_ref).max() < 1e-12 * abs(A).max()


def test_cg_matches_direct():
    sim, x, v, f_ext, targets = _scene()
    dt = 1e-2
    xd, vd = sim.step(x, v, dt, f_ext=f_ext, spring_targets=targets, direct=True)
    xc, vc = sim.step(x, v, dt, f_ext=f_ext, spring_targets=targets, cg_iterations=5000, cg_tolerance=1e-13)
    assert sim.last_cg_info == 0
    np.testing.assert_allclose(vc, vd, rtol=0, atol=1e-9 * np.abs(vd).max())
    np.testing.assert_allclose(xc, xd, rtol=0, atol=1e-9 * np.abs(vd).max() * dt)
    # a few iterations: not converged, but finite; starting at the answer stays there
    sim.step(x, v, dt, f_ext=f_ext, spring_targets=targets, cg_iterations=2)
    assert sim.last_cg_iterations <= 2
    x2, v2 = sim.step(x, v, dt, f_ext=f_ext, spring_targets=targets, cg_iterations=1, dv0=vd - v)
    np.testing.assert_allclose(v2, vd, atol=1e-8 * np.abs(vd).max())


def test_free_body_conserves_linear_momentum():
    X, T = grid_mesh(2, 2, 2, h=0.1, split=5)
    sim = make(X, T, density=np.linspace(800, 1200, len(T)))
    rng = np.random.default_rng(9)
    x = X + 0.01 * rng.standard_normal(X.shape)
    v = rng.standard_normal(X.shape)
    p0 = (sim.masses[:, None] * v).sum(axis=0)
    for direct in (True, False):
        x1, v1 = sim.step(x, v, 1e-2, direct=direct, cg_iterations=2000, cg_tolerance=1e-14)
        p1 = (sim.masses[:, None] * v1).sum(axis=0)
        np.testing.assert_allclose(p1, p0, rtol=0, atol=1e-10 * np.abs(sim.masses[:, None] * v).sum())


def test_fixed_vertices_do_not_move():
    sim, x, v, f_ext, targets = _scene()
    v_in = v.copy()
    v_in[sim.fixed] = 3.0  # ignored: fixed velocity is zero
    for direct in (True, False):
        x1, v1 = sim.step(x, v_in, 1e-2, f_ext=f_ext, spring_targets=targets, direct=direct)
        assert np.array_equal(x1[sim.fixed], x[sim.fixed])
        assert np.all(v1[sim.fixed] == 0.0)
        assert np.abs(x1[~sim.fixed] - x[~sim.fixed]).max() > 0
    # index-array form of `fixed` is equivalent to the mask
    sim2 = make(sim.rest_positions, sim.tets, fixed=np.flatnonzero(sim.fixed), gravity=(0, 0, -9.81))
    assert np.array_equal(sim2.fixed, sim.fixed)


def test_gravity_fall_of_unconstrained_body():
    X, T = grid_mesh(1, 1, 1, h=0.1, split=6)
    sim = make(X, T, gravity=(0.0, -9.81, 0.0))
    x1, v1 = sim.step(X, np.zeros_like(X), 0.01, direct=True)
    np.testing.assert_allclose(v1, np.broadcast_to([0, -0.0981, 0], X.shape), atol=1e-12)
    np.testing.assert_allclose(x1, X + 0.01 * v1, atol=1e-15)


# ---------------------------------------------------------------------------------------
# validation


def test_invalid_inputs_raise_wcut_error():
    X, T = grid_mesh(1, 1, 1, h=1.0, split=5)
    with pytest.raises(WcutError, match="non-positive volume"):
        make(X, T[:, [0, 2, 1, 3]])
    with pytest.raises(WcutError):
        make(X[:, :2], T)
    Xn = X.copy()
    Xn[0, 0] = np.nan
    with pytest.raises(WcutError, match="non-finite"):
        make(Xn, T)
    with pytest.raises(WcutError):
        make(X, T + 100)
    with pytest.raises(WcutError):
        make(X, T.astype(float))
    with pytest.raises(WcutError):
        make(X, T, poisson_ratio=0.5)
    with pytest.raises(WcutError):
        make(X, T, youngs_modulus=np.ones(3))
    with pytest.raises(WcutError):
        make(X, T, fixed=np.ones(3, dtype=bool))
    with pytest.raises(WcutError):
        make(X, T, spring_indices=[[0, 1, 2, 3]])
    with pytest.raises(WcutError, match="belong to no tet"):
        make(np.vstack([X, [[5.0, 5.0, 5.0]]]), T)
    sim = make(X, T)
    with pytest.raises(WcutError):
        sim.step(X, np.zeros((3, 3)), 0.01)
    with pytest.raises(WcutError):
        sim.step(X, np.zeros_like(X), -0.01)
    xn = X.copy()
    xn[1, 1] = np.inf
    with pytest.raises(WcutError):
        sim.internal_forces(xn)
