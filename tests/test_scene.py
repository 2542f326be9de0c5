"""Tests of wcut.scene: parsing and validating scene files, building the model, running a scene."""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np
import pytest

import wcut
from wcut.errors import MeshError, SceneError, WcutError
from wcut.scene import build_mesh, build_model, load_scene, run_scene
from wcut.usd import validate_usd

REPO = Path(__file__).resolve().parents[1]

MINIMAL = """
[mesh]
generator = "beam"
cells = [4, 2, 2]
size = [0.2, 0.05, 0.05]
"""


def _scene_error(tmp_path, write_scene, text: str, name: str = "bad.toml") -> str:
    path = write_scene(tmp_path, text, name)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    message = str(info.value)
    assert message.split(": ")[0].endswith(name), message  # every message names the file first
    return message


# ---------------------------------------------------------------------------------------------
# load_scene


def test_example_scene_loads():
    scene = load_scene(REPO / "scenes" / "beam_sag.toml")
    assert scene.name == "beam"
    assert scene.mesh["generator"] == "beam" and scene.mesh["path"] is None
    assert scene.mesh["cells"] == [20, 4, 4]
    assert scene.mesh["size"] == [0.2, 0.04, 0.04]
    assert scene.material == {"density": 1000.0, "youngs_modulus": 2.0e5, "poisson_ratio": 0.35}
    assert scene.damping == {"rayleigh_mass": 2.0, "rayleigh_stiffness": 0.002}
    assert scene.constraints["fixed_boxes"] == [[[-0.001, -1.0, -1.0], [0.001, 1.0, 1.0]]]
    assert scene.loads["gravity"] == [0.0, 0.0, -9.81]
    assert scene.solver["cg_iterations"] == 60 and scene.solver["dt"] == 0.01
    assert scene.simulation == {"duration": 3.0, "fps": 30.0}
    assert scene.output["path"] == "beam_sag.usdc" and scene.output["stress_colors"] is True
    assert scene.frame_count == 90
    assert scene.forces == [] and scene.attachments == []
    mesh = build_mesh(scene)
    assert (mesh.vertex_count, mesh.tet_count) == (21 * 5 * 5, 5 * 20 * 4 * 4)


def test_defaults_and_name_from_file(tmp_path, write_scene):
    scene = load_scene(write_scene(tmp_path, MINIMAL, "plain.toml"))
    assert scene.name == "plain"
    assert scene.path == tmp_path / "plain.toml"
    assert scene.material == {"density": 1000.0, "youngs_modulus": 1.0e5, "poisson_ratio": 0.3}
    assert scene.loads["gravity"] == [0.0, 0.0, -9.81]
    assert scene.mesh["tets_per_hex"] == 5 and scene.mesh["origin"] == [0.0, 0.0, 0.0]
    assert scene.output == {"path": None, "stress_colors": True, "stress_max": None, "up_axis": "Z", "subdivision": 2}
    assert scene.frame_count == 60  # 2 s at 30 fps


@pytest.mark.parametrize(
    "duration, fps, frames",
    [(1.0, 24, 24), (0.1, 30, 3), (0.001, 30, 1), (0.5, 25.5, 13)],
)
def test_frame_count(tmp_path, write_scene, duration, fps, frames):
    text = MINIMAL + f"[simulation]\nduration = {duration}\nfps = {fps}\n"
    assert load_scene(write_scene(tmp_path, text)).frame_count == frames


def test_integers_are_accepted_as_numbers(tmp_path, write_scene):
    text = MINIMAL + "[material]\nyoungs_modulus = 200000\ndensity = 900\n[loads]\ngravity = [0, -10, 0]\n"
    scene = load_scene(write_scene(tmp_path, text))
    assert scene.material["youngs_modulus"] == 2.0e5 and isinstance(scene.material["youngs_modulus"], float)
    assert scene.loads["gravity"] == [0.0, -10.0, 0.0]


