"""The quadratic tetrahedron's shape functions and quadrature rules (wcut/p2.py)."""

from itertools import product
from math import factorial

import numpy as np
import pytest

from wcut import p2


def test_shape_functions_interpolate_the_nodes_and_sum_to_one():
    N = p2.shape_functions(p2.NODE_POINTS)
    np.testing.assert_allclose(N, np.eye(10), atol=1e-15)
    L = np.random.default_rng(0).dirichlet(np.ones(4), size=50)
    np.testing.assert_allclose(p2.shape_functions(L).sum(axis=1), 1.0, atol=1e-14)


def test_gradients_match_finite_differences():
    L = np.random.default_rng(1).dirichlet(np.ones(4), size=20)
    h = 1e-6
    for k in range(3):  # xi_k = L_{k+1}, so moving xi_k moves L_{k+1} against L_0
        step = np.zeros(4)
        step[k + 1], step[0] = h, -h
        fd = (p2.shape_functions(L + step) - p2.shape_functions(L - step)) / (2 * h)
        np.testing.assert_allclose(p2.shape_gradients(L)[:, :, k], fd, atol=1e-8)


def _monomial_integral(powers) -> float:
    """Exact integral of L0^a L1^b L2^c L3^d over the reference tetrahedron (volume 1/6)."""
    return np.prod([factorial(a) for a in powers]) * factorial(3) / factorial(sum(powers) + 3) / 6.0


@pytest.mark.parametrize("rule, degree", [("gauss", 2), ("volume", 3)])
def test_quadrature_rules_are_exact_to_their_degree(rule, degree):
    points, weights = ((p2.GAUSS_POINTS, p2.GAUSS_WEIGHTS) if rule == "gauss"
                       else (p2.VOLUME_POINTS, p2.VOLUME_WEIGHTS))
    for powers in product(range(degree + 1), repeat=4):
        if sum(powers) <= degree:
            value = weights @ np.prod(points ** np.array(powers), axis=1)
            assert value == pytest.approx(_monomial_integral(powers), rel=1e-12, abs=1e-15), powers
    # and not beyond: the rules are the smallest that do the job
    powers = (degree + 1, 0, 0, 0)
    assert weights @ points[:, 0] ** (degree + 1) != pytest.approx(_monomial_integral(powers), rel=1e-6)


def test_integrals_of_shape_functions_and_hrz_fractions():
    """Corners integrate to -V/20 and edge nodes to V/5 (so row-sum lumping is negative); HRZ
    uses the consistent-mass diagonal 1/70 and 8/105, normalised."""
    integrals = p2.GAUSS_WEIGHTS @ p2.shape_functions(p2.GAUSS_POINTS) * 6.0  # in units of V
    np.testing.assert_allclose(integrals, [-1 / 20] * 4 + [1 / 5] * 6, atol=1e-14)
    # consistent mass diagonal by a degree-4 computation: exact monomial integrals of N_a^2
    diag = []
    for a in range(10):
        if a < 4:  # (2L^2 - L)^2 = 4L^4 - 4L^3 + L^2
            pw = lambda k: tuple(k if i == a else 0 for i in range(4))  # noqa: E731
            diag.append(4 * _monomial_integral(pw(4)) - 4 * _monomial_integral(pw(3)) + _monomial_integral(pw(2)))
        else:
            i, j = p2.EDGES[a - 4]
            diag.append(16 * _monomial_integral(tuple(2 if k in (i, j) else 0 for k in range(4))))
    diag = np.array(diag) * 6.0
    np.testing.assert_allclose(diag[:4], 1 / 70)
    np.testing.assert_allclose(diag[4:], 8 / 105)
    np.testing.assert_allclose(p2.HRZ_FRACTIONS, diag / diag.sum())
    assert p2.HRZ_FRACTIONS.min() > 0 and p2.HRZ_FRACTIONS.sum() == pytest.approx(1.0)


def test_jacobian_and_volume_of_a_curved_element():
    """A straight element has det J = 6V everywhere; a bulged one has the volume the degree-3
    rule gives."""
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    points = np.vstack([corners, 0.5 * (corners[p2.EDGES[:, 0]] + corners[p2.EDGES[:, 1]])])
    tets = np.arange(10)[None]
    at_gauss, at_nodes = p2.jacobian_determinants(points, tets)
    np.testing.assert_allclose(at_gauss, 1.0)
    np.testing.assert_allclose(at_nodes, 1.0)
    assert p2.volumes(points, tets)[0] == pytest.approx(1 / 6)
    # bulge the node of edge (1, 2) by t (1, 1, 1); det J is then a cubic polynomial, and the
    # degree-3 rule must agree with a Monte Carlo integral of it
    bulged = points.copy()
    bulged[5] += 0.05
    L = np.random.default_rng(2).dirichlet(np.ones(4), size=400000)
    J = np.einsum("ai,paj->pij", bulged, p2.shape_gradients(L))
    monte_carlo = np.linalg.det(J).mean() / 6.0
    assert monte_carlo > 1 / 6 + 0.01  # to first order the bulge adds t / 3 (the divergence theorem)
    assert p2.volumes(bulged, tets)[0] == pytest.approx(monte_carlo, rel=2e-3)


def test_midpoint_edges_are_shared():
    tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    edges, element_edges = p2.midpoint_edges(tets)
    assert len(edges) == 9  # 6 + 6 - 3 shared
    shared = set(element_edges[0]) & set(element_edges[1])
    assert len(shared) == 3
    for e, row in enumerate(element_edges):
        for k, index in enumerate(row):
            assert sorted(tets[e, p2.EDGES[k]]) == edges[index].tolist()
