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
from wcut.topology import connected_components



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
    solver.check()
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


# --- crack propagation (ShellFracture) ------------------------------------------------------

PRECUT_SIZE = 0.1  # m, side of the precut sheet the propagation tests pull apart


def _precut_tip(mesh) -> int:
    """The notch tip of a precut sheet: the boundary corner whose two boundary neighbours are
    the two copies of one point (the slit's last vertex, below and above)."""
    neighbours: dict[int, list[int]] = {}
    for a, b, _ in mesh.boundary_edges().tolist():
        neighbours.setdefault(a, []).append(b)
        neighbours.setdefault(b, []).append(a)
    X = mesh.vertices
    (tip,) = [v for v, n in neighbours.items() if len(n) == 2 and n[0] != n[1] and np.array_equal(X[n[0]], X[n[1]])]
    return tip



class _PulledPrecut:
    """A 6x6 precut sheet of 0.1 m (notch 0.03 m, tip at x = 1/30 m, y = 0.05 m) held at its
    bottom and top rows, the top row pulled up along y (mode I): pre-stretched by 3 % and
    pulled 0.5 mm more every 1 ms step, so the crack starts within a dozen steps. Each step
    runs the solver, then the fracture, and rebuilds the model after a change, checking the
    sheet (valid, area kept) after every change."""

    def __init__(self, variant="none", strength=2.0e5, max_cracks_per_step=1, cg_iterations=20):
        from wcut.mesh import precut_sheet
        from wcut.model import Model
        from wcut.solver import SolverCorotational

        self.solver_type, self.cg_iterations = SolverCorotational, cg_iterations
        mesh = precut_sheet(6, 6, (PRECUT_SIZE, PRECUT_SIZE), notch_length=0.03)
        self.rest_mesh, self.area, self.tip = mesh, mesh.area(), _precut_tip(mesh)
        X = mesh.vertices
        held = np.flatnonzero((X[:, 1] < 1e-9) | (X[:, 1] > PRECUT_SIZE - 1e-9))
        self.model = Model(mesh, density=1000.0, youngs_modulus=1.0e6, poisson_ratio=0.3, thickness=1.0e-3,
                           gravity=(0.0, 0.0, 0.0), fixed=held, rayleigh_mass=5.0)
        self.state, self.scratch = self.model.state(), self.model.state()
        q = X.copy()
        q[:, 1] *= 1.03
        self.state.particle_q.assign(q)
        self.solver = SolverCorotational(self.model, cg_iterations=cg_iterations)
        self.fracture = fracture.ShellFracture(mesh, strength, variant=variant, max_cracks_per_step=max_cracks_per_step)
        self.steps = 0
        self.pull = 0.0

    def step(self, pull: float | None = None):
        """One solver step with the top row at ``pull`` (m, default: the ramp), then one
        fracture step; returns the change (or None)."""
        from wcut.topology.shell import check_shell

        self.steps += 1
        self.pull = 0.03 * PRECUT_SIZE + 0.0005 * self.steps if pull is None else pull
        rest = self.fracture.mesh.vertices
        top = rest[:, 1] > PRECUT_SIZE - 1e-9
        q = self.state.particle_q.numpy()
        q[top, 1] = rest[top, 1] + self.pull
        self.state.particle_q.assign(q)
        self.solver.step(self.state, self.scratch, self.model.control(), 1.0e-3)
        self.state, self.scratch = self.scratch, self.state
        change = self.fracture.step(self.model, self.state)
        if change is not None:
            check_shell(self.fracture.mesh, self.area, 1e-9)
            self.model, self.state = self.model.rebuild(self.fracture.mesh, change, self.state)
            self.scratch = self.model.state()
            self.solver = self.solver_type(self.model, cg_iterations=self.cg_iterations)
        return change

    def separated(self) -> bool:
        """The crack has reached the right side of the sheet."""
        events = self.fracture.events
        return bool(events) and bool((events[-1].segments[:, 1, 0] > PRECUT_SIZE - 1e-9).any())


