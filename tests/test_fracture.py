"""Stress recovery for fracture on quadratic shells (wcut/fracture.py, thesis 6.2)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wcut import fracture
from wcut.shell import GAUSS_POINTS, NODE_POINTS
from wcut.errors import WcutError
from wcut.fracture import FractureError, fracture_candidates, nodal_stress, principal_stresses



def _rotation(seed: int) -> np.ndarray:
    """A random proper rotation (3, 3)."""
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _in_plane(a: float, b: float, shear: float, e1: np.ndarray, e2: np.ndarray) -> np.ndarray:
    """Plane stress with components (a, b, shear) in the orthonormal in-plane axes (e1, e2)."""
    return a * np.outer(e1, e1) + b * np.outer(e2, e2) + shear * (np.outer(e1, e2) + np.outer(e2, e1))


def _parallel(u: np.ndarray, v: np.ndarray) -> bool:
    return abs(abs(np.dot(u, v)) - 1.0) < 1e-12


def _sheet(cells: int, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A flat square sheet of 2 cells^2 quadratic triangles in the plane rotation @ xy, plus
    one unused node at the end. Returns points (N, 3) and triangles (M, 6)."""
    side = 2 * cells + 1  # nodes per row of the fine grid that holds corners and edge nodes

    def node(i, j):
        return j * side + i

    triangles = []
    for cx in range(cells):
        for cy in range(cells):
            i, j = 2 * cx, 2 * cy
            triangles.append([node(i, j), node(i + 2, j), node(i + 2, j + 2),
                              node(i + 1, j), node(i + 2, j + 1), node(i + 1, j + 1)])
            triangles.append([node(i, j), node(i + 2, j + 2), node(i, j + 2),
                              node(i + 1, j + 1), node(i + 1, j + 2), node(i, j + 1)])
    grid = np.stack(np.meshgrid(np.arange(side), np.arange(side)), axis=-1).reshape(-1, 2) * 0.01
    flat = np.column_stack([grid, np.zeros(len(grid))])
    points = np.vstack([flat, [[5.0, 5.0, 5.0]]]) @ rotation.T
    return points, np.array(triangles)


# --- extrapolation --------------------------------------------------------------------------

def test_extrapolation_is_exact_for_linear_fields():
    rng = np.random.default_rng(0)
    corners = rng.normal(size=(7, 3, 3, 3))  # a random linear tensor field per element
    exact = np.einsum("nc,mc...->mn...", NODE_POINTS, corners)
    at_gauss = np.einsum("gc,mc...->mg...", GAUSS_POINTS, corners)
    np.testing.assert_allclose(fracture.extrapolate_to_nodes(at_gauss), exact, rtol=0, atol=1e-12)
    scalars = rng.normal(size=(4, 3))  # scalar fields: no trailing axes
    np.testing.assert_allclose(fracture.extrapolate_to_nodes(scalars @ GAUSS_POINTS.T),
                               scalars @ NODE_POINTS.T, rtol=0, atol=1e-12)


def test_extrapolation_keeps_a_constant_field_and_any_trailing_shape():
    value = np.arange(10.0).reshape(2, 5)
    gauss = np.broadcast_to(value, (3, 3, 2, 5))
    nodes = fracture.extrapolate_to_nodes(gauss)
    assert nodes.shape == (3, 6, 2, 5)
    np.testing.assert_allclose(nodes, np.broadcast_to(value, (3, 6, 2, 5)), atol=1e-12)


def test_gauss_rule_is_the_degree_two_rule():
    # The rule integrates quadratics exactly with weight 1/3: mean of L0^2 over a triangle is 1/6.
    np.testing.assert_allclose(GAUSS_POINTS.sum(axis=1), 1.0)
    np.testing.assert_allclose((GAUSS_POINTS[:, 0] ** 2).mean(), 1.0 / 6.0)
    np.testing.assert_allclose((GAUSS_POINTS[:, 0] * GAUSS_POINTS[:, 1]).mean(), 1.0 / 12.0)


