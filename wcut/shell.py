"""The quadratic (6-node) triangle of thin shells: shape functions, Gauss rule, rest frames,
masses and bending hinges, in numpy (thesis 6.2).

Node order is VTK ``triangle6``: corners 0, 1, 2, then the nodes of edges (0, 1), (1, 2),
(2, 0) (:data:`EDGES`). With barycentric coordinates ``L = (L0, L1, L2)``::

    corner k:     N_k  = L_k (2 L_k - 1)
    edge (i, j):  N_ij = 4 L_i L_j

and reference coordinates ``xi = (L1, L2)``. This module is the host-side reference of
``wcut.kernels.tri_p2`` and ``wcut.kernels.bending``; the tests check them against each other.
"""

from __future__ import annotations

import numpy as np

#: Corner pairs of the three edge nodes 3..5.
EDGES = np.array([[0, 1], [1, 2], [2, 0]], dtype=np.int64)

#: The four linear triangles of an element's six nodes (its sub-triangulation), oriented as
#: the element: three at the corners and the middle one.
SUBTRIANGLES = np.array([[0, 3, 5], [3, 1, 4], [5, 4, 2], [3, 4, 5]], dtype=np.int64)

#: The nodes of a 6-node triangle traversed the other way round (corners 1 and 2 swapped).
REVERSED = np.array([0, 2, 1, 5, 4, 3], dtype=np.int64)

#: 3-point rule of degree 2 (exact for the stiffness of a straight element): point g has
#: barycentric coordinate 2/3 at corner g, 1/6 at the others. Strains and stresses are
#: evaluated there (thesis 6.2), so the map must be regular there.
GAUSS_POINTS = np.full((3, 3), 1.0 / 6.0) + np.eye(3) * 0.5
#: Weights on the reference triangle (area 1/2): ``A = sum w |det J|`` for a flat element.
GAUSS_WEIGHTS = np.full(3, 1.0 / 6.0)

#: Barycentric coordinates of the six nodes.
NODE_POINTS = np.vstack([np.eye(3), 0.5 * (np.eye(3)[EDGES[:, 0]] + np.eye(3)[EDGES[:, 1]])])

#: 7-point rule of degree 5 (Radon) for areas. The area element of a flat 6-node triangle,
#: curved edges in its plane included, is a quadratic polynomial, so its area is exact; out of
#: plane it is the square root of a quartic, not a polynomial, and the rule is accurate to
#: O(h^6) (relative error 2e-5 for a whole sphere octant in one element, see the tests).
_RA, _RB = (6.0 - np.sqrt(15.0)) / 21.0, (6.0 + np.sqrt(15.0)) / 21.0
AREA_POINTS = np.vstack([np.full(3, 1.0 / 3.0),
                         np.full((3, 3), _RA) + np.eye(3) * (1.0 - 3.0 * _RA),
                         np.full((3, 3), _RB) + np.eye(3) * (1.0 - 3.0 * _RB)])
#: Weights of :data:`AREA_POINTS` on the reference triangle (area 1/2).
AREA_WEIGHTS = np.array([9.0 / 40.0] + [(155.0 - np.sqrt(15.0)) / 1200.0] * 3
                        + [(155.0 + np.sqrt(15.0)) / 1200.0] * 3) / 2.0

#: HRZ lumped mass fractions (corners, edge nodes): each node's share is its diagonal entry of
#: the consistent mass matrix (``1/30`` and ``8/45`` of ``rho h A``) rescaled to sum to one.
#: Row-sum lumping gives the corners nothing (their shape functions integrate to zero).
HRZ_FRACTIONS = np.array([3.0 / 57.0] * 3 + [16.0 / 57.0] * 3)
#: ``int N_a dA / A`` of a straight element: the consistent load (gravity) fractions.
LOAD_FRACTIONS = np.array([0.0] * 3 + [1.0 / 3.0] * 3)

_DL_DXI = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]])  # dL/dxi (3, 2)


def shape_functions(L: np.ndarray) -> np.ndarray:
    """The six shape functions (P, 6) at barycentric points ``L`` (P, 3)."""
    L = np.atleast_2d(L)
    return np.concatenate([L * (2.0 * L - 1.0), 4.0 * L[:, EDGES[:, 0]] * L[:, EDGES[:, 1]]], axis=1)


