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
    # the solver's defaults: one step per frame, a relative residual and a safety cap
    assert scene.solver["cg_iterations"] is None and scene.solver["dt"] is None
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


def test_solver_cpu_threads_reach_the_solver(tmp_path, write_scene):
    from wcut.scene import Simulation

    default = Simulation(load_scene(write_scene(tmp_path, MINIMAL)))
    assert default.solver.cpu_threads == 1  # a small model stays on one thread
    pinned = Simulation(load_scene(write_scene(tmp_path, MINIMAL + "[solver]\ncpu_threads = 2\n", "two.toml")))
    assert pinned.solver.cpu_threads == 2


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
        ("[solver]\ncpu_threads = 0\n", "solver.cpu_threads", "1 to 8 threads"),
        ("[solver]\ncpu_threads = 2.0\n", "solver.cpu_threads", "expected an integer"),
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
         "attachments[0]", "exactly one of point, vertex and box"),
        ("[[attachments]]\ntarget = [0, 0, 0]\nstiffness = 10.0\n", "attachments[0]",
         "exactly one of point, vertex and box"),
        ("[[attachments]]\nbox = [[0, 0, 0], [1, 1, 1]]\ntarget = [0, 0, 0]\nstiffness = 10.0\n",
         "attachments[0].target", "rest position"),
        ("[[attachments]]\nvertex = 3\ntarget = [0, 0, 0]\nstiffness = 1.0\nvelocity = 2\n",
         "attachments[0].velocity", "three numbers"),
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
    ("[solver]\nrotation_stiffness = 1\n", "solver.rotation_stiffness"),
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

    monkeypatch.setattr(wcut.scene, "_build", no_simulation)
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


def test_scene_blade_with_improvement_keeps_running_and_its_worst_element_better(tmp_path, write_scene):
    """[cut] improve = true: the blade's cutter improves the elements after each frame's cut;
    the run goes on through the cut, and its worst element is better than without."""
    from conftest import TINY_SCENE

    from wcut.mesh import dihedral_angles
    from wcut.scene import Simulation, load_scene

    worst = []
    for improve in ("false", "true"):
        # no snapping: the blade passes 1 mm from a plane of nodes and leaves slivers
        text = TINY_SCENE + BLADE.replace("epsilon = 0.2", f"epsilon = 0.0\nimprove = {improve}")
        sim = Simulation(load_scene(write_scene(tmp_path, text, f"blade_{improve}.toml")))
        assert sim.blade.cutter.improve == (improve == "true")
        angles = []
        for _ in range(8):
            sim.advance()
            angles.append(float(dihedral_angles(sim.model.mesh.vertices, sim.model.mesh.tets).min()))
        assert sim.cut_events >= 1
        worst.append(min(angles))
    assert worst[1] > worst[0]  # (0.33 and 0.44 degrees)


