"""Tests of wcut.ar.render: ray casting and the textured render of a synthetic object."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from wcut.ar.camera import Camera
from wcut.ar.render import RayHits, Renderer, RenderError, Texture
from wcut.errors import WcutError

from conftest import axis_angle_rotation


def grid_surface(side: float, cells: int, height=None):
    """A square ``side`` x ``side`` (m) in the plane z = 0 centred at the origin, split into
    ``cells`` x ``cells`` squares of two triangles; ``height(x, y)`` (m) bends it."""
    xs = np.linspace(-side / 2, side / 2, cells + 1)
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    Z = np.zeros_like(X) if height is None else height(X, Y)
    points = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    idx = np.arange((cells + 1) ** 2).reshape(cells + 1, cells + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    triangles = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])]).astype(np.int32)
    return points, triangles


def top_camera(distance: float, width=160, height=120) -> Camera:
    """A camera on the z axis at ``distance`` (m) looking down at the origin."""
    return Camera.look_at([0.0, 0.0, distance], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0), width=width, height=height)


def test_silhouette_of_a_square_has_its_projected_area():
    cam = top_camera(2.0)
    side = 1.0
    points, triangles = grid_surface(side, 1)
    points = points @ axis_angle_rotation([0, 0, 1], 0.4).T  # turned in its plane: no pixel-centre ties
    mask = Renderer(cam).silhouette(points, triangles)
    assert mask.shape == (120, 160) and mask.dtype == bool
    side_px = cam.fx * side / 2.0
    perimeter_px = 4 * side_px
    assert abs(mask.sum() - side_px**2) < 0.5 * perimeter_px
    # the square is centred: its pixels' centroid is the principal point
    v, u = np.nonzero(mask)
    assert abs(u.mean() - cam.cx) < 0.5 and abs(v.mean() - cam.cy) < 0.5


def test_cast_pixels_lifts_projected_surface_points():
    cam = Camera.look_at([0.05, -0.08, 0.3], [0.0, 0.0, 0.0], width=160, height=120)
    points, triangles = grid_surface(0.1, 8, lambda x, y: 0.01 * np.sin(40 * x) * np.cos(30 * y))
    rng = np.random.default_rng(3)
    faces = rng.integers(0, len(triangles), size=40)
    weights = rng.dirichlet([2.0, 2.0, 2.0], size=40)
    targets = np.einsum("kj,kjd->kd", weights, points[triangles[faces]])
    pixels, depth = cam.project(targets)
    assert np.all(depth > 0)

    face, bary, distance = Renderer(cam).cast_pixels(pixels, points, triangles)
    assert face.dtype == np.int32 and face.shape == (40,) and bary.shape == (40, 3)
    assert np.all(face >= 0)
    np.testing.assert_allclose(bary.sum(axis=1), 1.0, atol=1e-6)
    lifted = np.einsum("kj,kjd->kd", bary, points[triangles[face]])
    np.testing.assert_allclose(lifted, targets, atol=1e-5)
    np.testing.assert_allclose(distance, np.linalg.norm(targets - cam.center, axis=1), atol=1e-5)


def test_rays_that_miss_give_minus_one():
    cam = top_camera(0.5)
    points, triangles = grid_surface(0.05, 2)
    pixels = np.array([[0.0, 0.0], [159.0, 119.0], [-500.0, 60.0], [cam.cx, cam.cy]])
    face, bary, distance = Renderer(cam).cast_pixels(pixels, points, triangles)
    assert face.tolist()[:3] == [-1, -1, -1] and face[3] >= 0
    assert np.all(bary[:3] == 0.0) and np.all(np.isinf(distance[:3]))
    assert distance[3] == pytest.approx(0.5, abs=1e-6)
    empty = Renderer(cam).cast_pixels(np.zeros((0, 2)), points, triangles)
    assert [a.shape[0] for a in empty] == [0, 0, 0]


def test_cast_returns_face_barycentrics_and_distance_per_pixel():
    cam = top_camera(0.5)
    points, triangles = grid_surface(0.1, 4)
    hits = Renderer(cam).cast(points, triangles)
    assert isinstance(hits, RayHits)
    assert hits.face.shape == (120, 160) and hits.face.dtype == np.int32
    assert hits.bary.shape == (120, 160, 2) and hits.distance.shape == (120, 160)
    assert hits.face[0, 0] == -1 and np.isinf(hits.distance[0, 0])
    # every hit lies on the plane z = 0 along its pixel ray
    v, u = np.nonzero(hits.mask)
    uv = hits.bary[v, u]
    w = np.column_stack([uv, 1.0 - uv.sum(axis=1)])
    on_surface = np.einsum("kj,kjd->kd", w, points[triangles[hits.face[v, u]]])
    along_ray = cam.center + hits.distance[v, u, None] * cam.rays(np.column_stack([u, v]))
    np.testing.assert_allclose(on_surface, along_ray, atol=1e-5)
    np.testing.assert_allclose(on_surface[:, 2], 0.0, atol=1e-7)


def test_moving_points_refits_instead_of_rebuilding():
    cam = top_camera(0.5)
    points, triangles = grid_surface(0.1, 4)
    renderer = Renderer(cam)
    before = renderer.cast(points, triangles)
    moved = points + [0.02, 0.0, 0.1]  # 2 cm sideways, 10 cm closer
    after = renderer.cast(moved, triangles.copy())  # equal content, another object
    assert (renderer.builds, renderer.refits) == (1, 1)
    fresh = Renderer(cam).cast(moved, triangles)
    np.testing.assert_array_equal(after.face, fresh.face)
    np.testing.assert_allclose(after.distance[after.mask], fresh.distance[fresh.mask], atol=1e-6)
    assert after.mask.sum() > before.mask.sum()  # closer: larger
    centre = (int(round(cam.cy)), int(round(cam.cx)))
    assert after.distance[centre] == pytest.approx(0.4, abs=1e-5)
    # another triangle set rebuilds
    renderer.cast(moved, triangles[::-1])
    assert renderer.builds == 2


def test_render_output_and_uniform_background():
    cam = top_camera(0.3)
    points, triangles = grid_surface(0.1, 8)
    image, mask = Renderer(cam).render(points, triangles, points)
    assert image.shape == (120, 160, 3) and image.dtype == np.uint8
    assert mask.dtype == bool
    np.testing.assert_array_equal(mask, Renderer(cam).silhouette(points, triangles))
    background = image[~mask]
    assert len(background) > 0 and np.all(background == background[0])
    tissue = image[mask].astype(float).mean(axis=0)
    assert tissue[2] > tissue[1] + 40 and tissue[2] > tissue[0] + 40  # reddish (BGR)
    assert image[mask].std() > 20  # textured


def test_texture_is_attached_to_the_material():
    """Moving the surface parallel to the image plane by k pixels' worth moves the image by k
    pixels: the texture follows the rest positions, not the world."""
    depth = 0.15
    cam = top_camera(depth)
    points, triangles = grid_surface(0.1, 8)
    renderer = Renderer(cam, ambient=1.0)  # no shading: the Lambert term varies with the ray
    texture = Texture(seed=5, scale=8e-3)
    k = 7
    step = k * depth / cam.fx  # m: k pixels at this depth
    first, mask1 = renderer.render(points, triangles, points, texture)
    second, mask2 = renderer.render(points + [step, 0.0, 0.0], triangles, points, texture)
    inner = cv2.erode((mask1[:, :-k] & mask2[:, k:]).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    assert inner.sum() > 5000
    diff = np.abs(second[:, k:].astype(int) - first[:, :-k].astype(int))[inner]
    assert diff.mean() < 0.01 and diff.max() <= 1  # float32 rounding only
    # ... while the unshifted comparison differs: the texture has detail at this scale
    assert np.abs(second[:, :-k].astype(int) - first[:, :-k].astype(int))[inner].mean() > 10


def test_texture_depends_on_seed_and_rejects_bad_parameters():
    cam = top_camera(0.3)
    points, triangles = grid_surface(0.1, 4)
    renderer = Renderer(cam)
    a, mask = renderer.render(points, triangles, points, Texture(seed=1))
    b, _ = renderer.render(points, triangles, points, Texture(seed=2))
    assert np.abs(a.astype(int) - b.astype(int))[mask].mean() > 10
    bad = [(dict(scale=0.0), "scale"), (dict(contrast=float("nan")), "contrast"), (dict(seed=1.5), "seed")]
    for kwargs, name in bad:
        with pytest.raises(RenderError, match=f"texture.{name}"):
            Texture(**kwargs)


def test_render_has_many_trackable_corners():
    cam = top_camera(0.16, width=480, height=360)
    points, triangles = grid_surface(0.1, 32)
    image, mask = Renderer(cam).render(points, triangles, points, Texture(seed=7))
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    corners = cv2.goodFeaturesToTrack(gray, maxCorners=2000, qualityLevel=0.01, minDistance=7)
    assert corners is not None and len(corners) >= 200
    # features lie on the object (its edge included), none in the flat background
    near_object = cv2.dilate(mask.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    u, v = np.round(corners[:, 0]).astype(int).T
    assert np.all(near_object[v, u])


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda r, p, t: r.cast(p[:, :2], t), "points"),
        (lambda r, p, t: r.cast(np.where(np.arange(len(p))[:, None] == 3, np.nan, p), t), "points"),
        (lambda r, p, t: r.cast(p, t + len(p)), "triangles"),
        (lambda r, p, t: r.cast(p, t.astype(float)), "triangles"),
        (lambda r, p, t: r.cast(p, np.zeros((0, 3), int)), "triangles"),
        (lambda r, p, t: r.render(p, t, p[:-1]), "rest_points"),
        (lambda r, p, t: r.render(p, t, p, texture=3), "texture"),
        (lambda r, p, t: r.cast_pixels(np.zeros((4, 3)), p, t), "pixels"),
        (lambda r, p, t: r.cast_pixels([[np.inf, 0.0]], p, t), "pixels"),
    ],
)
def test_bad_input_names_the_argument(call, name):
    points, triangles = grid_surface(0.1, 2)
    with pytest.raises(RenderError, match=f"^{name}: ") as info:
        call(Renderer(top_camera(0.3, 32, 24)), points, triangles)
    assert isinstance(info.value, WcutError)


def test_renderer_needs_a_camera():
    with pytest.raises(RenderError, match="camera"):
        Renderer("camera.json")