def test_shell_fracture_rejects_bad_arguments():
    from wcut.mesh import precut_sheet

    mesh = precut_sheet(2, 2, (0.1, 0.1), notch_length=0.05)
    with pytest.raises(FractureError, match="variant"):
        fracture.ShellFracture(mesh, 1.0e5, variant="snap")
    for strength in (0.0, -1.0, np.nan, np.inf, "1e5", None, True):
        with pytest.raises(FractureError, match="strength"):
            fracture.ShellFracture(mesh, strength)
    for count in (0, -1, 1.5, True, "2"):
        with pytest.raises(FractureError, match="max_cracks_per_step"):
            fracture.ShellFracture(mesh, 1.0e5, max_cracks_per_step=count)
    with pytest.raises(FractureError, match="smoothing"):
        fracture.ShellFracture(mesh, 1.0e5, smoothing="mean")
    with pytest.raises(FractureError, match="direction_smoothing"):
        fracture.ShellFracture(mesh, 1.0e5, direction_smoothing="mean")
    for quality in (-0.1, 1.0):
        with pytest.raises(FractureError, match="min_quality"):
            fracture.ShellFracture(mesh, 1.0e5, min_quality=quality)
    from wcut.mesh import beam

    for not_a_shell in (beam(1, 1, 1), mesh.vertices, None):
        with pytest.raises(FractureError, match="ShellMesh"):
            fracture.ShellFracture(not_a_shell, 1.0e5)
    assert set(fracture.VARIANTS) == {"none", "spatial", "material", "split"}


def test_shell_fracture_step_rejects_a_model_of_another_mesh():
    from wcut.mesh import precut_sheet

    frac = fracture.ShellFracture(precut_sheet(2, 2, (0.1, 0.1), notch_length=0.05), 1.0e5)
    other = _sheet_model(precut_sheet(4, 2, (0.1, 0.1), notch_length=0.05))
    with pytest.raises(FractureError, match="rebuild"):
        frac.step(other, other.state())


def test_shell_fracture_breaks_nothing_below_the_strength():
    run = _PulledPrecut(strength=1.0e9)
    for _ in range(5):
        assert run.step() is None
    assert run.fracture.events == [] and run.fracture.mesh is run.rest_mesh


@pytest.mark.parametrize("variant", fracture.VARIANTS)
def test_precut_sheet_under_tension_cracks_straight_from_the_notch_tip(variant):
    """Mode I (thesis figures 6.12 and 6.16): the crack starts at the notch tip and runs along
    y = 0.05 m, perpendicular to the load, one tip advancing edge by edge until the sheet is in
    two; the sheet stays valid with its area after every event (checked in the driver)."""
    run = _PulledPrecut(variant)
    tip_position = run.rest_mesh.vertices[run.tip].copy()
    for _ in range(60):
        run.step()
        if run.separated():
            break
    events = run.fracture.events
    assert run.separated(), f"{variant}: the crack did not cross the sheet in {run.steps} steps ({len(events)} events)"
    first = events[0]
    assert first.node == run.tip and first.initiation
    np.testing.assert_allclose(first.segments[0, 0], tip_position, rtol=0, atol=1e-12)
    assert all(not e.initiation for e in events[1:])  # one crack, grown from its tip
    cell = PRECUT_SIZE / 6
    for previous, event in zip(events, events[1:]):
        np.testing.assert_allclose(event.segments[0, 0], previous.segments[-1, 1], rtol=0, atol=1e-12)
    for event in events:
        assert event.sigma_plus > run.fracture.strength
        if variant != "split":
            assert not event.refined
        if variant == "none":
            assert not event.snapped
        d = event.segments[:, 1] - event.segments[:, 0]
        angle = np.degrees(np.arctan2(np.hypot(d[:, 1], d[:, 2]), np.abs(d[:, 0])))
        assert (angle < 10.0).all(), f"{variant}: segment at {angle.max():.1f} degrees from the x axis"
        assert (d[:, 0] > 0).all()  # forward, away from the notch
        assert np.abs(event.segments[:, :, 1] - 0.5 * PRECUT_SIZE).max() < 0.25 * cell
        assert abs(event.direction[0]) > np.cos(np.radians(10.0))
    if variant == "split":
        assert any(e.refined for e in events)
    assert connected_components(run.fracture.mesh).max() == 1  # two pieces
    assert run.model.particle_count == run.fracture.mesh.vertex_count