# --- principal stresses ---------------------------------------------------------------------

@pytest.mark.parametrize("seed", [1, 2, 3])
def test_principal_stresses_of_analytic_states_in_a_tilted_plane(seed):
    e1, e2, n = _rotation(seed).T  # in-plane axes and normal: not the xy-plane
    s, t = 3.0e6, 1.0e6
    cases = [  # (stress, sigma_plus, sigma_minus, direction of sigma_plus)
        (_in_plane(s, 0, 0, e1, e2), s, 0.0, e1),  # uniaxial tension along e1
        (_in_plane(s, t, 0, e1, e2), s, t, e1),  # biaxial tension
        (_in_plane(t, s, 0, e1, e2), s, t, e2),
        (_in_plane(0, 0, t, e1, e2), t, -t, (e1 + e2) / np.sqrt(2)),  # pure shear: 45 degrees
        (_in_plane(0, 0, -t, e1, e2), t, -t, (e1 - e2) / np.sqrt(2)),
        (_in_plane(-s, 0, 0, e1, e2), 0.0, -s, e2),  # uniaxial compression: no tension
        (_in_plane(-s, -t, 0, e1, e2), -t, -s, e2),  # biaxial compression: sigma_plus < 0
    ]
    for stress, plus, minus, direction in cases:
        got_plus, got_minus, got_direction = fracture.principal_stresses(stress, n)
        np.testing.assert_allclose([got_plus, got_minus], [plus, minus], rtol=0, atol=1e-9 * s)
        assert _parallel(got_direction, direction)
        assert abs(np.dot(got_direction, n)) < 1e-12
        crack = fracture.crack_direction(got_direction, n)
        assert abs(np.dot(crack, got_direction)) < 1e-12 and abs(np.dot(crack, n)) < 1e-12
        np.testing.assert_allclose(np.linalg.norm(crack), 1.0)
    # Only tension breaks: every state but the two compressions exceeds a small strength.
    assert sorted(fracture.fracture_candidates([c[1] for c in cases], 1.0)) == [0, 1, 2, 3, 4]


def test_principal_stresses_are_invariant_and_direction_covariant_under_rotation():
    rng = np.random.default_rng(4)
    e1, e2, n = np.eye(3)
    stress = np.stack([_in_plane(*rng.normal(size=3) * 1e6, e1, e2) for _ in range(20)])
    plus, minus, direction = fracture.principal_stresses(stress, n)
    for seed in range(5, 10):
        r = _rotation(seed)
        rotated = fracture.principal_stresses(r @ stress @ r.T, r @ n)
        np.testing.assert_allclose(rotated[0], plus, rtol=1e-12, atol=1e-6)
        np.testing.assert_allclose(rotated[1], minus, rtol=1e-12, atol=1e-6)
        for mine, theirs in zip(direction, rotated[2]):
            assert _parallel(r @ mine, theirs)


def test_direction_sign_is_fixed_and_vectorised_over_leading_axes():
    rng = np.random.default_rng(11)
    normals = rng.normal(size=(4, 5, 3))
    stress = rng.normal(size=(4, 5, 3, 3))
    plus, minus, direction = fracture.principal_stresses(stress, normals)
    assert plus.shape == minus.shape == (4, 5) and direction.shape == (4, 5, 3)
    largest = np.take_along_axis(direction, np.abs(direction).argmax(axis=-1)[..., None], axis=-1)
    assert (largest > 0).all()
    np.testing.assert_allclose(np.linalg.norm(direction, axis=-1), 1.0)
    # The same call on one element gives the same answer (no hidden coupling between entries).
    single = fracture.principal_stresses(stress[2, 3], normals[2, 3])
    np.testing.assert_allclose(single[2], direction[2, 3])
    # One normal per element (M, 1, 3) broadcasts over its element nodes (M, 6, 3, 3).
    per_element = fracture.principal_stresses(rng.normal(size=(4, 6, 3, 3)), normals[:, :1])
    assert per_element[2].shape == (4, 6, 3)
    assert (np.abs(np.einsum("mki,mi->mk", per_element[2], normals[:, 0])) < 1e-12).all()


