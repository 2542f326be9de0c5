"""tools/cuda_compile.py: the kernel modules compile for CUDA (NVRTC, PTX) without a GPU."""

from __future__ import annotations

from conftest import load_tool

#: the modules that compile in seconds; tet_p1, tet_p2, tri_p2 and topology take 5-60 s each,
#: so the test leaves them to the tool's full run (README)
QUICK = ["attachments", "bending", "cg", "cholesky", "cut_detection", "implicit_euler", "partial_sums", "raycast",
         "point_location", "rotation", "surface_query"]


def test_the_quick_kernel_modules_compile_for_sm_90(capsys):
    tool = load_tool("cuda_compile")
    assert set(QUICK) < set(tool.kernel_modules()) and 90 in tool.nvrtc_archs()
    assert tool.main(QUICK) == 0
    out = capsys.readouterr().out
    assert all(f"{name} " in out and "FAILED" not in out for name in QUICK)


def test_failures_and_bad_requests_are_reported(capsys, monkeypatch):
    tool = load_tool("cuda_compile")
    assert tool.main(["no_such_module"]) == 2
    assert tool.main(["cg", "--arch", "35"]) == 2
    assert "sm_35" in capsys.readouterr().err

    def broken(name, arch, directory):
        raise RuntimeError("NVRTC: error: identifier is undefined")

    monkeypatch.setattr(tool, "compile_for_cuda", broken)
    assert tool.main(["cg", "bending"]) == 1
    captured = capsys.readouterr()
    assert captured.out.count("FAILED") == 2 and "2 of 2 modules" in captured.err