@pytest.mark.parametrize(
    "extra, key, words",
    [
        ('colour = "red"\n', "colour", "unknown key"),
        ("[materials]\ndensity = 1.0\n", "materials", "unknown key"),
        ("[material]\nyoungs_modulos = 1.0e5\n", "material.youngs_modulos", "unknown key"),
        ("[solver]\ndt = 0.01\ncg_iter = 5\n", "solver.cg_iter", "unknown key"),
        ('[material]\nyoungs_modulus = "soft"\n', "material.youngs_modulus", "expected a number, got 'soft'"),
        ("[material]\ndensity = true\n", "material.density", "expected a number"),
        ("[material]\ndensity = nan\n", "material.density", "finite"),
        ("[solver]\ncg_iterations = true\n", "solver.cg_iterations", "expected an integer"),
        ("[solver]\ncg_iterations = 5.0\n", "solver.cg_iterations", "expected an integer"),
        ("[loads]\ngravity = [0.0, -9.81]\n", "loads.gravity", "three numbers"),
        ('[loads]\ngravity = [0.0, "down", 0.0]\n', "loads.gravity[1]", "expected a number"),
        ("[output]\nstress_colors = 1\n", "output.stress_colors", "true or false"),
        ("[output]\npath = 3\n", "output.path", "expected a string"),
        ("[constraints]\nfixed_indices = 3\n", "constraints.fixed_indices", "expected a list"),
        ("[constraints]\nfixed_indices = [1, 2.5]\n", "constraints.fixed_indices[1]", "expected an integer"),
        ("[constraints]\nfixed_boxes = [[0, 0, 0]]\n", "constraints.fixed_boxes[0]", "expected [[x0"),
        ("[solver]\ndt = -0.01\n", "solver.dt", "must be positive"),
        ("[solver]\ndt = 0.0\n", "solver.dt", "must be positive"),
        ("[simulation]\nfps = 0\n", "simulation.fps", "must be positive"),
        ("[simulation]\nduration = -1.0\n", "simulation.duration", "must be positive"),
        ('[output]\nup_axis = "X"\n', "output.up_axis", "'Y' or 'Z'"),
        ('[output]\nup_axis = "z"\n', "output.up_axis", "'Y' or 'Z'"),
        ("[output]\nsubdivision = 6\n", "output.subdivision", "0..5"),
        ("name = 7\n", "name", "expected a string"),
        ("solver = 3\n", "solver", "expected a table"),
    ],
)
def test_bad_values_name_the_key(tmp_path, write_scene, extra, key, words):
    # top-level keys must come before the [mesh] table in TOML
    text = extra + MINIMAL if not extra.startswith("[") else MINIMAL + extra
    message = _scene_error(tmp_path, write_scene, text)
    assert f" {key}" in message or f"{key}:" in message, message
    assert words in message, message


@pytest.mark.parametrize(
    "mesh_table, key, words",
    [
        ('[mesh]\npath = "a.msh"\ngenerator = "beam"\n', "mesh", "exactly one of mesh.path and mesh.generator"),
        ("[mesh]\ncells = [2, 2, 2]\n", "mesh", "exactly one of mesh.path and mesh.generator"),
        ('[mesh]\ngenerator = "sphere"\n', "mesh.generator", "unknown generator 'sphere'"),
        ('[mesh]\ngenerator = "beam"\ncells = [2, 2]\n', "mesh.cells", "three integers"),
        ('[mesh]\ngenerator = "beam"\ncells = [2, 2, 2.0]\n', "mesh.cells[2]", "expected an integer"),
        ("name = 'x'\n", "mesh", "missing section"),
        ('[mesh]\ngenerator = "beam"\norder = 3\n', "mesh.order", "1 (linear) or 2 (quadratic)"),
    ],
)
def test_bad_mesh_section(tmp_path, write_scene, mesh_table, key, words):
    message = _scene_error(tmp_path, write_scene, mesh_table)
    assert f"{key}:" in message and words in message, message


