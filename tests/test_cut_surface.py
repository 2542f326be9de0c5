"""Tests of wcut.cut.surface: planes, polygons, triangulated and swept-blade cut surfaces."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wcut.cut.surface import Plane, Polygon, SurfaceError, SweptBlade, TriangleSurface, strip
from wcut.errors import WcutError

TOL = 1e-9


# ---------------------------------------------------------------- independent references


def ref_point_triangle(p, a, b, c) -> float:
    """Distance from p to triangle abc (Ericson, Real-Time Collision Detection, 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ab @ ap, ac @ ap
    if d1 <= 0 and d2 <= 0:
        return float(np.linalg.norm(p - a))
    bp = p - b
    d3, d4 = ab @ bp, ac @ bp
    if d3 >= 0 and d4 <= d3:
        return float(np.linalg.norm(p - b))
    vc = d1 * d4 - d3 * d2
    if vc <= 0 and d1 >= 0 and d3 <= 0:
        return float(np.linalg.norm(p - (a + d1 / (d1 - d3) * ab)))
    cp = p - c
    d5, d6 = ab @ cp, ac @ cp
    if d6 >= 0 and d5 <= d6:
        return float(np.linalg.norm(p - c))
    vb = d5 * d2 - d1 * d6
    if vb <= 0 and d2 >= 0 and d6 <= 0:
        return float(np.linalg.norm(p - (a + d2 / (d2 - d6) * ac)))
    va = d3 * d6 - d5 * d4
    if va <= 0 and d4 - d3 >= 0 and d5 - d6 >= 0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return float(np.linalg.norm(p - (b + w * (c - b))))
    v, w = vb / (va + vb + vc), vc / (va + vb + vc)
    return float(np.linalg.norm(p - (a + v * ab + w * ac)))


def ref_distance(points, corners) -> np.ndarray:
    return np.array([min(ref_point_triangle(p, *tri) for tri in corners) for p in points])


def ref_crossing(a, b, corners, tol) -> float:
    """First Möller–Trumbore hit of segment a->b with triangles (nan if none or an end is on S)."""
    v0, e1, e2 = corners[:, 0], corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    d = b - a
    h = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, h)
    s = a - v0
    q = np.cross(s, e1)
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v, t = np.einsum("ij,ij->i", s, h) / det, q @ d / det, np.einsum("ij,ij->i", e2, q) / det
    n = np.cross(e1, e2)
    n /= np.linalg.norm(n, axis=1)[:, None]
    strict = (np.abs(np.einsum("ij,ij->i", a - v0, n)) > tol) & (np.abs(np.einsum("ij,ij->i", b - v0, n)) > tol)
    hit = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & (t < 1) & strict
    if not hit.any() or min(ref_distance([a, b], corners)) <= tol:
        return np.nan
    return float(t[hit].min())


def bumpy_grid(cells=6, size=1.0, seed=0):
    """A (cells x cells) grid over [0, size]^2 with random heights: an open surface."""
    rng = np.random.default_rng(seed)
    g = np.linspace(0.0, size, cells + 1)
    x, y = np.meshgrid(g, g, indexing="ij")
    vertices = np.c_[x.ravel(), y.ravel(), 0.15 * size * rng.standard_normal(x.size)]
    r, c = np.divmod(np.arange(cells * cells), cells)
    v0 = r * (cells + 1) + c
    tris = np.r_[np.c_[v0, v0 + cells + 1, v0 + cells + 2], np.c_[v0, v0 + cells + 2, v0 + 1]]
    return TriangleSurface(vertices, tris)


def vertical(xy, z0=-1.0, z1=1.0):
    xy = np.atleast_2d(np.asarray(xy, dtype=float))
    return np.c_[xy, np.full(len(xy), z0)], np.c_[xy, np.full(len(xy), z1)]


# ---------------------------------------------------------------- plane


def test_plane_crossing_parameter_is_exact():
    rng = np.random.default_rng(1)
    point, normal = np.array([0.1, -0.2, 0.3]), np.array([1.0, 2.0, -0.5])
    plane = Plane(point, normal)
    a, b = rng.uniform(-1, 1, (500, 3)), rng.uniform(-1, 1, (500, 3))
    n = normal / np.linalg.norm(normal)
    da, db = (a - point) @ n, (b - point) @ n
    expected = np.where(da * db < 0, da / (da - db), np.nan)
    t, nrm = plane.crossings(a, b, TOL)
    np.testing.assert_array_equal(np.isnan(t), np.isnan(expected))
    np.testing.assert_allclose(t, expected, rtol=0, atol=1e-14)
    hit = ~np.isnan(t)
    assert 100 < hit.sum() < 400
    np.testing.assert_allclose(nrm[hit], np.broadcast_to(n, (hit.sum(), 3)), atol=1e-15)
    assert np.isnan(nrm[~hit]).all()
    p = a + t[:, None] * (b - a)
    assert np.abs(plane.signed_distance(p[hit])).max() < 1e-14
    assert np.all((t[hit] > 0) & (t[hit] < 1))