@pytest.mark.parametrize("text, key", [
    ('[cut]\nimprove = 2\nframes = [1, 2]\nblade = [[[0,0,0],[1,0,0]], [[0,0,1],[1,0,1]]]', "cut.improve"),
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


# ---------------------------------------------------------------------------------------------
# thin shells: sheet generators, triangle files, attachments on a sheet, a sheet's run

#: a 0.2 m square sheet of 4 x 4 cells (32 triangles, 81 nodes) hung by its two corners at y = 0.2
SHEET = """
name = "sheet"

[mesh]
generator = "rectangle_sheet"
cells = [4, 4]
size = [0.2, 0.2]
thickness = 1e-3

[material]
youngs_modulus = 1.0e6

[constraints]
fixed_boxes = [[[-0.001, 0.199, -1.0], [0.001, 0.201, 1.0]], [[0.199, 0.199, -1.0], [0.201, 0.201, 1.0]]]

[solver]
dt = 0.01
cg_iterations = 30

[simulation]
duration = 0.1
fps = 30
"""


def test_sheet_scene_runs_to_a_valid_animation(tmp_path, write_scene):
    from pxr import Usd, UsdGeom

    scene = load_scene(write_scene(tmp_path, SHEET, "sheet.toml"))
    assert scene.mesh["order"] == 2 and scene.mesh["pattern"] == "alternate" and scene.mesh["thickness"] == 1e-3
    out = tmp_path / "sheet.usda"
    result = run_scene(scene, out, frames=3, progress=False)
    assert (result.frames, result.elements, result.nodes) == (3, 32, 81)
    assert validate_usd(out) == []
    stage = Usd.Stage.Open(str(out))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/sheet"))
    assert len(mesh.GetFaceVertexCountsAttr().Get(0)) == 32 * 4 ** 2  # output.subdivision = 2
    rest = np.array(mesh.GetPointsAttr().Get(0))
    last = np.array(mesh.GetPointsAttr().Get(3))
    hung = np.isclose(rest[:, 1], 0.2) & (np.isclose(rest[:, 0], 0.0) | np.isclose(rest[:, 0], 0.2))
    assert hung.sum() == 2 and np.allclose(last[hung], rest[hung], atol=1e-7)
    assert np.isfinite(last).all() and last[:, 2].min() < -1e-3  # the free edge falls
    colors = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("displayColor")
    assert np.ptp(np.asarray(colors.Get(Usd.TimeCode(3))), axis=0).max() > 0.05  # stress colours vary


def test_shell_von_mises_of_a_uniform_stretch(tmp_path, write_scene):
    """vertex_von_mises of a sheet stretched by 1 % along x and held along y: the plane stress
    sigma_xx = E eps / (1 - nu^2), sigma_yy = nu sigma_xx, at every node."""
    from wcut.stress import vertex_von_mises

    scene = load_scene(write_scene(tmp_path, SHEET, "sheet.toml"))
    model, _, _ = build_model(scene)
    state = model.state()
    q = model.mesh.vertices.copy()
    q[:, 0] *= 1.01
    state.particle_q.assign(q.astype(np.float32))
    E, nu = 1.0e6, 0.3
    sxx = E * 0.01 / (1 - nu ** 2)
    syy = nu * sxx
    expected = np.sqrt(sxx ** 2 - sxx * syy + syy ** 2)
    vm = vertex_von_mises(model, state)
    assert vm.shape == (81,)
    np.testing.assert_allclose(vm, expected, rtol=2e-3)
    assert np.abs(vertex_von_mises(model, model.state())).max() < 1e-3 * expected  # at rest


@pytest.mark.parametrize("mesh_table, triangles, corners, generate", [
    ('generator = "rectangle_sheet"\ncells = [3, 2]\nsize = [0.3, 0.1]\norigin = [1, 2, 3]\npattern = "right"',
     12, 12, lambda: wcut.rectangle_sheet(3, 2, (0.3, 0.1), origin=(1, 2, 3), pattern="right")),
    ('generator = "l_shape_sheet"\ncells = [4, 4]\nsize = [0.2, 0.2]',
     24, 21, lambda: wcut.l_shape_sheet(2, 0.2)),
    ('generator = "l_shape_sheet"', 96, 65, lambda: wcut.l_shape_sheet(4, 0.2)),
    ('generator = "precut_sheet"\ncells = [4, 4]\nsize = [0.2, 0.2]',  # default notch: half the width
     32, 25 + 2, lambda: wcut.precut_sheet(4, 4, (0.2, 0.2), 0.1)),
    ('generator = "precut_sheet"\ncells = [6, 4]\nsize = [0.3, 0.2]\nnotch_length = 0.2\npattern = "right"',
     48, 35 + 4, lambda: wcut.precut_sheet(6, 4, (0.3, 0.2), 0.2, pattern="right")),
])
def test_sheet_generators_build_shell_meshes(tmp_path, write_scene, mesh_table, triangles, corners, generate):
    mesh = build_mesh(load_scene(write_scene(tmp_path, f"[mesh]\n{mesh_table}\n")))
    assert isinstance(mesh, wcut.ShellMesh)
    assert mesh.triangle_count == triangles and len(mesh.corner_ids) == corners
    expected = generate()
    assert np.array_equal(mesh.triangles, expected.triangles) and np.allclose(mesh.vertices, expected.vertices)


@pytest.mark.parametrize("mesh_table, key, words", [
    ('generator = "disc_sheet"', "mesh.generator", "unknown generator 'disc_sheet'"),
    ('generator = "beam"\nthickness = 1e-3', "mesh.thickness", "only for shells"),
    ('generator = "rectangle_sheet"\nthickness = -1e-3', "mesh.thickness", "must be positive"),
    ('generator = "rectangle_sheet"\ncells = [4, 4, 4]', "mesh.cells", "two integers [nx, ny]"),
    ('generator = "rectangle_sheet"\ncells = [4]', "mesh.cells", "two integers [nx, ny]"),
    ('generator = "rectangle_sheet"\ncells = [4, 0]', "mesh.cells", "at least one cell"),
    ('generator = "rectangle_sheet"\nsize = [0.2, 0.2, 0.2]', "mesh.size", "two lengths"),
    ('generator = "rectangle_sheet"\norder = 1', "mesh.order", "expected 2 or no mesh.order"),
    ('generator = "rectangle_sheet"\npattern = "left"', "mesh.pattern", "'alternate', 'right'"),
    ('generator = "rectangle_sheet"\ntets_per_hex = 6', "mesh.tets_per_hex", "only for the beam"),
    ('generator = "rectangle_sheet"\nnotch_length = 0.1', "mesh.notch_length", "only for generator = 'precut_sheet'"),
    ('generator = "beam"\npattern = "right"', "mesh.pattern", "only for the sheet generators"),
    ('generator = "l_shape_sheet"\ncells = [3, 3]', "mesh.cells", "two equal even integers"),
    ('generator = "l_shape_sheet"\ncells = [4, 6]', "mesh.cells", "two equal even integers"),
    ('generator = "l_shape_sheet"\nsize = [0.2, 0.3]', "mesh.size", "two equal lengths"),
    ('generator = "precut_sheet"\ncells = [4, 5]', "mesh.cells", "even ny"),
    ('generator = "precut_sheet"\nsize = [0.2, 0.2]\nnotch_length = 0.2', "mesh.notch_length", "1..7 cells"),
    ('generator = "precut_sheet"\nsize = [0.2, 0.2]\nnotch_length = 0.01', "mesh.notch_length", "rounds to 0 cells"),
])
def test_bad_sheet_keys_name_the_key(tmp_path, write_scene, mesh_table, key, words):
    message = _scene_error(tmp_path, write_scene, f"[mesh]\n{mesh_table}\n")
    assert f"{key}:" in message and words in message, message


def test_triangle_files_are_shells(tmp_path, write_scene):
    """A file of triangle6 or triangle cells (no tetrahedra) is a ShellMesh; fixed_indices and
    vertex attachments use the file's numbering; mesh.order must be 2 or absent."""
    sheet = wcut.rectangle_sheet(2, 2, size=(0.1, 0.1))
    sheet.save(tmp_path / "sheet6.vtu")
    meshio.write(tmp_path / "sheet3.vtu", meshio.Mesh(sheet.vertices[:9], [("triangle", sheet.triangles[:, :3])]))
    for name in ("sheet6.vtu", "sheet3.vtu"):
        text = (f'[mesh]\npath = "{name}"\nthickness = 2e-3\n[constraints]\nfixed_indices = [0, 2]\n'
                "[[attachments]]\nvertex = 8\ntarget = [0.1, 0.1, 0.05]\nstiffness = 1.0\n")
        scene = load_scene(write_scene(tmp_path, text))
        mesh = build_mesh(scene)
        assert isinstance(mesh, wcut.ShellMesh) and mesh.triangle_count == 8 and mesh.vertex_count == 25
        model, _, _ = build_model(scene, mesh=mesh)
        assert model.tri_count == 8 and np.allclose(model.tri_thickness.numpy(), 2e-3)
        assert np.flatnonzero(model.particle_fixed.numpy()).tolist() == [0, 2]
        assert model.attachment_indices.numpy()[0, 0] == 8
    scene = load_scene(write_scene(tmp_path, '[mesh]\npath = "sheet6.vtu"\norder = 1\n', "order1.toml"))
    with pytest.raises(SceneError, match=r"^order1\.toml: mesh\.order: sheet6\.vtu holds triangles"):
        build_mesh(scene)  # the file says it is a shell, so the check is made once it is read


def test_thickness_for_a_tetrahedral_file_names_the_key(tmp_path, write_scene, small_beam):
    small_beam.save(tmp_path / "beam.vtu")
    scene = load_scene(write_scene(tmp_path, '[mesh]\npath = "beam.vtu"\nthickness = 1e-3\n'))
    with pytest.raises(SceneError, match=r"mesh\.thickness: only for shells, and beam\.vtu holds tetrahedra"):
        build_mesh(scene)


def test_attachment_points_on_a_sheet():
    """A point in a corner triangle gets its barycentric weights; a point off the sheet's plane
    is projected onto it; a point beyond the sheet's edge is held at the edge."""
    from wcut.model import Attachments

    sheet = wcut.rectangle_sheet(4, 4, size=(0.2, 0.2))
    t = 5
    corners = sheet.triangles[t, :3]
    w = np.array([0.2, 0.3, 0.5])
    inside = w @ sheet.vertices[corners]
    points = [inside, inside + [0.0, 0.0, 0.03], [-0.05, 0.125, 0.01]]
    attached = Attachments.at_points(sheet, points, 7.0)
    assert attached.indices.shape == (3, 4) and np.allclose(attached.stiffness, 7.0)
    for s in (0, 1):
        assert attached.indices[s].tolist() == corners.tolist() + [corners[0]]
        np.testing.assert_allclose(attached.weights[s], [*w, 0.0], atol=1e-12)
    assert np.allclose(attached.weights.sum(axis=1), 1.0) and np.all(attached.weights >= 0.0)
    edge = np.einsum("j,jk->k", attached.weights[2], sheet.vertices[attached.indices[2]])
    assert edge[0] == pytest.approx(0.0, abs=1e-12) and edge[2] == 0.0 and 0.1 <= edge[1] <= 0.15


def test_point_attachment_and_forces_on_a_sheet_scene(tmp_path, write_scene):
    text = SHEET + (
        "[[attachments]]\npoint = [0.07, 0.12, 0.02]\ntarget = [0.07, 0.12, 0.1]\nstiffness = 3.0\n"
        "[[loads.force]]\nbox = [[-1, -0.001, -1], [1, 0.001, 1]]\ntotal = [0.0, 0.0, -0.9]\n"
    )
    scene = load_scene(write_scene(tmp_path, text, "sheet.toml"))
    mesh = build_mesh(scene)
    model, control, forces = build_model(scene, mesh=mesh)
    assert np.allclose(model.attachment_rest_points.numpy(), [[0.07, 0.12, 0.0]], atol=1e-7)
    assert np.allclose(control.attachment_target.numpy(), [[0.07, 0.12, 0.1]])
    edge = mesh.vertices_in_box((-1, -0.001, -1), (1, 0.001, 1))
    assert len(edge) == 9  # 5 corners and 4 edge nodes along y = 0
    assert np.allclose(forces[edge], [0.0, 0.0, -0.1]) and np.allclose(forces.sum(axis=0), [0.0, 0.0, -0.9])


def test_a_blade_does_not_cut_a_shell(tmp_path, write_scene):
    text = SHEET + ("[cut]\nframes = [1, 2]\n"
                    "blade = [[[0.1, -0.1, 0.1], [0.1, 0.3, 0.1]], [[0.1, -0.1, -0.1], [0.1, 0.3, -0.1]]]\n")
    with pytest.raises(SceneError, match="cut: a blade cuts solids only"):
        run_scene(load_scene(write_scene(tmp_path, text, "sheet.toml")), tmp_path / "x.usda", progress=False)


def test_box_attachments_hold_every_vertex_and_move_at_their_velocity(tmp_path, write_scene):
    """A box grabs each of its vertices at its rest position; with a velocity the targets move
    v t: a stiffly held free edge follows them (frame 3 at 30 fps: 0.1 s, 1 mm at 1 cm/s)."""
    from wcut.scene import build_model

    text = SHEET + ("[[attachments]]\nbox = [[-1, -0.001, -1], [1, 0.001, 1]]\nstiffness = 1.0e4\n"
                    "velocity = [0.0, -0.01, 0.0]\n")
    text = text.replace("dt = 0.01", "dt = 0.002")
    scene = load_scene(write_scene(tmp_path, text, "sheet.toml"))
    model, control, _ = build_model(scene)
    held = model.mesh.vertices_in_box([-1, -0.001, -1], [1, 0.001, 1])
    assert len(held) == 9 and model.attachment_count == 9
    assert np.allclose(control.attachment_target.numpy(), model.mesh.vertices[held])
    from pxr import Usd, UsdGeom

    out = tmp_path / "sheet.usdc"
    run_scene(scene, out, frames=3, progress=False)
    stage = Usd.Stage.Open(str(out))  # kept: its prims expire with it
    points = UsdGeom.Mesh(stage.GetPrimAtPath("/World/sheet")).GetPointsAttr()
    rest, last = np.array(points.Get(0)), np.array(points.Get(3))
    edge = np.isclose(rest[:, 1], 0.0)
    assert (last[edge, 1] - rest[edge, 1]) == pytest.approx(-0.001, abs=1e-4)


FRACTURE = """
[fracture]
strength = 1.0e4
variant = "material"
max_cracks_per_step = 2
"""


def test_fracture_section_reaches_the_shell_fracture(tmp_path, write_scene, monkeypatch):
    """A sheet hung by two corners under gravity, weak enough to tear: [fracture] builds a
    ShellFracture with its settings, the run tears the sheet (advances recorded, the mesh grows
    nodes) and stays finite."""
    import wcut.scene as scene_module

    scene = load_scene(write_scene(tmp_path, SHEET + FRACTURE, "sheet.toml"))
    assert scene.fracture == {"strength": 1.0e4, "variant": "material", "max_cracks_per_step": 2,
                              "smoothing": "max", "direction_smoothing": "weighted", "min_quality": None}
    made = []
    build = scene_module._fracture
    monkeypatch.setattr(scene_module, "_fracture", lambda settings, mesh: made.append(build(settings, mesh))
                        or made[-1])
    result = run_scene(scene, tmp_path / "sheet.usda", frames=3, progress=False)
    fracture = made[0]
    assert (fracture.strength, fracture.variant, fracture.max_cracks_per_step) == (1.0e4, "material", 2)
    assert result.crack_events == len(fracture.events) > 0 and result.nodes > 81
    steps = [e.step for e in fracture.events]
    assert max(steps.count(s) for s in set(steps)) <= 2


@pytest.mark.parametrize(
    "text, key, words",
    [
        ("[fracture]\nvariant = 'none'\n", "fracture.strength", "missing"),
        ("[fracture]\nstrength = -1.0\n", "fracture.strength", "positive"),
        ("[fracture]\nstrength = 1.0\nvariant = 'snap'\n", "fracture.variant", "unknown variant"),
        ("[fracture]\nstrength = 1.0\nmax_cracks_per_step = 0\n", "fracture.max_cracks_per_step", "1.."),
        ("[fracture]\nstrength = 1.0\nsmoothing = 'mean'\n", "fracture.smoothing", "'max' or 'weighted'"),
        ("[fracture]\nstrength = 1.0\nmin_quality = 1.5\n", "fracture.min_quality", "[0, 1)"),
        ("[fracture]\nstrength = 1.0\nspeed = 1\n", "fracture.speed", "unknown key"),
    ],
)
def test_bad_fracture_section_names_the_key(tmp_path, write_scene, text, key, words):
    message = _scene_error(tmp_path, write_scene, SHEET + text)
    assert f"{key}:" in message and words in message, message


def test_fracture_of_a_solid_is_refused(tmp_path, tiny_scene):
    scene = load_scene(tiny_scene)
    scene.fracture = {"strength": 1.0, "variant": "none", "max_cracks_per_step": 1, "smoothing": "max",
                      "direction_smoothing": "weighted", "min_quality": None}
    with pytest.raises(SceneError, match="fracture: fracture is simulated on shells only"):
        run_scene(scene, tmp_path / "x.usda", progress=False)


def test_keyframed_attachments_move_their_targets_and_hold_after_the_last(tmp_path, write_scene):
    from wcut.scene import Simulation, load_scene

    scene = load_scene(write_scene(tmp_path, TINY_WITH_KEYS))
    sim = Simulation(scene)
    start = sim.control.attachment_target.numpy().copy()
    seen = []
    for _ in range(6):  # 30 fps, frames end at 1/30 .. 6/30 s
        sim.advance()
        seen.append(sim.control.attachment_target.numpy() - start)
    # keys: 0 s -> 0, 0.1 s -> +2 cm in z, 0.2 s -> back to +1 cm; held after
    np.testing.assert_allclose([o[:, 2].mean() for o in seen], [0.02 / 3, 0.04 / 3, 0.02, 0.05 / 3, 0.04 / 3, 0.01],
                               atol=1e-6)
    np.testing.assert_allclose(np.concatenate(seen)[:, :2], 0.0, atol=1e-7)


@pytest.mark.parametrize("keys, message", [("[[0.0, 0, 0, 0]]", "at least two rows"),
                                           ("[[0.1, 0, 0, 0], [0.1, 0, 0, 1]]", "increase"),
                                           ("[[0.0, 0, 0], [0.1, 0, 0, 1]]", r"keyframes\[0\]")])
def test_bad_keyframes_name_the_key(tmp_path, write_scene, keys, message):
    from wcut.scene import load_scene

    with pytest.raises(wcut.SceneError, match=message):
        load_scene(write_scene(tmp_path, TINY_WITH_KEYS.replace(
            "keyframes = [[0.0, 0, 0, 0], [0.1, 0, 0, 0.02], [0.2, 0, 0, 0.01]]", f"keyframes = {keys}")))


TINY_WITH_KEYS = """
[mesh]
generator = "beam"
cells = [4, 2, 2]
size = [0.2, 0.05, 0.05]

[constraints]
fixed_boxes = [[[-0.001, -1.0, -1.0], [0.001, 1.0, 1.0]]]

[[attachments]]
box = [[0.199, -1.0, -1.0], [0.201, 1.0, 1.0]]
stiffness = 100.0
keyframes = [[0.0, 0, 0, 0], [0.1, 0, 0, 0.02], [0.2, 0, 0, 0.01]]

[solver]
dt = 0.0333334

[simulation]
duration = 0.2
fps = 30
"""


def test_a_cut_scene_on_two_threads_follows_one_thread():
    """beam_cut rebuilds its model and solver at every frame that cuts; with the element kernels split
    over two threads each time it cuts the same elements and ends where one thread ends (with
    the conjugate gradient run to a tolerance of 1e-6: the rotated factor makes each iteration
    reduce the residual tenfold, so a rounding difference that stops it one iteration apart
    moves little)."""
    from wcut.scene import Simulation

    ends = []
    for threads in (1, 2):
        scene = load_scene(REPO / "scenes" / "beam_cut.toml")
        scene.solver.update(cpu_threads=threads, cg_tolerance=1e-6)
        simulation = Simulation(scene)
        for _ in range(25):  # the blade first changes the mesh at frames 23 and 24
            simulation.advance()
        assert simulation.solver.cpu_threads == threads
        ends.append((simulation.model.tet_count, simulation.state.particle_q.numpy()))
    (count_one, one), (count_two, two) = ends
    assert count_one == count_two > 371  # cut: elements were added
    extent, before = np.ptp(one, axis=0).max(), build_mesh(load_scene(REPO / "scenes" / "beam_cut.toml")).vertex_count
    assert np.abs(two[:before] - one[:before]).max() < 1e-6 * extent
    # a vertex the blade inserts lies where an edge crosses it, which amplifies the rounding of
    # the edge's ends when the edge is nearly parallel to the blade (measured 3.7e-7 m)
    assert np.abs(two[before:] - one[before:]).max() < 1e-5 * extent