@pytest.mark.parametrize(
    "extra, key, words",
    [
        ("[[attachments]]\npoint = [0.1, 0.02, 0.02]\nvertex = 3\ntarget = [0, 0, 0]\nstiffness = 10.0\n",
         "attachments[0]", "exactly one of point and vertex"),
        ("[[attachments]]\ntarget = [0, 0, 0]\nstiffness = 10.0\n", "attachments[0]", "exactly one of point and vertex"),
        ("[[attachments]]\nvertex = 3\nstiffness = 10.0\n", "attachments[0].target", "missing"),
        ("[[attachments]]\nvertex = 3\ntarget = [0, 0, 0]\n", "attachments[0].stiffness", "missing"),
        ("[[attachments]]\nvertex = 3\ntarget = [0, 0, 0]\nstiffness = 1.0\nanchor = 2\n", "attachments[0].anchor",
         "unknown key"),
        ("[[attachments]]\nvertex = 3\ntarget = [0, 0]\nstiffness = 1.0\n", "attachments[0].target", "three numbers"),
        ("attachments = 5\n", "attachments", "array of tables"),
        ("[[loads.force]]\nbox = [[0, 0, 0], [1, 1, 1]]\n", "loads.force[0].total", "missing"),
        ("[[loads.force]]\ntotal = [0, 0, -1]\n", "loads.force[0].box", "missing"),
        ("[[loads.force]]\nbox = [[0, 0, 0], [1, 1, 1]]\ntotal = [0, 0, -1]\nspread = 1\n",
         "loads.force[0].spread", "unknown key"),
        ("[loads.force]\nbox = [[0, 0, 0], [1, 1, 1]]\ntotal = [0, 0, -1]\n", "loads.force", "array of tables"),
    ],
)
def test_bad_attachments_and_forces(tmp_path, write_scene, extra, key, words):
    text = extra + MINIMAL if extra.startswith("attachments =") else MINIMAL + extra
    message = _scene_error(tmp_path, write_scene, text)
    assert f"{key}:" in message and words in message, message


def test_invalid_toml(tmp_path, write_scene):
    message = _scene_error(tmp_path, write_scene, MINIMAL + "[material\ndensity = \n")
    assert "not valid TOML" in message and "line 6" in message
    assert message.startswith(str(tmp_path / "bad.toml"))


def test_missing_scene_file(tmp_path):
    path = tmp_path / "absent.toml"
    with pytest.raises(SceneError, match="no such scene file") as info:
        load_scene(path)
    assert str(path) in str(info.value)


def test_missing_mesh_file_is_a_mesh_error(tmp_path, write_scene):
    scene = load_scene(write_scene(tmp_path, '[mesh]\npath = "meshes/organ.vtu"\n'))
    with pytest.raises(MeshError, match="no such file") as info:
        build_mesh(scene)
    assert isinstance(info.value, WcutError)
    assert str(tmp_path / "meshes" / "organ.vtu") in str(info.value)


def test_mesh_path_is_relative_to_the_scene_file(tmp_path, write_scene, small_beam):
    (tmp_path / "meshes").mkdir()
    meshio.write(tmp_path / "meshes" / "beam.vtu", meshio.Mesh(small_beam.vertices, [("tetra", small_beam.tets)]))
    scene = load_scene(write_scene(tmp_path, '[mesh]\npath = "meshes/beam.vtu"\n'))
    mesh = build_mesh(scene)
    assert np.array_equal(mesh.tets, small_beam.tets)
    assert np.allclose(mesh.vertices, small_beam.vertices)


