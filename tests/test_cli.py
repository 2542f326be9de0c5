"""Tests of the ``wcut`` command (wcut.cli.main, run in-process) and its installed entry point."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import meshio
import numpy as np
import pytest

import wcut
from wcut.cli import main
from wcut.usd import validate_usd


def _listing(directory: Path) -> list[str]:
    """Every file and directory under ``directory`` (hidden temporary files included)."""
    return sorted(str(p.relative_to(directory)) for p in directory.rglob("*"))


def _fails_with_one_line(capsys, argv, *words) -> str:
    """Run ``wcut argv``: exit status 2, one ``wcut: error:`` line on stderr containing ``words``."""
    assert main(argv) == 2
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("wcut: error: "), lines[0]
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


# ---------------------------------------------------------------------------------------------
# help and version


def test_version(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    assert capsys.readouterr().out.strip() == f"wcut {wcut.__version__}"


def test_version_matches_the_installed_distribution():
    from importlib.metadata import version

    assert version("wcut") == wcut.__version__


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--help"], ["usage: wcut", "run", "bench", "--version"]),
        (["run", "--help"], ["usage: wcut run", "SCENE.toml", "--output", "--frames", "--quiet"]),
        (["bench", "--help"], ["usage: wcut bench", "--json", "--quiet"]),
    ],
)
def test_help(capsys, argv, words):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 0
    out = capsys.readouterr().out
    for word in words:
        assert word in out


def test_no_command_prints_help_and_fails(capsys):
    assert main([]) == 2
    assert "usage: wcut" in capsys.readouterr().out


def test_unknown_command_is_an_argparse_error(capsys):
    with pytest.raises(SystemExit) as info:
        main(["fly"])
    assert info.value.code == 2
    assert "invalid choice" in capsys.readouterr().err


def test_entry_point_is_installed():
    exe = Path(sys.executable).with_name("wcut")
    exe = str(exe) if exe.exists() else shutil.which("wcut")
    assert exe, "the wcut console script is not installed"
    proc = subprocess.run([exe, "--version"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == f"wcut {wcut.__version__}"


# ---------------------------------------------------------------------------------------------
# wcut run


@pytest.mark.parametrize("ext", [".usdc", ".usda"])
def test_run_writes_a_valid_animation(tmp_path, tiny_scene, capsys, ext):
    out = tmp_path / "out" / f"anim{ext}"
    assert main(["run", str(tiny_scene), "-o", str(out), "--frames", "2", "--quiet"]) == 0
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    assert "frames: 2" in lines
    assert any(re.fullmatch(r"mean step: \d+\.\d+ ms \(8 steps\)", line) for line in lines), lines
    assert any(re.fullmatch(r"real-time factor: \d+\.\d\d \(.*\)", line) for line in lines), lines
    assert "nodes: 45" in lines
    assert "elements: 80" in lines
    assert f"wrote {out}" in lines
    assert captured.err == ""  # --quiet: no progress bar
    assert _listing(out.parent) == [out.name]
    assert validate_usd(out) == []


def test_run_default_output_comes_from_the_scene(tmp_path, tiny_scene, write_scene, capsys, monkeypatch):
    text = tiny_scene.read_text() + '\n[output]\npath = "result.usda"\n'
    scene = write_scene(tmp_path, text, "with_output.toml")
    monkeypatch.chdir(tmp_path)
    assert main(["run", str(scene), "--frames", "1", "--quiet"]) == 0
    assert "frames: 1" in capsys.readouterr().out.splitlines()
    assert validate_usd(tmp_path / "result.usda") == []


def _write_flat_mesh(path: Path):
    """A .vtu file meshio reads whose second element is flat (vertex 4 on the edge 1-2)."""
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0.5, 0]], dtype=np.float64)
    meshio.write(path, meshio.Mesh(x, [("tetra", np.array([[0, 1, 2, 3], [1, 2, 3, 4]]))]))


def _write_surface_mesh(path: Path):
    """A .vtu file with quadrilaterals only: neither a solid nor a shell (a triangle file is a shell)."""
    meshio.write(path, meshio.Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]), [("quad", [[0, 1, 2, 3]])]))


@pytest.mark.parametrize(
    "case",
    ["unknown-key", "missing-scene", "bad-extension", "flat-mesh", "surface-mesh", "missing-mesh", "empty-box"],
)
def test_run_bad_input_fails_cleanly(tmp_path, tiny_scene, write_scene, capsys, case):
    out_dir = tmp_path / "out"
    out = out_dir / "anim.usdc"
    scene = tiny_scene
    words: tuple[str, ...]
    if case == "unknown-key":
        scene = write_scene(tmp_path, tiny_scene.read_text().replace("youngs_modulus", "youngs_modulos"), "typo.toml")
        words = ("typo.toml", "material.youngs_modulos", "unknown key")
    elif case == "missing-scene":
        scene = tmp_path / "absent.toml"
        words = (str(scene), "no such scene file")
    elif case == "bad-extension":
        out = out_dir / "anim.txt"
        words = ("anim.txt", "unsupported extension '.txt'")
    elif case in ("flat-mesh", "surface-mesh", "missing-mesh"):
        mesh_text = '[mesh]\npath = "organ.vtu"\n[simulation]\nduration = 0.1\n'
        scene = write_scene(tmp_path, mesh_text, "organ.toml")
        if case == "flat-mesh":
            _write_flat_mesh(tmp_path / "organ.vtu")
            words = ("organ.vtu", "element 1", "degenerate")
        elif case == "surface-mesh":
            _write_surface_mesh(tmp_path / "organ.vtu")
            words = ("organ.vtu", "no tetrahedra")
        else:
            words = (str(tmp_path / "organ.vtu"), "no such file")
    else:  # a fixed box that holds no vertex
        text = tiny_scene.read_text().replace("[[-0.001, -1.0, -1.0], [0.001, 1.0, 1.0]]", "[[5, 5, 5], [6, 6, 6]]")
        scene = write_scene(tmp_path, text, "empty_box.toml")
        words = ("empty_box.toml", "constraints.fixed_boxes[0]", "contains no vertex")
    before = _listing(tmp_path)
    _fails_with_one_line(capsys, ["run", str(scene), "-o", str(out), "--frames", "2", "--quiet"], *words)
    assert not out.exists()
    assert _listing(tmp_path) == before  # no output, no temporary file, no output directory


def test_multi_line_error_messages_are_joined(tmp_path, write_scene, capsys):
    scene = write_scene(tmp_path, '[mesh]\ngenerator = "beam"\ncells = [1, 1, 1]\n[material\n', "broken.toml")
    line = _fails_with_one_line(capsys, ["run", str(scene), "-o", str(tmp_path / "x.usdc")], "not valid TOML")
    assert "  " not in line


@pytest.mark.parametrize("frames", ["0", "-1", "abc", "1.5", ""])
def test_bad_frame_counts_are_rejected_by_argparse(tmp_path, tiny_scene, capsys, frames):
    out = tmp_path / "anim.usdc"
    with pytest.raises(SystemExit) as info:
        main(["run", str(tiny_scene), "-o", str(out), "--frames", frames])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "--frames" in err and "positive integer" in err
    assert not out.exists()


def test_run_requires_a_scene(capsys):
    with pytest.raises(SystemExit) as info:
        main(["run"])
    assert info.value.code == 2
    assert "SCENE.toml" in capsys.readouterr().err


def test_cut_command_writes_mesh_and_report(tmp_path):
    import json

    from wcut.cli import main
    from wcut.mesh import TetMesh, beam

    source = tmp_path / "beam.vtu"
    beam(6, 2, 2, size=(0.3, 0.1, 0.1)).save(source)
    out, report = tmp_path / "cut.vtu", tmp_path / "r.json"
    for method in ("paulus", "bielser", "snap", "delete"):
        assert main(["cut", str(source), "-o", str(out), "--plane", "0.151,0,0,1,0.1,0", "--method", method,
                     "--epsilon", "0.1", "--report", str(report)]) == 0
        data = json.loads(report.read_text())
        assert set(data) >= {"nodes_before", "nodes_after", "elements_before", "elements_after", "cut_elements",
                             "volume_before", "volume_after", "min_dihedral_deg", "components",
                             "min_dihedral_deg_before", "elements_below_1deg", "elements_below_5deg",
                             "min_volume_to_median"}
        assert data["min_dihedral_deg_before"] == pytest.approx(54.7356, abs=1e-4)  # arccos(1/sqrt(3))
        assert data["elements_below_1deg"] <= data["elements_below_5deg"] <= data["elements_after"]
        assert 0 < data["min_volume_to_median"] <= 1
        cut = TetMesh.load(out)
        assert (cut.vertex_count, cut.tet_count) == (data["nodes_after"], data["elements_after"])
        if method in ("paulus", "bielser"):
            assert data["components"] == 2
            assert abs(data["volume_after"] - data["volume_before"]) < 1e-9 * data["volume_before"]


def test_cut_command_order_2(tmp_path):
    """``--order 2``: linear input is made quadratic (straight edges), tetra10 input is cut as
    it is (here the curved organ); the output holds tetra10 cells and the report counts all
    nodes, with volumes by quadrature."""
    import json

    import meshio

    from wcut.cli import main
    from wcut.mesh import beam
    from wcut.quadratic import QuadraticTetMesh

    linear = tmp_path / "beam.vtu"
    beam(6, 2, 2, size=(0.3, 0.1, 0.1)).save(linear)
    organ = Path(__file__).resolve().parents[1] / "scenes" / "meshes" / "organ_p2.vtu"
    for source, plane in ((linear, "0.151,0.05,0.05,1,0.1,0"), (organ, "0.0,0.01,0.005,0.1,1,0.3")):
        out, report = tmp_path / "cut.vtu", tmp_path / "r.json"
        assert main(["cut", str(source), "-o", str(out), "--plane", plane, "--order", "2",
                     "--report", str(report)]) == 0
        data = json.loads(report.read_text())
        assert [block.type for block in meshio.read(out).cells] == ["tetra10"]
        cut = QuadraticTetMesh.load(out)
        assert (cut.vertex_count, cut.tet_count) == (data["nodes_after"], data["elements_after"])
        assert data["order"] == 2 and data["components"] == 2
        assert abs(data["volume_after"] - data["volume_before"]) < 1e-6 * data["volume_before"]
        assert cut.volumes().sum() == pytest.approx(data["volume_after"], rel=1e-12)


def test_cut_command_bad_input_exits_2(tmp_path, capsys):
    from wcut.cli import main
    from wcut.mesh import beam

    source = tmp_path / "beam.vtu"
    beam(2, 2, 2).save(source)
    out = tmp_path / "cut.vtu"
    cases = [(["--plane", "5,0,0,1,0,0"], "misses the mesh"), (["--plane", "1,2"], "six numbers"),
             (["--surface", str(tmp_path / "none.obj")], "none.obj"),
             (["--plane", "5,0,0,1,0,0", "--order", "2"], "misses the mesh")]
    for extra, message in cases:
        assert main(["cut", str(source), "-o", str(out)] + extra) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1
        assert not out.exists()


def test_cut_reads_a_mesh_with_unused_vertices_and_says_so_in_one_line(tmp_path, capsys):
    from wcut.mesh import beam

    mesh = beam(4, 2, 2, size=(0.2, 0.1, 0.1))
    source = tmp_path / "raptor.vtu"
    meshio.write(source, meshio.Mesh(np.vstack([mesh.vertices, [[9.0, 9.0, 9.0]]]), [("tetra", mesh.tets)]))
    out = tmp_path / "cut.vtu"
    assert main(["cut", str(source), "-o", str(out), "--plane", "0.101,0.05,0.05,1,0.1,0"]) == 0
    err = capsys.readouterr().err
    notes = [line for line in err.splitlines() if line.startswith("wcut: note:")]
    assert notes == [f"wcut: note: raptor.vtu: 1 vertices no cell uses are dropped (file indices {mesh.vertex_count})"]
    assert out.exists()


def test_a_plane_cut_that_does_not_separate_exits_2_and_writes_nothing(tmp_path, capsys, monkeypatch):
    """Without the cutter's separation of what the remeshing left joined (a plane through a
    beam of poor elements where splits are refused), ``wcut cut`` says so and writes nothing."""
    from wcut.cut import Cutter
    from wcut.mesh import beam, perturbed

    source = tmp_path / "poor.vtu"
    perturbed(beam(5, 4, 4, size=(0.05, 0.04, 0.04)), 1.0, seed=0).save(source)
    out, report = tmp_path / "cut.vtu", tmp_path / "r.json"
    plane = "0.022739233746429083,0.015395734275277406,0.010819470478723893,0.16021416297716448,-0.818128926665578,0.5522648652001644"
    argv = ["cut", str(source), "-o", str(out), f"--plane={plane}", "--epsilon", "0", "--report", str(report)]
    assert main(argv) == 0 and out.exists()
    out.unlink()
    report.unlink()
    monkeypatch.setattr(Cutter, "_separate", lambda self, plane, stats: None)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "the cut did not separate poor.vtu" in err and "straddle" in err and err.count("\n") == 1
    assert not out.exists() and not report.exists()


def test_the_first_run_on_a_terminal_says_kernels_are_compiling(tmp_path, tiny_scene, capsys, monkeypatch):
    """One line before a command's kernels compile the first time (a marker in Warp's kernel
    cache, named by the kernels' sources, remembers it); nothing the second time."""
    import warp as wp

    monkeypatch.setattr(wp.config, "kernel_cache_dir", str(tmp_path / "cache"))
    (tmp_path / "cache").mkdir()
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    argv = ["run", str(tiny_scene), "-o", str(tmp_path / "a.usda"), "--frames", "1", "--quiet"]
    assert main(argv) == 0
    assert "wcut: compiling kernels, once" in capsys.readouterr().err
    assert main(argv) == 0
    assert "compiling" not in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------