def test_a_cracked_sheet_keeps_running_finite_with_the_load_held():
    """After the crack has crossed the sheet (split variant: the most refined mesh), 1000 more
    steps with the pull held stay finite, the halves stay apart and come to rest."""
    run = _PulledPrecut("split")
    while not run.separated():
        run.step()
        assert run.steps < 60
    held = run.pull
    solver = run.solver  # the solver of the run (20 CG iterations)
    control = run.model.control()
    for _ in range(1000):
        solver.step(run.state, run.scratch, control, 1.0e-3)
        run.state, run.scratch = run.scratch, run.state
    solver.check()
    q, qd = run.state.particle_q.numpy(), run.state.particle_qd.numpy()
    assert np.isfinite(q).all() and np.isfinite(qd).all()
    rest = run.fracture.mesh.vertices
    assert np.abs(q - rest).max() < 1.1 * held  # the top half follows its held row, the bottom stays
    assert np.abs(qd).max() < 1e-2  # m/s: damped to rest, no growing oscillation
    # the crack faces: the nodes the crack duplicated (pairs of nodes at one rest point, right of
    # the notch tip) have been pulled apart, the copy above carried up with the top half
    tip_x = run.rest_mesh.vertices[run.tip, 0]
    _, first, inverse, counts = np.unique(rest, axis=0, return_index=True, return_inverse=True, return_counts=True)
    gaps = []
    for group in np.flatnonzero(counts == 2):
        a, b = np.flatnonzero(inverse.ravel() == group)
        if rest[a, 0] > tip_x + 1e-9:
            gaps.append(abs(q[a, 1] - q[b, 1]))
    assert len(gaps) >= 2 * len(run.fracture.events) and min(gaps) > 0.5 * held


@pytest.mark.parametrize("limit", [1, 2])
def test_max_cracks_per_step_bounds_the_events_of_a_step(limit):
    from collections import Counter

    run = _PulledPrecut("none", strength=5.0e4, max_cracks_per_step=limit)
    for _ in range(12):
        run.step()
    counts = Counter(e.step for e in run.fracture.events)
    assert counts and max(counts.values()) <= limit
    if limit > 1:
        assert max(counts.values()) == limit  # the bound is what limited them
    for step in counts:  # nodes advanced in one step are distinct
        nodes = [e.node for e in run.fracture.events if e.step == step]
        assert len(set(nodes)) == len(nodes)
    assert np.isfinite(run.state.particle_q.numpy()).all()


@pytest.mark.parametrize("variant", fracture.VARIANTS)
def test_l_shape_pulled_apart_cracks_first_at_the_reentrant_corner(variant):
    """The L-shape of figure 6.15: with its right arm pulled out and down (as in the stress
    test above, the load ramped over 10 steps), ShellFracture's first crack starts at the
    re-entrant corner and runs into the sheet."""
    from wcut.mesh import l_shape_sheet
    from wcut.solver import SolverCorotational
    from wcut.topology.shell import check_shell

    mesh = l_shape_sheet(4, 0.2)
    top = mesh.vertices_in_box((-1.0, 0.2 - 1e-9, -1.0), (1.0, 1.0, 1.0))
    right = mesh.vertices_in_box((0.2 - 1e-9, -1.0, -1.0), (1.0, 1.0, 1.0))
    model = _sheet_model(mesh, fixed=np.concatenate([top, right]), rayleigh_mass=50.0)
    state, scratch = model.state(), model.state()
    solver = SolverCorotational(model, cg_iterations=60)
    frac = fracture.ShellFracture(mesh, 2.0e4, variant=variant)
    for step in range(30):
        q = state.particle_q.numpy()
        q[right] = mesh.vertices[right] + np.array([0.004, -0.004, 0.0]) * min(1.0, (step + 1) / 10)
        state.particle_q.assign(q)
        solver.step(state, scratch, None, 0.05)
        state, scratch = scratch, state
        change = frac.step(model, state)
        if change is not None:
            break
    assert frac.events, "no crack in 30 steps"
    first = frac.events[0]
    assert np.allclose(mesh.vertices[first.node], [0.1, 0.1, 0.0], atol=1e-9)
    assert first.initiation and first.step == step
    np.testing.assert_allclose(first.segments[0, 0], [0.1, 0.1, 0.0], atol=1e-9)
    into = first.segments[0, 1] - first.segments[0, 0]
    assert into[0] < 0 and into[1] < 0  # into the L, away from the missing quadrant
    check_shell(frac.mesh, mesh.area(), 1e-9)
    model, state = model.rebuild(frac.mesh, change, state)
    SolverCorotational(model, cg_iterations=60).step(state, model.state(), None, 0.05)