def test_generator_options_reach_the_beam(tmp_path, write_scene):
    text = '[mesh]\ngenerator = "beam"\ncells = [2, 1, 3]\nsize = [0.2, 0.1, 0.3]\norigin = [1, 2, 3]\ntets_per_hex = 6\n'
    mesh = build_mesh(load_scene(write_scene(tmp_path, text)))
    assert mesh.tet_count == 6 * 2 * 1 * 3
    assert np.allclose(mesh.vertices.min(axis=0), [1, 2, 3])
    assert np.allclose(mesh.vertices.max(axis=0), [1.2, 2.1, 3.3])


# ---------------------------------------------------------------------------------------------
# build_model


def test_fixed_boxes_fix_exactly_the_vertices_inside(tmp_path, write_scene):
    text = MINIMAL + (
        "[constraints]\n"
        "fixed_boxes = [[[-0.001, -1.0, -1.0], [0.001, 1.0, 1.0]], [[0.199, -1.0, 0.049], [0.201, 1.0, 1.0]]]\n"
        "fixed_indices = [22]\n"
    )
    scene = load_scene(write_scene(tmp_path, text))
    mesh = build_mesh(scene)
    model, _, _ = build_model(scene, mesh=mesh)
    x = mesh.vertices
    expected = (np.abs(x[:, 0]) < 1e-9) | ((np.abs(x[:, 0] - 0.2) < 1e-9) & (np.abs(x[:, 2] - 0.05) < 1e-9))
    expected[22] = True
    assert np.array_equal(model.particle_fixed.numpy().astype(bool), expected)
    assert model.fixed_count == 9 + 3 + 1


def test_fixed_box_without_vertices_is_an_error(tmp_path, write_scene):
    text = MINIMAL + "[constraints]\nfixed_boxes = [[[-0.001, -1.0, -1.0], [0.001, 1.0, 1.0]], [[5, 5, 5], [6, 6, 6]]]\n"
    scene = load_scene(write_scene(tmp_path, text, "empty_box.toml"))
    with pytest.raises(SceneError) as info:
        build_model(scene)
    message = str(info.value)
    assert message.startswith("empty_box.toml:")
    assert "constraints.fixed_boxes[1]" in message and "no vertex" in message


def test_forces_are_spread_evenly(tmp_path, write_scene):
    text = MINIMAL + (
        "[[loads.force]]\nbox = [[0.199, -1, -1], [0.201, 1, 1]]\ntotal = [0.0, 0.3, -0.9]\n"
        "[[loads.force]]\nbox = [[0.099, -1, 0.049], [0.101, 1, 1]]\ntotal = [1.5, 0.0, 0.0]\n"
    )
    scene = load_scene(write_scene(tmp_path, text))
    mesh = build_mesh(scene)
    _, _, f = build_model(scene, mesh=mesh)
    assert f.shape == (mesh.vertex_count, 3)
    assert np.allclose(f.sum(axis=0), [1.5, 0.3, -0.9], atol=1e-6)
    end = mesh.vertices_in_box((0.199, -1, -1), (0.201, 1, 1))
    mid = mesh.vertices_in_box((0.099, -1, 0.049), (0.101, 1, 1))
    assert len(end) == 9 and len(mid) == 3
    assert np.allclose(f[end], [0.0, 0.3 / 9, -0.9 / 9], atol=1e-7)
    assert np.allclose(f[mid], [0.5, 0.0, 0.0], atol=1e-7)
    others = np.setdiff1d(np.arange(mesh.vertex_count), np.concatenate([end, mid]))
    assert np.all(f[others] == 0.0)


def test_force_box_without_vertices_is_an_error(tmp_path, write_scene):
    text = MINIMAL + "[[loads.force]]\nbox = [[5, 5, 5], [6, 6, 6]]\ntotal = [0, 0, -1]\n"
    with pytest.raises(SceneError, match=r"loads\.force\[0\]\.box contains no vertex"):
        build_model(load_scene(write_scene(tmp_path, text)))