def test_plane_endpoints_within_tol_do_not_cross():
    plane, tol = Plane([0, 0, 0], [0, 0, 1]), 1e-6
    a = np.array([[0, 0, 0.5e-6], [0, 0, -0.9e-6], [0, 0, 1.5e-6], [0, 0, 0.0]])
    b = np.array([[0, 0, -1.0], [1, 0, 1.0], [0, 0, -1.0], [0, 0, 1.0]])
    t, _ = plane.crossings(a, b, tol)
    assert np.isnan(t[:2]).all() and np.isnan(t[3])
    assert t[2] == pytest.approx(1.5e-6 / (1.0 + 1.5e-6), rel=1e-12)


def test_plane_segment_in_plane_does_not_cross():
    plane = Plane([0, 0, 1], [0, 0, 1])
    t, n = plane.crossings([[0, 0, 1], [-1, 2, 1]], [[1, 1, 1], [3, 0, 1]], 0.0)
    assert np.isnan(t).all() and np.isnan(n).all()


def test_plane_normal_is_unit_and_keeps_its_orientation():
    a, b = np.array([[0.0, 0, -1], [0.0, 0, 1]]), np.array([[0.0, 0, 1], [0.0, 0, -1]])
    for sign in (1.0, -1.0):
        t, n = Plane([0, 0, 0], [0, 0, 2 * sign]).crossings(a, b, TOL)
        np.testing.assert_allclose(t, [0.5, 0.5])
        np.testing.assert_allclose(n, [[0, 0, sign]] * 2)  # the surface's normal, whatever the direction
    assert Plane([0, 0, 0], [0, 0, 1]).extension_crossings(a, b, TOL)[0] == pytest.approx([0.5, 0.5])
    lo, hi = Plane([0, 0, 0], [0, 0, 1]).bounds()
    assert np.all(lo == -np.inf) and np.all(hi == np.inf)


def test_plane_distance_and_limit():
    plane = Plane([0, 0, 1], [0, 0, -3])
    np.testing.assert_allclose(plane.signed_distance([[5, 5, 0], [0, 0, 3]]), [1, -2])
    np.testing.assert_allclose(plane.distance([[5, 5, 0], [0, 0, 3]]), [1, 2])
    np.testing.assert_array_equal(plane.distance([[5, 5, 0], [0, 0, 3]], limit=1.5), [1, np.inf])


@pytest.mark.parametrize(
    "make, words",
    [
        (lambda: Plane([0, 0, 0], [0, 0, 0]), "zero"),
        (lambda: Plane([0, np.nan, 0], [0, 0, 1]), "NaN"),
        (lambda: Plane([0, 0], [0, 0, 1]), "shape"),
        (lambda: Plane([0, 0, 0], [0, 0, 1]).crossings([[0, 0, 0]], [[0, 0, 1], [0, 0, 2]], TOL), "shape"),
        (lambda: Plane([0, 0, 0], [0, 0, 1]).crossings([[0, 0, np.inf]], [[0, 0, 1]], TOL), "NaN"),
        (lambda: Plane([0, 0, 0], [0, 0, 1]).crossings([[0, 0, 0]], [[0, 0, 1]], -1.0), "tolerance"),
        (lambda: TriangleSurface(np.zeros((3, 3)), np.zeros((0, 3), dtype=int)), "empty"),
        (lambda: TriangleSurface(np.eye(3), [[0, 1, 3]]), "out of range"),
    ],
)
def test_bad_input_raises_surface_error(make, words):
    with pytest.raises(SurfaceError, match=words):
        make()
    assert issubclass(SurfaceError, WcutError)


# ---------------------------------------------------------------- polygon


SQUARE = [[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]
L_SHAPE = [[0, 0, 0], [2, 0, 0], [2, 1, 0], [1, 1, 0], [1, 2, 0], [0, 2, 0]]


def triangle_areas(surface):
    v = surface.vertices[surface.triangles]
    return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)


def test_polygon_bounded_but_extension_is_its_plane():
    square = Polygon(SQUARE)
    a, b = vertical([[0.2, 0.3], [2.0, 0.0]], -1.0, 3.0)
    t, n = square.crossings(a, b, TOL)
    assert t[0] == pytest.approx(0.25) and np.isnan(t[1])
    np.testing.assert_allclose(n[0], [0, 0, 1])
    te, ne = square.extension_crossings(a, b, TOL)
    np.testing.assert_allclose(te, [0.25, 0.25])
    np.testing.assert_allclose(ne, [[0, 0, 1]] * 2)
    lo, hi = square.bounds()
    np.testing.assert_allclose(lo, [-1, -1, 0]) and np.testing.assert_allclose(hi, [1, 1, 0])