def shape_gradients(L: np.ndarray) -> np.ndarray:
    """``dN_a/dxi`` (P, 6, 2) at barycentric points ``L`` (P, 3)."""
    L = np.atleast_2d(L)
    dN_dL = np.zeros((len(L), 6, 3))
    for k in range(3):
        dN_dL[:, k, k] = 4.0 * L[:, k] - 1.0
    for m, (i, j) in enumerate(EDGES):
        dN_dL[:, 3 + m, i] = 4.0 * L[:, j]
        dN_dL[:, 3 + m, j] = 4.0 * L[:, i]
    return dN_dL @ _DL_DXI


def area_vectors(vertices: np.ndarray, triangles: np.ndarray, L: np.ndarray) -> np.ndarray:
    """``dX/dxi1 x dX/dxi2`` (M, P, 3) of 6-node triangles (M, 6) at barycentric points ``L``
    (P, 3): the surface normal scaled by the area element (m^2 per unit reference area)."""
    tangents = np.einsum("mai,pak->mpik", vertices[triangles], shape_gradients(L))
    return np.cross(tangents[..., 0], tangents[..., 1])


def corner_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """``(x1 - x0) x (x2 - x0)`` (M, 3) of the corners: the flat triangle's normal, of length
    twice its area (m^2)."""
    x0 = vertices[triangles[:, 0]]
    return np.cross(vertices[triangles[:, 1]] - x0, vertices[triangles[:, 2]] - x0)


def areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Areas (m^2) of curved 6-node triangles (M,) by the 7-point degree-5 rule: exact for
    flat elements (see :data:`AREA_POINTS`)."""
    return np.linalg.norm(area_vectors(vertices, triangles, AREA_POINTS), axis=2) @ AREA_WEIGHTS


def jacobians(vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Jacobian of each 6-node triangle relative to its corner normal, ``(dX/dxi1 x
    dX/dxi2) . n`` with ``n`` the unit normal of the corners (m^2 per unit reference area), at
    the Gauss points (M, 3) and at the nodes (M, 6). A straight element has twice its area
    everywhere; a curved one is valid while all are positive (it does not fold over itself)."""
    normals = corner_normals(vertices, triangles)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    unit = np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
    at_gauss = np.einsum("mpi,mi->mp", area_vectors(vertices, triangles, GAUSS_POINTS), unit)
    at_nodes = np.einsum("mpi,mi->mp", area_vectors(vertices, triangles, NODE_POINTS), unit)
    return at_gauss, at_nodes


def rest_frames(rest: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rest data at the Gauss points: ``(poses, areas, frames)``.

    - ``poses`` (M, 3, 2, 2): ``J^{-1}`` (1/m) with ``J = E^T dX/dxi`` and ``E = [E1 | E2]`` the
      orthonormal tangent basis (``E1`` along ``dX/dxi1``, normal ``E1 x E2`` along
      ``dX/dxi1 x dX/dxi2``);
    - ``areas`` (M, 3): the points' shares ``w_g det J`` of the rest area (m^2), all positive for
      an element that is not folded;
    - ``frames`` (M, 3, 3, 3): columns ``E1, E2, normal``.
    """
    dN = shape_gradients(GAUSS_POINTS)  # (3, 6, 2)
    T = np.einsum("mai,gaj->mgij", rest[triangles], dN)  # dX/dxi (M, 3, 3, 2)
    t1, t2 = T[..., 0], T[..., 1]
    e1 = t1 / np.linalg.norm(t1, axis=-1, keepdims=True)
    normal = np.cross(t1, t2)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    e2 = np.cross(normal, e1)
    frames = np.stack([e1, e2, normal], axis=-1)
    J = np.einsum("mgki,mgkj->mgij", frames[..., :2], T)
    det = J[..., 0, 0] * J[..., 1, 1] - J[..., 0, 1] * J[..., 1, 0]
    return np.linalg.inv(J), GAUSS_WEIGHTS * det, frames


def vertex_normals(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Unit normals (N, 3) at the nodes: the area-weighted mean of the normals of the
    sub-triangles (:data:`SUBTRIANGLES`) around each node; zero at an unused node."""
    sub = triangles[:, SUBTRIANGLES].reshape(-1, 3)
    x0 = points[sub[:, 0]]
    area_normals = np.cross(points[sub[:, 1]] - x0, points[sub[:, 2]] - x0)
    normals = np.zeros_like(points, dtype=np.float64)
    for k in range(3):
        np.add.at(normals, sub[:, k], area_normals)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)


def plane_stress_lame(youngs_modulus, poisson_ratio) -> tuple[np.ndarray, np.ndarray]:
    """``(mu, lambda*)`` (Pa) of plane stress: ``lambda* = 2 mu lambda / (lambda + 2 mu)
    = E nu / (1 - nu^2)``."""
    E, nu = np.asarray(youngs_modulus, dtype=np.float64), np.asarray(poisson_ratio, dtype=np.float64)
    return E / (2.0 * (1.0 + nu)), E * nu / (1.0 - nu * nu)