@pytest.mark.parametrize("point", [(0.1, 0.025, 0.025), (0.013, 0.041, 0.007), (0.187, 0.003, 0.032)])
def test_attachment_at_a_point_has_barycentric_weights(tmp_path, write_scene, point):
    text = MINIMAL + (
        f"[[attachments]]\npoint = [{point[0]}, {point[1]}, {point[2]}]\ntarget = [0.3, 0.0, 0.1]\nstiffness = 25.0\n"
        "[[attachments]]\nvertex = 44\ntarget = [0.25, 0.05, 0.05]\nstiffness = 5.0\n"
    )
    scene = load_scene(write_scene(tmp_path, text))
    mesh = build_mesh(scene)
    model, control, _ = build_model(scene, mesh=mesh)
    assert model.attachment_count == 2
    indices = model.attachment_indices.numpy()
    weights = model.attachment_weights.numpy().astype(np.float64)
    # the point spring: weights of the element containing the point
    assert weights[0].sum() == pytest.approx(1.0, abs=1e-6)
    assert np.all(weights[0] >= -1e-7)
    assert np.allclose(weights[0] @ mesh.vertices[indices[0]], point, atol=1e-6)
    assert sorted(indices[0].tolist()) in [sorted(t) for t in mesh.tets.tolist()]
    # the vertex spring: all weight on vertex 44 (the far corner)
    assert indices[1, 0] == 44 and weights[1, 0] == pytest.approx(1.0) and weights[1, 1:].sum() == 0.0
    assert np.allclose(model.attachment_stiffness.numpy(), [25.0, 5.0])
    assert np.allclose(control.attachment_target.numpy(), [[0.3, 0.0, 0.1], [0.25, 0.05, 0.05]])
    assert np.allclose(model.attachment_rest_points.numpy(), [point, mesh.vertices[44]], atol=1e-9)


def test_attachment_vertex_out_of_range(tmp_path, write_scene):
    text = MINIMAL + "[[attachments]]\nvertex = 45\ntarget = [0, 0, 0]\nstiffness = 5.0\n"
    with pytest.raises(SceneError, match=r"attachments\[0\]\.vertex: vertex 45 is not a vertex"):
        build_model(load_scene(write_scene(tmp_path, text)))


def test_material_and_gravity_reach_the_model(tmp_path, write_scene):
    text = MINIMAL + "[material]\ndensity = 500.0\n[loads]\ngravity = [0.0, -9.81, 0.0]\n"
    model, _, _ = build_model(load_scene(write_scene(tmp_path, text)))
    assert model.particle_mass.numpy().sum() == pytest.approx(500.0 * 0.2 * 0.05 * 0.05, rel=1e-5)
    assert np.allclose(np.array(model.gravity), [0.0, -9.81, 0.0])


def test_bad_material_is_a_wcut_error(tmp_path, write_scene):
    text = MINIMAL + "[material]\npoisson_ratio = 0.5\n"
    with pytest.raises(WcutError, match="poisson_ratio"):
        build_model(load_scene(write_scene(tmp_path, text)))


# ---------------------------------------------------------------------------------------------
# run_scene


def test_run_scene_writes_a_valid_animation(tmp_path, tiny_scene):
    scene = load_scene(tiny_scene)
    out = tmp_path / "out" / "tiny.usda"
    result = run_scene(scene, out, frames=3, progress=False)
    assert result.output == out
    assert out.is_file()
    assert validate_usd(out) == []
    assert result.frames == 3
    assert result.steps == 3 * 4  # 1/30 s per frame in ceil((1/30) / 0.01) = 4 sub-steps
    assert result.nodes == 45 and result.elements == 80
    assert result.mean_step_ms > 0.0
    assert sorted(p.name for p in out.parent.iterdir()) == ["tiny.usda"]

    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(out))
    assert stage.GetStartTimeCode() == 0 and stage.GetEndTimeCode() == 3
    assert stage.GetTimeCodesPerSecond() == 30.0
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/tiny"))
    rest = np.array(mesh.GetPointsAttr().Get(0))
    last = np.array(mesh.GetPointsAttr().Get(3))
    surface = wcut.beam(4, 2, 2, size=(0.2, 0.05, 0.05)).boundary()
    assert rest.shape == (len(surface.vertex_ids), 3)
    assert len(mesh.GetFaceVertexCountsAttr().Get(0)) == len(surface.triangles)
    # the clamped end stays, the free end falls under gravity
    clamped = np.isclose(rest[:, 0], 0.0)
    free = np.isclose(rest[:, 0], 0.2)
    assert np.allclose(last[clamped], rest[clamped], atol=1e-6)
    assert np.all(last[free, 2] < rest[free, 2])
    assert np.all(np.isfinite(last))


