"""Pictures of a cut body (wcut.picture): the wound found and drawn in its own colour."""

import numpy as np

import wcut
from wcut.ar.camera import Camera
from wcut.cut import TriangleSurface
from wcut.picture import BACKGROUND_RGB, WOUND_RGB, render_picture, wound_faces


def _cut_beam():
    mesh = wcut.beam(4, 2, 2, size=(0.08, 0.04, 0.04))
    topology = wcut.TetTopology(mesh)
    wcut.Cutter(topology).cut(wcut.Plane([0.041, 0.0, 0.0], [1.0, 0.0, 0.0]))
    return mesh, topology.to_mesh()


def test_the_wound_is_the_faces_the_cut_opened():
    before, after = _cut_beam()
    triangles = after.boundary().triangles
    surface = TriangleSurface(before.vertices, before.boundary().triangles)
    wound = wound_faces(after.vertices, triangles, surface, 1e-9)
    centroids = after.vertices[triangles].mean(axis=1)
    on_plane = np.abs(centroids[:, 0] - 0.041) < 1e-9
    assert wound.any() and np.array_equal(wound, on_plane)


def test_a_picture_of_the_opened_halves_shows_the_wound_lit():
    before, after = _cut_beam()
    triangles = after.boundary().triangles
    left = triangles[after.vertices[triangles].mean(axis=1)[:, 0] < 0.0411]  # the left half alone
    surface = TriangleSurface(before.vertices, before.boundary().triangles)
    wound = wound_faces(after.vertices, left, surface, 1e-9)
    camera = Camera.look_at([0.1, -0.03, 0.05], [0.03, 0.02, 0.02], up=(0.0, 0.0, 1.0), width=80, height=60)
    image = render_picture(camera, after.vertices, left, wound).astype(float) / 255.0
    background = np.all(np.abs(image - BACKGROUND_RGB) < 1e-6, axis=2)
    reddish = (image[:, :, 0] > 2.0 * image[:, :, 1]) & ~background
    assert 0 < background.sum() < image.shape[0] * image.shape[1]
    assert reddish.sum() > 50  # the left half's cut face
    assert image[reddish].max() <= max(WOUND_RGB) + 1e-6 and image[reddish][:, 0].min() > 0.05  # lit, not black