# bad input found by fuzzing the command line: each refused in one line, before any work,
# leaving nothing behind and deleting nothing


def _argparse_fails_with_one_line(capsys, argv, *words) -> None:
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("wcut: error: "), lines
    for word in words:
        assert word in lines[0], lines[0]


@pytest.mark.parametrize("argv, words", [
    (["fly"], ["invalid choice"]),
    (["run"], ["run:", "SCENE.toml"]),
    (["cut", "x.vtu"], ["cut:", "-o/--output"]),
    (["run", "s.toml", "--frames", "0"], ["--frames", "positive integer"]),
])
def test_argparse_errors_are_one_line(capsys, argv, words):
    _argparse_fails_with_one_line(capsys, argv, *words)


AR_SCENE = Path(__file__).resolve().parents[1] / "scenes" / "ar" / "band_control.toml"


def test_synth_refuses_a_directory_of_other_files_and_a_file(tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("years of work")
    _fails_with_one_line(capsys, ["synth", str(AR_SCENE), "-o", str(mine), "--quiet"], "other files than a capture")
    assert (mine / "thesis.tex").read_text() == "years of work"
    file = tmp_path / "notes.txt"
    file.write_text("keep")
    _fails_with_one_line(capsys, ["synth", str(AR_SCENE), "-o", str(file), "--quiet"], "is a file")
    assert file.read_text() == "keep"


@pytest.mark.parametrize("name", ["out.xyz", "out", "out.obj", "out.stl"])
def test_cut_refuses_an_output_format_without_tetrahedra_before_cutting(tmp_path, capsys, monkeypatch, name):
    from wcut.cut import Cutter
    from wcut.mesh import beam

    source = tmp_path / "beam.vtu"
    beam(2, 2, 2).save(source)
    monkeypatch.setattr(Cutter, "cut", lambda *a, **k: pytest.fail("cut before the output was checked"))
    _fails_with_one_line(capsys, ["cut", str(source), "-o", str(tmp_path / name), "--plane", "0.5,0,0,1,0,0"],
                         "cannot write a tetrahedral mesh")
    assert not (tmp_path / name).exists()


def test_cut_takes_a_huge_normal_and_a_negative_first_value(tmp_path, capsys):
    import json

    from wcut.mesh import beam

    source = tmp_path / "beam.vtu"
    beam(4, 2, 2, size=(0.2, 0.1, 0.1), origin=(-0.1, 0.0, 0.0)).save(source)
    out, report = tmp_path / "cut.vtu", tmp_path / "r.json"
    for plane in (["--plane", "-0.011,0,0,1e308,0,0"], ["--plane=-0.011,0,0,1,1e-300,0"]):
        assert main(["cut", str(source), "-o", str(out), *plane, "--report", str(report)]) == 0
        assert json.loads(report.read_text())["components"] == 2


def test_a_report_that_cannot_be_written_leaves_no_mesh(tmp_path, capsys):
    from wcut.mesh import beam

    source = tmp_path / "beam.vtu"
    beam(2, 2, 2).save(source)
    out = tmp_path / "cut.vtu"
    _fails_with_one_line(capsys, ["cut", str(source), "-o", str(out), "--plane", "0.5,0,0,1,0,0",
                                  "--report", "/proc/wcut-report.json"], "cannot write here")
    assert not out.exists()


@pytest.mark.parametrize("extra, words", [
    ("[simulation]\nduration = 1e308\nfps = 30\n", ["simulation", "frames"]),
    ("[simulation]\nduration = 1.0\nfps = 1e308\n", ["simulation", "frames"]),
    ("[loads]\ngravity = [0.0, 0.0, -1e300]\n", ["loads.gravity", "beyond"]),
    ("[mesh]\ngenerator = \"beam\"\ncells = [100000, 100000, 100000]\n", ["mesh.cells", "at most"]),
])
def test_absurd_scene_magnitudes_are_refused_at_once(tmp_path, write_scene, capsys, extra, words):
    text = f'name = "absurd"\n{extra}'
    if "[mesh]" not in extra:
        text += '[mesh]\ngenerator = "beam"\ncells = [2, 1, 1]\nsize = [0.1, 0.05, 0.05]\n'
    path = write_scene(tmp_path, text, "absurd.toml")
    _fails_with_one_line(capsys, ["run", str(path), "-o", str(tmp_path / "x.usdc"), "--quiet"], *words)
    assert not (tmp_path / "x.usdc").exists()