def test_run_scene_default_frames_and_output_path(tmp_path, tiny_scene, write_scene, monkeypatch):
    text = tiny_scene.read_text().replace("[simulation]\nduration = 0.1", "[simulation]\nduration = 0.05") + \
        '\n[output]\npath = "anim.usdc"\nstress_colors = false\nup_axis = "Y"\n'
    scene = load_scene(write_scene(tmp_path, text, "tiny2.toml"))
    monkeypatch.chdir(tmp_path)
    result = run_scene(scene, progress=False)
    assert result.frames == scene.frame_count == 2
    assert result.output == Path("anim.usdc")
    assert (tmp_path / "anim.usdc").is_file()
    assert validate_usd(tmp_path / "anim.usdc") == []


def test_run_scene_rejects_zero_frames(tmp_path, tiny_scene):
    with pytest.raises(SceneError, match="frames must be at least 1"):
        run_scene(load_scene(tiny_scene), tmp_path / "x.usdc", frames=0, progress=False)
    assert not (tmp_path / "x.usdc").exists()


def test_stress_colours_share_one_scale_over_the_whole_run(tmp_path, tiny_scene):
    """Frame 0 is at rest: on the run's common scale it must be at the bottom of the colour map."""
    from pxr import Usd, UsdGeom

    from wcut.usd import stress_colors

    scene = load_scene(tiny_scene)
    result = run_scene(scene, tmp_path / "anim.usda", frames=3, progress=False)
    stage = Usd.Stage.Open(str(result.output))
    mesh = next(p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh))
    colors = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("displayColor")
    lowest = stress_colors([0.0, 1.0])[0]
    first = np.asarray(colors.Get(Usd.TimeCode(0)))
    last = np.asarray(colors.Get(Usd.TimeCode(3)))
    np.testing.assert_allclose(first, np.broadcast_to(lowest, first.shape), atol=0.02)
    assert np.abs(last - lowest).max() > 0.2  # the clamped, sagging beam is stressed


@pytest.mark.parametrize("extra, key", [
    ("[solver]\ncg_iterations = 100000000\n", "solver.cg_iterations"),
    ("[solver]\nrotation_iterations = 0\n", "solver.rotation_iterations"),
    ("[solver]\ndt = 1e-12\n", "solver.dt"),
    ("[solver]\ncg_tolerance = -1.0\n", "solver.cg_tolerance"),
    ("[simulation]\nfps = 1e-9\n", "solver.dt"),
    ("[material]\npoisson_ratio = 0.5\n", "material.poisson_ratio"),
    ("[material]\ndensity = 0.0\n", "material.density"),
    ("[damping]\nrayleigh_mass = -1.0\n", "damping.rayleigh_mass"),
    ("[[attachments]]\nvertex = 3\ntarget = [0, 0, 0]\nstiffness = -1.0\n", "attachments[0].stiffness"),
])
def test_values_out_of_range_name_their_key(tmp_path, write_scene, extra, key):
    message = _scene_error(tmp_path, write_scene, MINIMAL + extra)
    assert key in message


