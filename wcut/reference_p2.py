"""Assembled reference of corotational quadratic tetrahedra, in numpy + scipy.sparse.

An independent implementation of what ``wcut.kernels.tet_p2`` computes matrix-free: it
assembles the 30x30 element matrices from the shape functions of :mod:`wcut.p2` (sharing no
code with the kernels), so the tests can check the kernels against a matrix, and the accuracy
study (``tools/p2_accuracy.py``) solves static problems with a direct solver. Per element and
Gauss point ``g`` (volume share ``V_g = w_g det J_g``, shape gradients ``G_g[a] = grad_X N_a``
in 1/m), with Lame parameters ``mu, lambda`` (Pa)::

    K_e[3a+i, 3b+j] = sum_g V_g (lambda G[b,j] G[a,i] + mu delta_ij G[a].G[b] + mu G[b,i] G[a,j])

and, corotated with the Gauss point's polar rotation ``R_g`` of ``F_g``, the gradients become
``R_g G_g`` (Hooke's law is isotropic). Degrees of freedom are ``3 * node + component``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import p2
from .model import lame_parameters


def gauss_gradients(points: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shape-function gradients ``grad_X N_a`` (M, 4, 10, 3) at the Gauss points of elements
    ``tets`` (M, 10) with rest node positions ``points`` (metres), and the points' volume shares
    ``w_g det J_g`` (M, 4) in m^3."""
    J = p2.jacobians(points, tets, p2.GAUSS_POINTS)  # (M, 4, 3, 3)
    dN = p2.shape_gradients(p2.GAUSS_POINTS)  # (4, 10, 3) in xi
    G = np.einsum("gaj,mgji->mgai", dN, np.linalg.inv(J))  # grad_X N = J^-T grad_xi N
    return G, np.linalg.det(J) * p2.GAUSS_WEIGHTS


def polar_rotations(points: np.ndarray, rest: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Polar rotations (M, 4, 3, 3) of ``F`` at the Gauss points (batched SVD, reflection
    removed by flipping the singular vector of the smallest singular value)."""
    G, _ = gauss_gradients(rest, tets)
    return _rotations(_deformation_gradients(points, tets, G))


def _deformation_gradients(points: np.ndarray, tets: np.ndarray, G: np.ndarray) -> np.ndarray:
    """``F`` (M, 4, 3, 3) at the Gauss points, from the rest shape gradients G."""
    return np.einsum("mai,mgaj->mgij", points[tets], G)


def _rotations(F: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(F)
    R = U @ Vt
    neg = np.linalg.det(R) < 0
    U[neg, :, 2] *= -1.0
    R[neg] = U[neg] @ Vt[neg]
    return R


def stiffness_matrix(rest: np.ndarray, tets: np.ndarray, youngs_modulus, poisson_ratio,
                     rotations: np.ndarray | None = None) -> sp.csr_matrix:
    """The (corotated) stiffness matrix (3N, 3N) in N/m of P2 elements; ``rotations`` (M, 4, 3, 3)
    per Gauss point, identity when None (linear elasticity)."""
    G, Vg = gauss_gradients(rest, tets)
    if rotations is not None:
        G = np.einsum("mgij,mgaj->mgai", rotations, G)
    M = len(tets)
    mu, lam = (np.broadcast_to(v, (M,)) for v in lame_parameters(youngs_modulus, poisson_ratio))
    Ke = np.empty((M, 30, 30))
    for s in range(0, M, 1024):  # in chunks: the 6-index terms take 29 kB per element
        c = slice(s, s + 1024)
        g, w = G[c], Vg[c][:, :, None, None, None, None]
        term_lam = np.einsum("mgai,mgbj->mgaibj", g, g)
        term_mu_t = np.einsum("mgaj,mgbi->mgaibj", g, g)
        dots = np.einsum("mgak,mgbk->mgab", g, g)
        term_mu_d = dots[:, :, :, None, :, None] * np.eye(3)[None, None, None, :, None, :]
        Ke[c] = (w * (lam[c, None, None, None, None, None] * term_lam + mu[c, None, None, None, None, None]
                      * (term_mu_d + term_mu_t))).sum(axis=1).reshape(-1, 30, 30)
    dofs = (3 * tets[:, :, None] + np.arange(3)).reshape(M, 30)
    rows = np.broadcast_to(dofs[:, :, None], (M, 30, 30)).ravel()
    cols = np.broadcast_to(dofs[:, None, :], (M, 30, 30)).ravel()
    n = 3 * len(rest)
    return sp.csr_matrix((Ke.ravel(), (rows, cols)), shape=(n, n))


def internal_forces(points: np.ndarray, rest: np.ndarray, tets: np.ndarray, youngs_modulus,
                    poisson_ratio) -> np.ndarray:
    """Corotational elastic forces (N, 3) in N: ``f_a = -sum_g V_g R sigma(R^T F - I) grad N_a``."""
    G, Vg = gauss_gradients(rest, tets)
    F = _deformation_gradients(points, tets, G)
    R = _rotations(F)
    mu, lam = (np.broadcast_to(v, (len(tets),))[:, None, None, None] for v in
               lame_parameters(youngs_modulus, poisson_ratio))
    E = np.einsum("mgji,mgjk->mgik", R, F) - np.eye(3)  # R^T F - I
    S = mu * (E + np.swapaxes(E, 2, 3)) + lam * np.trace(E, axis1=2, axis2=3)[:, :, None, None] * np.eye(3)
    P = np.einsum("mgij,mgjk->mgik", R, S) * Vg[:, :, None, None]
    fe = -np.einsum("mgij,mgaj->mai", P, G)
    out = np.zeros((len(points), 3))
    np.add.at(out, tets.ravel(), fe.reshape(-1, 3))
    return out


def body_load(rest: np.ndarray, tets: np.ndarray, density, gravity) -> np.ndarray:
    """Consistent nodal loads (N, 3) in N of a body force ``rho g``: ``int rho N_a g dV``."""
    _, Vg = gauss_gradients(rest, tets)
    load = (np.broadcast_to(density, (len(tets),))[:, None] * (Vg @ p2.shape_functions(p2.GAUSS_POINTS)))
    weights = np.zeros(len(rest))
    np.add.at(weights, tets.ravel(), load.ravel())
    return weights[:, None] * np.asarray(gravity, dtype=np.float64)


def static_solve(K: sp.csr_matrix, load: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """Displacements (N, 3) of the linear problem ``K u = f`` with ``u = 0`` on ``fixed``
    nodes (a direct sparse solve)."""
    n = len(load)
    free_nodes = np.ones(n, dtype=bool)
    free_nodes[fixed] = False
    free = np.flatnonzero(np.repeat(free_nodes, 3))
    u = np.zeros(3 * n)
    u[free] = spla.spsolve(K[free][:, free].tocsc(), load.reshape(-1)[free])
    return u.reshape(n, 3)