def test_principal_angle_agrees_with_eq_6_1_and_removes_the_shear():
    rng = np.random.default_rng(12)
    s22, s12 = rng.normal(size=(2, 50))
    s11 = s22 + rng.uniform(0.1, 2.0, size=50)  # s11 > s22: where eq 6.1's arctan is unambiguous
    theta = fracture.principal_angle(s11, s22, s12)
    # Eq 6.1 as printed gives the double angle (it omits the standard 1/2 of tan 2theta).
    np.testing.assert_allclose(2 * theta, np.arctan(2 * s12 / (s11 - s22)), atol=1e-12)
    c, s = np.cos(theta), np.sin(theta)
    rotated_shear = (s22 - s11) * s * c + s12 * (c * c - s * s)
    np.testing.assert_allclose(rotated_shear, 0.0, atol=1e-12)
    # In the xy-plane the basis is (x, y), so the direction is (cos theta, sin theta, 0).
    e1, e2, n = np.eye(3)
    _, _, direction = fracture.principal_stresses(
        np.stack([_in_plane(a, b, t, e1, e2) for a, b, t in zip(s11, s22, s12)]), n)
    for d, angle in zip(direction, theta):
        assert _parallel(d, np.array([np.cos(angle), np.sin(angle), 0.0]))


def test_tangent_basis_is_orthonormal_and_right_handed():
    normals = np.random.default_rng(13).normal(size=(200, 3))
    normals = np.vstack([normals, np.eye(3), -np.eye(3)])
    t1, t2 = fracture.tangent_basis(normals)
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    frame = np.stack([t1, t2, n], axis=-1)
    gram = frame.transpose(0, 2, 1) @ frame
    np.testing.assert_allclose(gram, np.broadcast_to(np.eye(3), gram.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(frame), 1.0, atol=1e-12)


finite = st.floats(-1e9, 1e9, allow_nan=False)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.lists(finite, min_size=6, max_size=6), st.lists(st.floats(-1, 1), min_size=3, max_size=3))
def test_principal_stress_invariants(components, normal):
    normal = np.array(normal)
    if np.linalg.norm(normal) < 0.1:
        normal = np.array([0.3, -0.2, 0.9])
    xx, yy, zz, xy, yz, zx = components
    stress = np.array([[xx, xy, zx], [xy, yy, yz], [zx, yz, zz]])
    plus, minus, direction = fracture.principal_stresses(stress, normal)
    n = normal / np.linalg.norm(normal)
    projected_trace = np.trace(stress) - n @ stress @ n
    scale = 1.0 + np.abs(stress).max()
    assert plus >= minus
    assert abs(plus + minus - projected_trace) <= 1e-12 * scale * 10
    s11, s22, s12 = fracture.tangent_components(stress, normal)
    assert abs(plus * minus - (s11 * s22 - s12 * s12)) <= 1e-12 * scale * scale * 10
    assert abs(np.linalg.norm(direction) - 1.0) < 1e-12 and abs(direction @ n) < 1e-12


# --- nodal smoothing ------------------------------------------------------------------------