def test_fixed_index_outside_the_mesh_names_its_key(tmp_path, write_scene):
    text = MINIMAL + "[constraints]\nfixed_indices = [0, 45]\n"
    with pytest.raises(SceneError, match=r"constraints.fixed_indices: vertex 45 is not a vertex"):
        build_model(load_scene(write_scene(tmp_path, text)))


@pytest.mark.parametrize("output", ["anim.txt", "missing_parent_is_fine/anim.usdc", "blocked/anim.usdc"])
def test_output_is_checked_before_the_simulation(tmp_path, tiny_scene, monkeypatch, output):
    import wcut.scene

    (tmp_path / "blocked").write_text("a file where a directory is needed")

    def no_simulation(*args, **kwargs):
        raise AssertionError("the model was built before the output was checked")

    monkeypatch.setattr(wcut.scene, "build_model", no_simulation)
    if output.startswith("missing_parent_is_fine"):
        with pytest.raises(AssertionError, match="model was built"):  # the check passed
            run_scene(load_scene(tiny_scene), tmp_path / output, frames=1, progress=False)
        assert not (tmp_path / "missing_parent_is_fine").exists()  # and created nothing
    else:
        with pytest.raises(WcutError):
            run_scene(load_scene(tiny_scene), tmp_path / output, frames=1, progress=False)


BLADE = """
[cut]
method = "paulus"
epsilon = 0.2
frames = [1, 5]
blade = [[[0.101, -0.01, 0.07], [0.101, 0.07, 0.07]], [[0.101, -0.01, -0.02], [0.101, 0.07, -0.02]]]
"""


def test_scene_blade_cuts_and_keeps_running(tmp_path, write_scene):
    from conftest import TINY_SCENE

    from wcut.scene import load_scene, run_scene

    path = write_scene(tmp_path, TINY_SCENE + BLADE, "blade.toml")
    result = run_scene(load_scene(path), tmp_path / "blade.usdc", frames=8, progress=False)
    assert result.cut_events >= 1
    assert result.elements >= 80 and result.nodes > 45  # snapped onto the node plane, then split


@pytest.mark.parametrize("text, key", [
    ('[cut]\nframes = [1]\nblade = [[[0,0,0],[1,0,0]]]', "cut.frames"),
    ('[cut]\nmethod = "laser"\nframes = [1, 2]\nblade = [[[0,0,0],[1,0,0]], [[0,0,1],[1,0,1]]]', "cut.method"),
    ('[cut]\nframes = [1, 2]\nblade = [[[0,0,0],[1,0,0]]]', "cut.blade"),
    ('[cut]\nframes = [3, 2]\nblade = [[[0,0,0],[1,0,0]], [[0,0,1],[1,0,1]]]', "cut.frames"),
    ('[cut]\nepsilon = 0.9\nframes = [1, 2]\nblade = [[[0,0,0],[1,0,0]], [[0,0,1],[1,0,1]]]', "cut.epsilon"),
    ('[cut]\nknife = 1', "cut.knife"),
])
def test_bad_cut_section_names_the_key(tmp_path, write_scene, text, key):
    from conftest import TINY_SCENE

    from wcut.errors import SceneError
    from wcut.scene import load_scene

    path = write_scene(tmp_path, TINY_SCENE + "\n" + text + "\n", "bad.toml")
    with pytest.raises(SceneError, match=key.replace(".", r"\.")):
        load_scene(path)


SAGGING_CUT = """
name = "sag_cut"

[mesh]
generator = "beam"
cells = [12, 3, 3]
size = [0.16, 0.04, 0.04]

[material]
density = 1000.0
youngs_modulus = 3.0e5
poisson_ratio = 0.35

[damping]
rayleigh_stiffness = 0.005

[constraints]
fixed_boxes = [[[-0.001, -1.0, -1.0], [0.001, 1.0, 1.0]]]

[solver]
dt = 0.01
cg_iterations = 40

[simulation]
fps = 30

[cut]
method = "paulus"
epsilon = 0.1
frames = [10, 40]
blade = [[[0.081, -0.01, 0.05], [0.081, 0.05, 0.05]], [[0.081, -0.01, -0.01], [0.081, 0.05, -0.01]]]
"""


