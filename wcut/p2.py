"""The quadratic (10-node) tetrahedron: shape functions, Gauss rules and Jacobians, in numpy.

Node order is VTK's ``tetra10`` (meshio's ``tetra10``): corners 0..3, then the nodes of
the edges (0,1), (1,2), (2,0), (0,3), (1,3), (2,3) (:data:`EDGES`). In barycentric
coordinates ``L = (L0, L1, L2, L3)`` the shape functions are (thesis eq. 3.16-3.17,
table A.3)::

    corner k:     N_k  = L_k (2 L_k - 1)
    edge (i, j):  N_ij = 4 L_i L_j

The reference coordinates are ``xi = (L1, L2, L3)`` (node 0 at the origin), so the Jacobian
``J = dX/dxi`` of a straight element is ``[X1-X0 | X2-X0 | X3-X0]`` and a positively oriented
element (``det[v1-v0, v2-v0, v3-v0] > 0``, as :class:`wcut.mesh.TetMesh` keeps them) has
``det J > 0`` everywhere. A curved element (edge nodes off the straight midpoints) has a ``J``
that varies over the element; it is valid while ``det J > 0`` at every point that matters:
the Gauss points and the nodes (:func:`jacobian_determinants`).

This module is the host-side reference: the Warp kernels in ``wcut.kernels.tet_p2`` evaluate
the same formulas, and the tests check them against each other.
"""

from __future__ import annotations

import numpy as np

from .mesh import unique_rows

#: Corner pairs of the six edge nodes 4..9 (VTK tetra10 order).
EDGES = np.array([[0, 1], [1, 2], [2, 0], [0, 3], [1, 3], [2, 3]], dtype=np.int64)

#: 4-point Gauss rule of degree 2 (exact for the stiffness of a straight P2 element, whose
#: shape-function gradients are linear): barycentric coordinates, one point near each corner.
_A, _B = (5.0 + 3.0 * np.sqrt(5.0)) / 20.0, (5.0 - np.sqrt(5.0)) / 20.0
GAUSS_POINTS = np.full((4, 4), _B) + np.eye(4) * (_A - _B)
#: Weights of :data:`GAUSS_POINTS` on the reference element (volume 1/6): ``V = sum w det J``.
GAUSS_WEIGHTS = np.full(4, 1.0 / 24.0)

#: 5-point rule of degree 3 (Keast): exact for ``det J`` of a curved P2 element (a cubic), so
#: volumes of curved elements are exact. One negative weight, at the centroid.
VOLUME_POINTS = np.vstack([np.full(4, 0.25), np.full((4, 4), 1.0 / 6.0) + np.eye(4) * (0.5 - 1.0 / 6.0)])
VOLUME_WEIGHTS = np.array([-4.0 / 5.0] + [9.0 / 20.0] * 4) / 6.0

#: Barycentric coordinates of the ten nodes.
NODE_POINTS = np.vstack([np.eye(4), 0.5 * (np.eye(4)[EDGES[:, 0]] + np.eye(4)[EDGES[:, 1]])])

#: dL/dxi (4, 3): L0 = 1 - xi0 - xi1 - xi2, L(k+1) = xi_k.
_DL_DXI = np.vstack([-np.ones(3), np.eye(3)])

#: HRZ lumped mass fractions of a straight P2 element (corners, edges): each node's share of
#: the element mass is its diagonal of the consistent mass matrix, ``1/70`` and ``8/105`` of
#: ``rho V``, rescaled to sum to one. Row-sum lumping would give corners ``-1/20`` (negative).
HRZ_FRACTIONS = np.array([1.0 / 36.0] * 4 + [4.0 / 27.0] * 6)


def shape_functions(L: np.ndarray) -> np.ndarray:
    """The ten shape functions (P, 10) at barycentric points ``L`` (P, 4)."""
    L = np.atleast_2d(L)
    corners = L * (2.0 * L - 1.0)
    edges = 4.0 * L[:, EDGES[:, 0]] * L[:, EDGES[:, 1]]
    return np.concatenate([corners, edges], axis=1)


def shape_gradients(L: np.ndarray) -> np.ndarray:
    """Gradients ``dN_a/dxi`` (P, 10, 3) of the shape functions at barycentric points (P, 4)."""
    L = np.atleast_2d(L)
    dN_dL = np.zeros((len(L), 10, 4))
    for k in range(4):
        dN_dL[:, k, k] = 4.0 * L[:, k] - 1.0
    for e, (i, j) in enumerate(EDGES):
        dN_dL[:, 4 + e, i] = 4.0 * L[:, j]
        dN_dL[:, 4 + e, j] = 4.0 * L[:, i]
    return dN_dL @ _DL_DXI


def jacobians(points: np.ndarray, tets: np.ndarray, L: np.ndarray) -> np.ndarray:
    """``J = dX/dxi`` (M, P, 3, 3) of elements ``tets`` (M, 10) at barycentric points ``L``
    (P, 4); ``points`` (N, 3) in metres."""
    return np.einsum("mai,paj->mpij", points[tets], shape_gradients(L))


def jacobian_determinants(points: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``det J`` (m^3 per unit reference volume) at the Gauss points (M, 4) and at the
    nodes (M, 10). An element is valid when all are positive."""
    return (np.linalg.det(jacobians(points, tets, GAUSS_POINTS)),
            np.linalg.det(jacobians(points, tets, NODE_POINTS)))


def volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Exact volumes (m^3) of curved P2 elements (M,), by the degree-3 rule."""
    return np.linalg.det(jacobians(points, tets, VOLUME_POINTS)) @ VOLUME_WEIGHTS


def midpoint_edges(tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The unique edges of linear elements ``tets`` (M, 4) as sorted corner pairs (E, 2), and
    for every element the index of its six edges in VTK order (M, 6)."""
    pairs = np.sort(tets[:, EDGES], axis=2).reshape(-1, 2)
    edges, inverse = unique_rows(pairs, int(pairs.max(initial=0)) + 1, return_inverse=True)
    return edges, inverse.reshape(-1, 6)