def test_max_rule_picks_the_element_with_the_highest_sigma_plus_at_a_shared_node():
    # Two elements sharing the edge 1-2 (nodes 1, 2 and edge node 4); node 8 is used by none.
    triangles = np.array([[0, 1, 2, 3, 4, 5], [1, 6, 2, 7, 9, 4]])
    e1, e2, n = np.eye(3)
    tension = _in_plane(2.0, 0.0, 0.0, e1, e2)  # sigma_plus = 2
    big_but_compressive = _in_plane(-10.0, 1.5, 0.0, e1, e2)  # larger norm, sigma_plus = 1.5
    node_stress = np.empty((2, 6, 3, 3))
    node_stress[0], node_stress[1] = big_but_compressive, tension
    node_stress[0, 0] = _in_plane(0.0, 0.0, 0.0, e1, e2)
    normals = np.tile(n, (10, 1))
    smooth = fracture.smooth_max_principal(triangles, node_stress, normals, 10)
    for shared in (1, 2, 4):
        np.testing.assert_array_equal(smooth[shared], tension)
    np.testing.assert_array_equal(smooth[3], big_but_compressive)  # only element 0 there
    np.testing.assert_array_equal(smooth[0], 0.0)
    np.testing.assert_array_equal(smooth[8], 0.0)  # unused node: zero tensor
    # Both compressive: the least compressed (the "highest" sigma_plus, negative) wins.
    node_stress[1] = _in_plane(-5.0, -4.0, 0.0, e1, e2)
    smooth = fracture.smooth_max_principal(triangles, node_stress, normals, 10)
    np.testing.assert_array_equal(smooth[1], big_but_compressive)


def test_weighted_mean_of_equal_tensors_is_the_tensor_and_weights_matter():
    triangles = np.array([[0, 1, 2, 3, 4, 5], [1, 6, 2, 7, 9, 4]])
    a = _in_plane(1.0, 2.0, 3.0, *np.eye(3)[:2])
    node_stress = np.broadcast_to(a, (2, 6, 3, 3))
    smooth = fracture.smooth_weighted(triangles, node_stress, [1.0, 1.0], 10)
    np.testing.assert_allclose(smooth[[0, 1, 2, 3, 4, 5, 6, 7, 9]], np.broadcast_to(a, (9, 3, 3)), atol=1e-15)
    np.testing.assert_array_equal(smooth[8], 0.0)
    different = np.stack([np.broadcast_to(a, (6, 3, 3)), np.broadcast_to(3 * a, (6, 3, 3))])
    smooth = fracture.smooth_weighted(triangles, different, [1.0, 3.0], 10)
    np.testing.assert_allclose(smooth[4], 2.5 * a)  # (1 * a + 3 * 3a) / 4
    np.testing.assert_allclose(smooth[0], a)


@pytest.mark.parametrize("seed", [20, 21])
def test_affine_displacement_gives_its_constant_stress_at_every_node(seed):
    """An affine in-plane displacement u = G x has a constant strain and so a constant
    plane stress; extrapolation and both smoothing rules must return it at every node."""
    rotation = _rotation(seed)
    points, triangles = _sheet(3, rotation)
    e1, e2, n = rotation.T
    gradient = np.random.default_rng(seed).normal(size=(2, 2)) * 1e-3  # du/dx in (e1, e2)
    strain = 0.5 * (gradient + gradient.T)
    youngs, poisson = 2.0e5, 0.35
    plane = youngs / (1 - poisson**2) * ((1 - poisson) * strain + poisson * np.trace(strain) * np.eye(2))
    stress = _in_plane(plane[0, 0], plane[1, 1], plane[0, 1], e1, e2)
    gauss = np.broadcast_to(stress, (len(triangles), 3, 3, 3))
    node_stress = fracture.extrapolate_to_nodes(gauss)
    normals = np.tile(n, (len(points), 1))
    corners = points[triangles[:, :3]]
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    used = np.arange(len(points) - 1)
    for smooth in (fracture.smooth_max_principal(triangles, node_stress, normals, len(points)),
                   fracture.smooth_weighted(triangles, node_stress, areas, len(points))):
        np.testing.assert_allclose(smooth[used], np.broadcast_to(stress, (len(used), 3, 3)),
                                   rtol=0, atol=1e-12 * np.abs(stress).max())
        np.testing.assert_array_equal(smooth[-1], 0.0)


# --- criterion and input errors -------------------------------------------------------------

def test_fracture_candidates_are_sorted_by_decreasing_stress():
    sigma = np.array([1.0, 5.0, -3.0, 2.5, 5.0, 2.0])
    np.testing.assert_array_equal(fracture.fracture_candidates(sigma, 2.0), [1, 4, 3])
    assert fracture.fracture_candidates(sigma, 10.0).size == 0
    assert fracture.fracture_candidates(sigma, 2.0).dtype == np.int64