def test_polygon_orientation_follows_vertex_order():
    t, n = Polygon(SQUARE[::-1]).crossings(*vertical([[0, 0]]), TOL)
    assert t[0] == pytest.approx(0.5)
    np.testing.assert_allclose(n[0], [0, 0, -1])


def test_non_convex_polygon_notch_is_not_crossed():
    shape = Polygon(L_SHAPE)
    assert triangle_areas(shape).sum() == pytest.approx(3.0)
    t, _ = shape.crossings(*vertical([[1.5, 1.5], [0.5, 0.5], [1.5, 0.5], [0.5, 1.5], [1.0, 1.0]]), TOL)
    assert np.isnan(t[0])
    np.testing.assert_allclose(t[1:], 0.5)  # (1, 1) is the reflex corner: a vertex of the polygon
    assert not np.isnan(shape.extension_crossings(*vertical([[1.5, 1.5]]), TOL)[0][0])


def test_comb_polygon_triangulates_to_its_area():
    # A comb in a tilted plane: many reflex corners, plus a collinear vertex on the base.
    xy = [(0, 0), (2.5, 0), (5, 0), (5, 3), (4, 3), (4, 1), (3, 1), (3, 3), (2, 3), (2, 1), (1, 1), (1, 3), (0, 3)]
    rot = np.linalg.qr(np.random.default_rng(3).standard_normal((3, 3)))[0]
    comb = Polygon(np.c_[np.array(xy, float), np.zeros(len(xy))] @ rot.T + [0.3, -0.2, 0.1])
    assert triangle_areas(comb).sum() == pytest.approx(5 * 3 - 2 * 2, rel=1e-12)
    np.testing.assert_allclose(np.abs(comb.normals @ rot[:, 2]), 1.0, atol=1e-12)


@pytest.mark.parametrize(
    "vertices, words",
    [
        ([[0, 0, 0], [1, 0, 0], [1, 1, 1e-3], [0, 1, 0]], "not planar"),
        ([[0, 0, 0], [1, 0, 0], [2, 0, 0]], "zero area"),
        ([[0, 0, 0], [1, 0, 0]], "at least 3"),
        ([[0, 0, 0], [3, 2, 0], [3, 0, 0], [0, 1, 0]], "self-intersecting: edges 0 and 2"),
    ],
)
def test_bad_polygon_raises(vertices, words):
    with pytest.raises(SurfaceError, match=words):
        Polygon(vertices)


# ---------------------------------------------------------------- triangulated surface