def test_scene_blade_cuts_a_sagging_beam_in_two(tmp_path, write_scene):
    """A cantilever sags under gravity while a blade goes down through it: the blade is mapped
    to the rest configuration each frame, so the wound follows the moving material and the
    beam comes apart into its clamped half and a free half, which falls."""
    from pxr import Usd, UsdGeom

    from wcut.topology import check_topology, connected_components

    from conftest import run_recording_blade

    path = write_scene(tmp_path, SAGGING_CUT, "sag_cut.toml")
    result, blade = run_recording_blade(load_scene(path), tmp_path / "sag_cut.usdc", frames=45)
    assert result.cut_events >= 2
    topo = blade.topology
    check_topology(topo, 0.16 * 0.04 * 0.04)
    mesh = topo.to_mesh()
    assert (result.nodes, result.elements) == (mesh.vertex_count, mesh.tet_count)
    labels = connected_components(mesh)
    assert labels.max() == 1
    # two halves, not a sliver broken off (a cut that stops short can leave one element loose)
    x = mesh.vertices[mesh.tets].mean(axis=1)[:, 0]
    clamped, free = set(labels[x < 0.07]), set(labels[x > 0.095])
    assert len(clamped) == len(free) == 1 and clamped != free
    volumes = mesh.volumes()
    assert min(volumes[labels == 0].sum(), volumes[labels == 1].sum()) > 0.4 * volumes.sum()
    # the free half falls: in the last frame it is far below the sagging clamped half
    stage = Usd.Stage.Open(str(result.output))
    points = np.array(UsdGeom.Mesh(stage.GetPrimAtPath("/World/sag_cut")).GetPointsAttr().Get(45))
    assert points[:, 2].min() < -0.1


def test_quadratic_scene_runs_and_writes_the_tessellated_surface(tmp_path, write_scene, small_beam):
    """mesh.order = 2: a linear file gets edge nodes, a tetra10 file is used as is, and every
    curved face is written as 4**subdivision triangles."""
    from pxr import Usd, UsdGeom

    from wcut.quadratic import to_quadratic

    (tmp_path / "meshes").mkdir()
    small_beam.save(tmp_path / "meshes" / "beam.vtu")
    to_quadratic(small_beam).save(tmp_path / "meshes" / "beam10.vtu")
    faces = len(small_beam.boundary().triangles)
    for mesh_file, level in (("beam.vtu", 1), ("beam10.vtu", 2)):
        text = (f'[mesh]\npath = "meshes/{mesh_file}"\norder = 2\n[output]\nsubdivision = {level}\n'
                "[constraints]\nfixed_boxes = [[[-1, -1, -1], [1e-9, 1, 1]]]\n[simulation]\nduration = 0.2\n")
        scene = load_scene(write_scene(tmp_path, text, f"p2_{level}.toml"))
        mesh = build_mesh(scene)
        assert mesh.order == 2 and mesh.tet_count == small_beam.tet_count
        out = tmp_path / f"p2_{level}.usda"
        result = run_scene(scene, out, progress=False)
        assert result.nodes == small_beam.vertex_count + len(small_beam.edges())
        assert validate_usd(out) == []
        stage = Usd.Stage.Open(str(out))
        (prim,) = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
        counts = UsdGeom.Mesh(prim).GetFaceVertexCountsAttr().Get(Usd.TimeCode(1))
        assert len(counts) == faces * 4 ** level
        points = np.asarray(UsdGeom.Mesh(prim).GetPointsAttr().Get(Usd.TimeCode(result.frames)))
        assert np.isfinite(points).all() and points[:, 2].min() < -1e-4  # it sags under gravity