@pytest.mark.parametrize("strength", [0.0, -1.0, np.inf, np.nan, "1e6", None, True])
def test_fracture_candidates_reject_a_bad_strength(strength):
    with pytest.raises(FractureError, match="strength"):
        fracture.fracture_candidates([1.0, 2.0], strength)


def test_bad_input_names_the_argument_and_the_first_bad_index():
    assert issubclass(FractureError, WcutError)
    gauss = np.zeros((4, 3, 3, 3))
    gauss[2, 1, 0, 2] = np.nan
    with pytest.raises(FractureError, match=r"gauss_values\[2, 1, 0, 2\]"):
        fracture.extrapolate_to_nodes(gauss)
    with pytest.raises(FractureError, match="gauss_values has shape"):
        fracture.extrapolate_to_nodes(np.zeros((4, 2, 3, 3)))
    with pytest.raises(FractureError, match=r"normal\[1\] has zero length"):
        fracture.principal_stresses(np.zeros((2, 3, 3)), [[0, 0, 1], [0, 0, 0]])
    with pytest.raises(FractureError, match="stress has shape"):
        fracture.principal_stresses(np.zeros((2, 2)), [0, 0, 1])
    with pytest.raises(FractureError, match="do not broadcast"):
        fracture.principal_stresses(np.zeros((2, 3, 3)), np.ones((3, 3)))
    with pytest.raises(FractureError, match="parallel to the normal"):
        fracture.crack_direction([0, 0, 2.0], [0, 0, 1.0])
    triangles = np.array([[0, 1, 2, 3, 4, 5], [1, 6, 2, 7, 10, 4]])
    stress, normals = np.zeros((2, 6, 3, 3)), np.tile([0.0, 0.0, 1.0], (10, 1))
    with pytest.raises(FractureError, match=r"triangles\[1, 4\] = 10"):
        fracture.smooth_max_principal(triangles, stress, normals, 10)
    with pytest.raises(FractureError, match=r"triangles\[0\].*repeats"):
        fracture.smooth_weighted([[0, 1, 1, 3, 4, 5]], stress[:1], [1.0], 10)
    with pytest.raises(FractureError, match="node_stress has shape"):
        fracture.smooth_weighted(triangles[:1], stress, [1.0], 10)
    with pytest.raises(FractureError, match=r"weights\[1\] = 0"):
        fracture.smooth_weighted([[0, 1, 2, 3, 4, 5], [1, 6, 2, 7, 9, 4]], stress, [1.0, 0.0], 10)
    with pytest.raises(FractureError, match="normals has shape"):
        fracture.smooth_max_principal(triangles[:1], stress[:1], normals[:5], 10)
    normals[7] = 0.0
    with pytest.raises(FractureError, match=r"normals\[7\] has zero length"):
        fracture.smooth_max_principal(triangles[:1], stress[:1], normals, 10)
    with pytest.raises(FractureError, match=r"sigma_plus\[1\] is inf"):
        fracture.fracture_candidates([0.0, np.inf], 1.0)
    with pytest.raises(FractureError, match="sigma_plus has shape"):
        fracture.fracture_candidates(np.zeros((2, 3)), 1.0)


# --- from a simulation ----------------------------------------------------------------------

def _sheet_model(mesh, **kwargs):
    from wcut.model import Model

    return Model(mesh, youngs_modulus=1.0e6, poisson_ratio=0.3, thickness=1.0e-3, gravity=(0.0, 0.0, 0.0), **kwargs)