def test_hit_through_shared_edge_is_reported_once():
    square = TriangleSurface([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    s = np.linspace(0.01, 0.99, 99)
    t, n = square.crossings(*vertical(np.c_[s, s]), TOL)  # all through the shared diagonal
    np.testing.assert_allclose(t, 0.5)
    np.testing.assert_allclose(n, np.tile([0, 0, 1], (99, 1)))


def test_hit_through_shared_vertex_is_reported_once():
    # A non-planar fan of 6 triangles around an apex at the origin, and a slanted segment through it.
    angles = np.linspace(0, 2 * np.pi, 7)[:-1]
    rim = np.c_[np.cos(angles), np.sin(angles), -0.3 * np.ones(6)]
    fan = TriangleSurface(np.r_[[[0, 0, 0]], rim], [[0, 1 + k, 1 + (k + 1) % 6] for k in range(6)])
    a = np.array([[0.1, 0.05, -1.0], [-0.2, 0.1, -1.0]])
    t, n = fan.crossings(a, -a, TOL)
    np.testing.assert_allclose(t, 0.5)
    assert np.all(n[:, 2] > 0)


def folded():
    """A 'C' folded surface: bottom sheet z=0, wall x=2, top sheet z=1 (x, y in [0, 2] x [0, 1])."""
    v = [[0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0], [2, 0, 1], [2, 1, 1], [0, 0, 1], [0, 1, 1]]
    return TriangleSurface(v, [[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2], [4, 6, 7], [4, 7, 5]])


def test_first_crossing_of_a_folded_surface():
    fold = folded()
    a, b = np.array([[1, 0.5, -1.0]]), np.array([[1, 0.5, 2.0]])
    t, n = fold.crossings(a, b, TOL)
    assert t[0] == pytest.approx(1 / 3)
    np.testing.assert_allclose(n[0], [0, 0, 1])  # bottom sheet
    t, n = fold.crossings(b, a, TOL)
    assert t[0] == pytest.approx(1 / 3)
    np.testing.assert_allclose(n[0], [0, 0, -1])  # top sheet, (4, 6, 7) winds the other way


def test_endpoint_on_the_surface_never_crosses():
    fold = folded()
    # Starts on the bottom sheet, strictly crosses the top sheet: still no crossing (contract).
    t, _ = fold.crossings([[1, 0.5, 0.0], [1, 0.5, 0.5]], [[1, 0.5, 2.0], [1, 0.5, 2.0]], 1e-6)
    assert np.isnan(t[0]) and t[1] == pytest.approx(1 / 3)
    # Lying in the surface does not cross either.
    assert np.isnan(fold.crossings([[0.5, 0.5, 0]], [[1.5, 0.5, 0]], 1e-6)[0][0])


def test_crossings_match_brute_force_reference():
    rng = np.random.default_rng(7)
    grid = bumpy_grid(5, seed=2)
    a = rng.uniform([-0.1, -0.1, -0.4], [1.1, 1.1, 0.4], (400, 3))
    b = a + 0.3 * rng.standard_normal((400, 3))
    t, n = grid.crossings(a, b, 1e-7)
    corners = grid.vertices[grid.triangles]
    expected = np.array([ref_crossing(a[i], b[i], corners, 1e-7) for i in range(len(a))])
    np.testing.assert_array_equal(np.isnan(t), np.isnan(expected))
    np.testing.assert_allclose(t, expected, atol=1e-12)
    assert (~np.isnan(t)).sum() > 50
    np.testing.assert_allclose(np.linalg.norm(n[~np.isnan(t)], axis=1), 1.0)


def test_distance_matches_brute_force_reference():
    rng = np.random.default_rng(5)
    grid = bumpy_grid(4, seed=1)
    points = rng.uniform(-0.5, 1.5, (150, 3))
    expected = ref_distance(points, grid.vertices[grid.triangles])
    np.testing.assert_allclose(grid.distance(points), expected, rtol=1e-12, atol=1e-14)
    d, j = grid.nearest(points)
    corners = grid.vertices[grid.triangles[j]]
    np.testing.assert_allclose([ref_point_triangle(p, *c) for p, c in zip(points, corners)], d, atol=1e-14)
    limited = grid.distance(points, limit=0.2)
    np.testing.assert_array_equal(limited, np.where(expected <= 0.2, limited, np.inf))
    np.testing.assert_allclose(limited[expected <= 0.2], expected[expected <= 0.2], atol=1e-14)


def test_a_limited_distance_is_the_nearest_search_s_distance():
    """``distance`` with a finite limit (compiled, the triangles whose boxes come within it)
    gives the nearest search's distances up to rounding, near, on and far from the surface,
    and inf beyond the limit."""
    rng = np.random.default_rng(12)
    grid = bumpy_grid(6, seed=2)
    points = np.concatenate([rng.uniform(-0.5, 1.5, (400, 3)), grid.vertices[:20],
                             grid.vertices[:20] + rng.normal(0.0, 1e-4, (20, 3))])
    for limit in (1e-6, 1e-3, 0.05, 0.3):
        limited, searched = grid.distance(points, limit), grid.nearest(points, limit)[0]
        np.testing.assert_array_equal(np.isinf(limited), np.isinf(searched))
        np.testing.assert_allclose(limited, searched, rtol=0.0, atol=1e-15)
        assert np.isfinite(limited).any() and np.isinf(limited).any()


def test_a_query_of_few_pairs_measures_them_all_and_finds_what_the_search_finds(monkeypatch):
    import wcut.cut.surface as surface_module

    rng = np.random.default_rng(11)
    grid = bumpy_grid(4, seed=1)
    points = np.concatenate([rng.uniform(-0.5, 1.5, (6, 3)), grid.vertices[:6]])  # on shared vertices: ties
    assert len(grid) <= surface_module._ALL_PAIRS
    few = [grid.nearest(p[None], limit) for p in points for limit in (np.inf, 0.2)]
    monkeypatch.setattr(surface_module, "_ALL_PAIRS", 0)  # always the compiled search
    searched = [grid.nearest(p[None], limit) for p in points for limit in (np.inf, 0.2)]
    for (d, j), (d_ref, j_ref) in zip(few, searched):
        np.testing.assert_allclose(d, d_ref, rtol=0.0, atol=1e-15)  # up to rounding
        np.testing.assert_array_equal(j, j_ref)  # the same triangle among equally near ones
    assert any(np.isinf(d[0]) for d, _ in few) and any(np.isfinite(d[0]) for d, _ in few)


def test_extension_uses_the_plane_of_the_nearest_triangle():
    fold = folded()
    # Beyond the free edge x=0 of the bottom sheet, the extension is the plane z=0 ...
    t, n = fold.extension_crossings([[-0.5, 0.5, -0.2]], [[-0.5, 0.5, 0.2]], TOL)
    assert t[0] == pytest.approx(0.5) and fold.crossings([[-0.5, 0.5, -0.2]], [[-0.5, 0.5, 0.2]], TOL)[0][0] != 0.5
    np.testing.assert_allclose(n[0], [0, 0, 1])
    # ... and beyond the wall it is the plane x=2.
    t, n = fold.extension_crossings([[1.8, 0.5, 3.0]], [[2.2, 0.5, 3.0]], TOL)
    assert t[0] == pytest.approx(0.5)
    np.testing.assert_allclose(np.abs(n[0]), [1, 0, 0])


OBJ = """# a unit square as one quad, plus a triangle with slashes and negative indices
o square
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0   # trailing comment
vt 0 0
vn 0 0 1
f 1/1/1 2/1/1 3/1/1 4/1/1
v 0 0 1
f -5//1 -4//1 -1//1
"""


def test_obj_round_trip(tmp_path):
    path = tmp_path / "surface.obj"
    path.write_text(OBJ)
    surface = TriangleSurface.load(path)
    np.testing.assert_array_equal(surface.triangles, [[0, 1, 2], [0, 2, 3], [0, 1, 4]])
    np.testing.assert_array_equal(surface.vertices[4], [0, 0, 1])
    surface.save(tmp_path / "again.obj")
    again = TriangleSurface.load(tmp_path / "again.obj")
    np.testing.assert_array_equal(again.vertices, surface.vertices)
    np.testing.assert_array_equal(again.triangles, surface.triangles)
    grid = bumpy_grid(3)
    grid.save(str(tmp_path / "grid.obj"))
    np.testing.assert_array_equal(TriangleSurface.load(str(tmp_path / "grid.obj")).vertices, grid.vertices)


@pytest.mark.parametrize(
    "text, words",
    [
        ("v 0 0 0\nv 1 0 0\nv 0 x 0\nf 1 2 3\n", r":3: bad vertex"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2 4\n", r":5: face vertex '4' out of range"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", r":4: a face needs at least 3"),
        ("v 0 0 0\nv 1 0 0\nf 1 2 -3\n", r":3: face vertex '-3'"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 a 3\n", r":4: bad face vertex 'a'"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n", r"triangle 1 is degenerate"),
        ("v 0 0 0\n# nothing else\n", r"empty surface"),
    ],
)
def test_bad_obj_raises_naming_file_and_line(tmp_path, text, words):
    path = tmp_path / "bad.obj"
    path.write_text(text)
    with pytest.raises(SurfaceError, match=words) as info:
        TriangleSurface.load(path)
    assert str(path) in str(info.value)


def test_missing_or_unreadable_obj_names_the_path(tmp_path):
    missing = tmp_path / "nowhere" / "cut.obj"
    with pytest.raises(SurfaceError, match="does not exist") as info:
        TriangleSurface.load(missing)
    assert str(missing) in str(info.value)
    (tmp_path / "binary.obj").write_bytes(b"\xff\xfe\x00v 1 2 3")
    with pytest.raises(SurfaceError, match="cannot be read"):
        TriangleSurface.load(tmp_path / "binary.obj")
    with pytest.raises(SurfaceError, match="cannot be read"):
        TriangleSurface.load(tmp_path)


# ---------------------------------------------------------------- swept blade


def moving_blade(frames=6):
    """A blade along z (length 0.1) moved along x by 0.01 per frame."""
    tip = np.c_[0.01 * np.arange(frames), np.zeros(frames), np.zeros(frames)]
    return SweptBlade.from_tip_path(tip, [0, 0, 0.1])


def test_swept_blade_triangle_counts():
    blade = moving_blade(6)
    assert blade.frame_count == 6
    for k in range(1, 6):
        assert len(blade.surface_until(k)) == 2 * k
        assert len(blade.increment(k)) == 2
    area = triangle_areas(blade.surface_until(5)).sum()
    assert area == pytest.approx(0.05 * 0.1)


def test_swept_blade_increments_are_local():
    blade = moving_blade(4)
    a, b = np.array([[0.005, -0.01, 0.05]]), np.array([[0.005, 0.01, 0.05]])  # crosses frame 1's sweep
    assert blade.surface_until(2).crossings(a, b, TOL)[0][0] == pytest.approx(0.5)
    t, n = blade.increment(1).crossings(a, b, TOL)
    assert t[0] == pytest.approx(0.5)
    np.testing.assert_allclose(n[0], [0, 1, 0])  # blade direction (z) x motion (x)
    assert np.isnan(blade.increment(2).crossings(a, b, TOL)[0][0])


def test_swept_blade_that_stops_or_pivots():
    tip = np.array([[0, 0, 0], [0.01, 0, 0], [0.01, 0, 0], [0.02, 0, 0]], float)
    blade = SweptBlade.from_tip_path(tip, [0, 0, 0.1])
    assert blade.increment(2) is None
    assert len(blade.surface_until(3)) == 4
    assert SweptBlade(np.zeros((3, 2, 3)) + [[0, 0, 0], [0, 0, 1]]).surface_until(2) is None
    pivot = SweptBlade([[[0, 0, 0], [0, 0, 1]], [[0, 0, 0], [0, 1, 1]]])  # turns about its tip
    assert len(pivot.increment(1)) == 1
    with pytest.raises(SurfaceError, match="out of range"):
        blade.increment(4)
    with pytest.raises(SurfaceError, match="out of range"):
        blade.surface_until(0)
    with pytest.raises(SurfaceError, match="zero vector"):
        SweptBlade.from_tip_path(tip, [0, 0, 0])
    with pytest.raises(SurfaceError, match="shape"):
        SweptBlade(np.zeros((3, 3)))


def test_curved_sweep_of_slivers_matches_brute_force():
    # A slow curved sweep: long thin triangles, which the broad phase cuts into pieces.
    frames = 40
    s = np.linspace(0, 1, frames)
    tip = np.c_[0.12 * s, 0.02 * np.sin(4 * s), -0.06 + 0.01 * s]
    surface = SweptBlade.from_tip_path(tip, [0.01, 0.03, 0.12]).surface_until(frames - 1)
    rng = np.random.default_rng(11)
    mid = surface.vertices[surface.triangles].mean(axis=1)[rng.integers(0, len(surface), 300)]
    a = mid + 0.004 * rng.standard_normal((300, 3))
    b = mid + 0.004 * rng.standard_normal((300, 3))
    t, _ = surface.crossings(a, b, 1e-9)
    corners = surface.vertices[surface.triangles]
    expected = np.array([ref_crossing(a[i], b[i], corners, 1e-9) for i in range(len(a))])
    np.testing.assert_array_equal(np.isnan(t), np.isnan(expected))
    np.testing.assert_allclose(t, expected, atol=1e-12)
    assert (~np.isnan(t)).sum() > 60
    np.testing.assert_allclose(surface.distance(a[:40]), ref_distance(a[:40], corners), atol=1e-14)
    # Tiny segments (far shorter than the broad-phase pieces) through random points of the surface.
    j = rng.integers(0, len(surface), 500)
    w = rng.dirichlet([1, 1, 1], 500)
    p = np.einsum("ik,ikj->ij", w, corners[j])
    d = surface.normals[j] + 0.5 * rng.standard_normal((500, 3))
    d *= 1e-6 / np.linalg.norm(d, axis=1)[:, None]
    t, _ = surface.crossings(p - d, p + d, 0.0)
    np.testing.assert_allclose(t, 0.5, atol=1e-6)


def test_swept_blade_samples_are_even_and_include_the_ends():
    blade = SweptBlade([[[0, 0, 0], [0, 0, 0.1]], [[0.01, 0.02, 0], [0.01, 0.05, 0.08]]])
    for frame in (0, 1):
        points = blade.samples(frame, 5)
        assert points.shape == (5, 3)
        np.testing.assert_array_equal(points[[0, -1]], blade.blade[frame])
        steps = np.diff(points, axis=0)
        np.testing.assert_allclose(steps, np.broadcast_to(steps[0], steps.shape), rtol=0, atol=1e-15)
        np.testing.assert_allclose(4 * steps[0], blade.blade[frame, 1] - blade.blade[frame, 0], atol=1e-15)
    np.testing.assert_array_equal(blade.samples(1, 2), blade.blade[1])
    for frame in (-1, 2):
        with pytest.raises(SurfaceError, match="out of range"):
            blade.samples(frame, 5)


def test_strip_of_two_point_polylines_is_the_blade_increment():
    blade = moving_blade(3)
    for k in (1, 2):
        a, b = strip(blade.blade[k - 1], blade.blade[k]), blade.increment(k)
        np.testing.assert_array_equal(a.vertices, b.vertices)
        np.testing.assert_array_equal(a.triangles, b.triangles)
        np.testing.assert_array_equal(a.normals, b.normals)


def test_strip_of_a_moving_polyline():
    """A bent polyline (3 segments) translated along x: two triangles per segment, area
    length x distance, normal = polyline direction x motion (as a swept blade)."""
    before = np.array([[0, 0, 0], [0, 0.03, 0.01], [0, 0.05, 0.01], [0, 0.08, 0.0]])
    after = before + [0.02, 0, 0]
    surface = strip(before, after)
    assert len(surface) == 6
    length = np.linalg.norm(np.diff(before, axis=0), axis=1).sum()
    assert triangle_areas(surface).sum() == pytest.approx(0.02 * length, rel=1e-12)
    tangent = np.repeat(np.diff(before, axis=0), 2, axis=0)
    expected = np.cross(tangent, [1.0, 0, 0])
    np.testing.assert_allclose(surface.normals, expected / np.linalg.norm(expected, axis=1)[:, None], atol=1e-12)
    # a segment through the middle of the second quad crosses it half way
    t, n = surface.crossings([[0.01, 0.04, -0.1]], [[0.01, 0.04, 0.1]], TOL)
    assert t[0] == pytest.approx(0.5 + 0.01 / 0.2) and n[0] == pytest.approx([0, 0, -1])  # y x x = -z


def test_strip_drops_zero_area_triangles_and_returns_none_without_area():
    before = np.array([[0, 0, 0], [0, 0.1, 0], [0, 0.2, 0]], float)
    after = before.copy()
    after[2] += [0.05, 0, 0]  # only the last point moves: the first quad has no area
    surface = strip(before, after)
    assert len(surface) == 1  # of the second quad, only the triangle through the moved point
    assert triangle_areas(surface).sum() == pytest.approx(0.5 * 0.1 * 0.05)
    assert strip(before, before) is None
    assert strip(before[:1], after[:1]) is None  # a single point sweeps no area
    along = before + [0, 0.3, 0]  # moving along its own line: every triangle is flat
    assert strip(before, along) is None


@pytest.mark.parametrize("before, after, words", [
    (np.zeros((3, 3)), np.zeros((4, 3)), "shape"),
    (np.zeros((3, 2)), np.zeros((3, 2)), "shape"),
    (np.zeros(3), np.zeros(3), "shape"),
    ([[0, 0, 0], [0, 1, np.nan]], [[1, 0, 0], [1, 1, 0]], "NaN"),
    ([["a", 0, 0], [0, 1, 0]], [[1, 0, 0], [1, 1, 0]], "not numeric"),
])
def test_strip_bad_input_raises_surface_error(before, after, words):
    with pytest.raises(SurfaceError, match=words):
        strip(before, after)


def test_plane_tangent_planes_are_the_plane():
    plane = Plane([0.1, 0.2, 0.3], [0.0, 3.0, 4.0])
    points = np.random.default_rng(4).uniform(-2, 2, (7, 3))
    origin, normal = plane.tangent_planes(points)
    assert origin.shape == normal.shape == (7, 3)
    np.testing.assert_allclose(plane.signed_distance(origin), 0.0, atol=1e-15)
    np.testing.assert_allclose(normal, np.broadcast_to([0, 0.6, 0.8], (7, 3)), atol=1e-15)
    with pytest.raises(SurfaceError, match="shape"):
        plane.tangent_planes(np.zeros((2, 2)))


def test_triangle_surface_tangent_planes_are_the_nearest_triangles_planes():
    grid = bumpy_grid(5, seed=3)
    corners = grid.vertices[grid.triangles]
    rng = np.random.default_rng(5)
    points = rng.uniform(-0.3, 1.3, (60, 3))
    origin, normal = grid.tangent_planes(points)
    np.testing.assert_allclose(np.linalg.norm(normal, axis=1), 1.0, atol=1e-12)
    for p, o, n in zip(points, origin, normal):
        gaps = [ref_point_triangle(p, *tri) for tri in corners]
        nearest = np.flatnonzero(np.isclose(gaps, min(gaps), rtol=0, atol=1e-12))
        # the plane returned is that of a nearest triangle (ties allowed): its normal, through it
        assert any(np.allclose(n, grid.normals[j], atol=1e-12) and abs((corners[j] - o) @ n).max() < 1e-12
                   for j in nearest), (p, nearest)


def test_projecting_onto_the_tangent_plane_puts_a_point_on_the_surface():
    """Points just off the inside of a triangle: one projection onto the tangent plane lands on S."""
    grid = bumpy_grid(5, seed=6)
    rng = np.random.default_rng(7)
    j = rng.integers(0, len(grid), 100)
    weights = 0.2 + 0.4 * rng.dirichlet([1, 1, 1], 100)
    on = np.einsum("ik,ikj->ij", weights, grid.vertices[grid.triangles[j]])
    offset = 1e-4 * rng.choice([-1.0, 1.0], 100)
    points = on + offset[:, None] * grid.normals[j]
    origin, normal = grid.tangent_planes(points)
    np.testing.assert_allclose(normal, grid.normals[j], atol=1e-12)
    projected = points - np.einsum("ij,ij->i", points - origin, normal)[:, None] * normal
    np.testing.assert_allclose(projected, on, rtol=0, atol=1e-12)
    assert grid.distance(projected).max() <= 1e-12


# ---------------------------------------------------------------- properties

unit = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(point=st.tuples(unit, unit, unit), normal=st.tuples(unit, unit, unit), seed=st.integers(0, 2**32 - 1))
def test_plane_and_huge_polygon_agree(point, normal, seed):
    if np.linalg.norm(normal) < 1e-3:
        return
    plane = Plane(point, normal)
    n = plane.normal
    u = np.cross(n, np.eye(3)[np.argmin(np.abs(n))])
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    square = Polygon([plane.point + 100.0 * (su * u + sw * w) for su, sw in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    rng = np.random.default_rng(seed)
    a, b = rng.uniform(-2, 2, (200, 3)), rng.uniform(-2, 2, (200, 3))
    tol = 1e-6
    da, db = np.abs(plane.signed_distance(a)), np.abs(plane.signed_distance(b))
    clear = (np.abs(da - tol) > 1e-9) & (np.abs(db - tol) > 1e-9)  # away from the tolerance bands
    tp, np_ = plane.crossings(a, b, tol)
    tq, nq = square.crossings(a, b, tol)
    np.testing.assert_array_equal(np.isnan(tp[clear]), np.isnan(tq[clear]))
    np.testing.assert_allclose(tp[clear], tq[clear], atol=1e-9)
    np.testing.assert_allclose(np_[clear], nq[clear], atol=1e-12)
    hit = ~np.isnan(tq)
    p = a[hit] + tq[hit, None] * (b[hit] - a[hit])
    assert np.all(square.distance(p) <= 1e-9)
    q = a + np.nan_to_num(tp)[:, None] * (b - a)
    assert np.all(np.abs(plane.signed_distance(q[~np.isnan(tp)])) <= 1e-9)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), tol=st.sampled_from([0.0, 1e-9, 1e-4]))
def test_triangle_crossings_are_on_the_surface_and_strict(seed, tol):
    rng = np.random.default_rng(seed)
    grid = bumpy_grid(4, seed=seed % 1000)
    a = rng.uniform(-0.2, 1.2, (300, 3))
    b = a + 0.4 * rng.standard_normal((300, 3))
    t, n = grid.crossings(a, b, tol)
    hit = ~np.isnan(t)
    assert np.all((t[hit] > 0) & (t[hit] < 1))
    p = a[hit] + t[hit, None] * (b[hit] - a[hit])
    assert np.all(grid.distance(p) <= 1e-9)
    assert np.all(grid.distance(a[hit]) > tol) and np.all(grid.distance(b[hit]) > tol)
    np.testing.assert_allclose(np.linalg.norm(n[hit], axis=1), 1.0)
    # The endpoints are on opposite sides of the reported normal's plane at the crossing point.
    assert np.all(np.einsum("ij,ij->i", a[hit] - p, n[hit]) * np.einsum("ij,ij->i", b[hit] - p, n[hit]) < 0)


def _v_surface():
    """Two vertical sheets meeting at x = 0 (a V opening towards +y), 2 m high."""
    v = np.array([[-1.0, 1.0, -1.0], [-1.0, 1.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0],
                  [1.0, 1.0, -1.0], [1.0, 1.0, 1.0]])
    return TriangleSurface(v, np.array([[0, 2, 1], [1, 2, 3], [2, 4, 3], [3, 4, 5]]))


def test_winding_jumps_by_one_across_the_surface_and_not_across_a_fold():
    surface = _v_surface()
    h = 0.01
    a = np.array([[-0.5, 0.5 + h, 0.0],   # inside the V, then across the left sheet
                  [0.5, 0.5 + h, 0.0],    # inside, across the right sheet
                  [-0.05, 0.1, 0.0],      # inside near the fold, to inside on the other side
                  [0.0, -0.05, 0.0],      # outside below the fold, to outside left of it
                  [-0.5, 0.5 + h, 0.0]])  # inside, to inside further up
    b = np.array([[-0.5, 0.5 - h, 0.0], [0.5, 0.5 - h, 0.0], [0.05, 0.1, 0.0], [-0.1, 0.0, 0.0],
                  [-0.2, 0.6, 0.0]])
    jumps = surface.winding_jumps(a, b, np.full(5, 10.0))
    np.testing.assert_allclose(np.abs(jumps[:2]), 1.0, atol=0.02)
    assert np.abs(jumps[2:]).max() < 0.1  # smooth on one side (faster near the fold), no jump
    assert np.sign(jumps[0]) == np.sign(jumps[1])  # both sheets face the same way
    # far triangles left out: a radius that reaches only the near sheet keeps the jump
    near = surface.winding_jumps(a[:1], b[:1], np.array([0.3]))
    assert abs(abs(near[0]) - 1.0) < 0.1


def test_winding_numbers_tell_the_side_of_the_surface():
    """The local winding number of S at a point: opposite signs next to S on either side,
    differences equal to :meth:`winding_jumps` over the same triangles, and 0 beyond S's edge
    in its plane."""
    surface = _v_surface()
    h = 0.01
    above, below = np.array([[-0.5, 0.5 + h, 0.0]]), np.array([[-0.5, 0.5 - h, 0.0]])
    inside, outside = surface.winding_numbers(above, 10.0)[0], surface.winding_numbers(below, 10.0)[0]
    # inside the V the far sheet adds its solid angle (0.63); outside it takes it off (0.37)
    assert 0.5 < abs(inside) < 1.0 and 0.3 < abs(outside) < 0.5 and np.sign(inside) != np.sign(outside)
    jump = surface.winding_jumps(below, above, np.array([10.0]))[0]
    assert inside - outside == pytest.approx(jump, abs=1e-12)
    # the near sheet alone: about a half on either side
    near = surface.winding_numbers(np.r_[above, below], 0.3)
    np.testing.assert_allclose(near, [np.sign(inside) * 0.5, np.sign(outside) * 0.5], atol=0.01)
    # beyond the right sheet's end, in its plane (the left sheet out of reach): no side
    assert abs(surface.winding_numbers(np.array([[1.5, 1.5, 0.0]]), 0.8)[0]) < 1e-9