def flexural_rigidity(youngs_modulus, poisson_ratio, thickness) -> np.ndarray:
    """``D = Y h^3 / (12 (1 - nu^2))`` (N*m) of a plate of thickness h (m)."""
    return np.asarray(youngs_modulus) * np.asarray(thickness) ** 3 / (12.0 * (1.0 - np.asarray(poisson_ratio) ** 2))


def hinges(rest: np.ndarray, triangles: np.ndarray, rigidity: np.ndarray):
    """Bending hinges of the sub-triangulation (:data:`SUBTRIANGLES`) of 6-node triangles,
    for ``wcut.kernels.bending``.

    Every edge shared by two sub-triangles is a hinge ``(x0, x1, x2, x3)``: the edge as the
    first triangle runs it, then the opposite vertex of each triangle. Returns ``(indices
    (H, 4), weights (H, 4) (1/m), stiffness (H,) (N*m), rest_curvature (H, 3))``, the last the rest value of
    ``sum w_i X_i`` (dimensionless, zero for a flat rest shape) in the hinge's rest frame.

    The weights are the affine dependency of the hinge unfolded into a plane (each triangle
    keeps its shape): ``w2 = 1/h2``, ``w3 = 1/h3`` (heights over the edge), ``w0`` and ``w1``
    such that ``sum w = 0`` and ``sum w_i P_i = 0``. ``stiffness = D |e|^2 / (A0 + A1)`` with
    ``D`` the mean rigidity of the hinge's elements (``rigidity`` (M,) N*m).
    """
    sub = triangles[:, SUBTRIANGLES].reshape(-1, 3)
    owner = np.repeat(np.arange(len(triangles)), 4)
    directed = np.concatenate([sub[:, [0, 1]], sub[:, [1, 2]], sub[:, [2, 0]]])
    opposite = np.concatenate([sub[:, 2], sub[:, 0], sub[:, 1]])
    element = np.tile(owner, 3)
    order = np.lexsort((np.max(directed, axis=1), np.min(directed, axis=1)))
    key = np.sort(directed[order], axis=1)
    same = np.all(key[1:] == key[:-1], axis=1)
    first, second = order[:-1][same], order[1:][same]
    indices = np.column_stack([directed[first], opposite[first], opposite[second]])

    X = rest[indices]
    edge = X[:, 1] - X[:, 0]
    length = np.linalg.norm(edge, axis=1)
    along = edge / length[:, None]
    heights, offsets, areas = [], [], []
    for apex in (X[:, 2], X[:, 3]):
        d = apex - X[:, 0]
        offset = np.einsum("ij,ij->i", d, along)
        height = np.linalg.norm(d - offset[:, None] * along, axis=1)
        heights.append(height)
        offsets.append(offset)
        areas.append(0.5 * length * height)
    w2, w3 = 1.0 / heights[0], 1.0 / heights[1]
    w1 = -(w2 * offsets[0] + w3 * offsets[1]) / length
    weights = np.column_stack([-(w1 + w2 + w3), w1, w2, w3])
    D = 0.5 * (rigidity[element[first]] + rigidity[element[second]])
    stiffness = D * length ** 2 / (areas[0] + areas[1])

    curvature = np.einsum("hi,hij->hj", weights, X)
    normal = np.cross(edge, X[:, 2] - X[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    frame = np.stack([along, normal, np.cross(along, normal)], axis=-1)
    rest_curvature = np.einsum("hij,hi->hj", frame, curvature)
    return indices, weights, stiffness, rest_curvature


def bending_energy(points: np.ndarray, indices: np.ndarray, weights: np.ndarray, stiffness: np.ndarray,
                   rest_curvature: np.ndarray) -> float:
    """The hinge energy ``1/2 sum k |sum w_i x_i - R_h b|^2`` (J) of ``wcut.kernels.bending``."""
    X = points[indices]
    edge = X[:, 1] - X[:, 0]
    along = edge / np.linalg.norm(edge, axis=1, keepdims=True)
    normal = np.cross(edge, X[:, 2] - X[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    frame = np.stack([along, normal, np.cross(along, normal)], axis=-1)
    s = np.einsum("hi,hij->hj", weights, X) - np.einsum("hij,hj->hi", frame, rest_curvature)
    return float(0.5 * np.sum(stiffness * np.einsum("hj,hj->h", s, s)))