@pytest.mark.parametrize("rule", ["max", "weighted"])
def test_nodal_stress_of_an_affine_stretch_is_exact_at_every_node(rule):
    from wcut.mesh import ShellMesh, rectangle_sheet
    from wcut.shell import plane_stress_lame

    flat = rectangle_sheet(3, 2, (0.3, 0.2))
    tilt = np.linalg.qr(np.array([[1.0, 0.2, 0.3], [-0.4, 1.0, 0.1], [0.2, 0.5, 1.0]]))[0]
    model = _sheet_model(ShellMesh(flat.vertices @ tilt.T, flat.triangles))
    strain = np.array([[0.01, 0.004], [0.004, 0.002]])
    stretch = np.eye(3)
    stretch[:2, :2] += strain
    state = model.state()
    state.particle_q.assign((flat.vertices @ stretch.T) @ tilt.T)
    stress, normals = nodal_stress(model, state, rule)
    mu, lam = plane_stress_lame(1.0e6, 0.3)
    plane = 2 * mu * strain + lam * np.trace(strain) * np.eye(2)
    assert np.abs(stress - tilt[:, :2] @ plane @ tilt[:, :2].T).max() < 5e-4 * np.abs(plane).max()  # float32
    sigma_plus, sigma_minus, _ = principal_stresses(stress, normals)
    assert np.allclose(sigma_plus, np.linalg.eigvalsh(plane)[1], rtol=5e-4)


def test_l_shape_pulled_apart_breaks_first_at_the_reentrant_corner():
    """The L-shape of figure 6.12 with its arms pulled apart: the largest smoothed maximal
    principal stress (thesis rule) is at the re-entrant corner, where a crack must start."""
    from wcut.mesh import l_shape_sheet
    from wcut.solver import SolverCorotational

    mesh = l_shape_sheet(4, 0.2)
    top = mesh.vertices_in_box((-1.0, 0.2 - 1e-9, -1.0), (1.0, 1.0, 1.0))
    right = mesh.vertices_in_box((0.2 - 1e-9, -1.0, -1.0), (1.0, 1.0, 1.0))
    model = _sheet_model(mesh, fixed=np.concatenate([top, right]), rayleigh_mass=50.0)
    state, scratch = model.state(), model.state()
    q = mesh.vertices.copy()
    q[right] += np.array([0.004, -0.004, 0.0])  # the right arm pulled out and down
    state.particle_q.assign(q)
    solver = SolverCorotational(model, cg_iterations=200, cg_tolerance=1e-7)
    for _ in range(30):
        solver.step(state, scratch, None, 0.05)
        state, scratch = scratch, state
    solver.check_finite()
    stress, normals = nodal_stress(model, state, "max")
    sigma_plus, _, _ = principal_stresses(stress, normals)
    first = fracture_candidates(sigma_plus, 0.5 * sigma_plus.max())[0]
    assert np.allclose(mesh.vertices[first], [0.1, 0.1, 0.0], atol=1e-9)


def test_nodal_stress_rejects_an_unknown_rule():
    from wcut.mesh import rectangle_sheet

    model = _sheet_model(rectangle_sheet(1, 1, (0.1, 0.1)))
    with pytest.raises(FractureError, match="rule"):
        nodal_stress(model, model.state(), "mean")


def test_a_stretched_sheet_exports_to_usd_coloured_by_its_maximal_principal_stress(tmp_path):
    from wcut.mesh import precut_sheet
    from wcut.scene import render_surface
    from wcut.usd import UsdAnimationWriter, stress_colors, validate_usd

    mesh = precut_sheet(8, 4, (0.2, 0.1), notch_length=0.05)
    model = _sheet_model(mesh)
    state = model.state()
    surface = render_surface(mesh, 2)
    path = tmp_path / "sheet.usda"
    with UsdAnimationWriter(path, fps=30) as writer:
        for frame, pull in enumerate((0.0, 0.01)):
            state.particle_q.assign(mesh.vertices * np.array([1.0, 1.0 + pull, 1.0]))
            stress, normals = nodal_stress(model, state)
            sigma_plus = principal_stresses(stress, normals)[0]
            writer.write_frame("sheet", frame, surface.points(state.particle_q.numpy()), surface.triangles,
                               stress_colors(surface.points(sigma_plus), vmin=0.0, vmax=2e4))
    assert validate_usd(path) == []
    assert len(surface.triangles) == 16 * mesh.triangle_count
