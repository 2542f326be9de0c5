"""The benchmark code runs and reports sane, complete records (speed itself is measured by
``wcut bench``, never asserted in tests)."""

import json

from wcut.bench import run_benchmarks

KEYS = {"name", "tets", "nodes", "step_ms", "reference_step_ms", "speedup_vs_reference", "rotation_ns_per_element",
        "matvec_ns_per_element"}


def test_benchmark_on_a_small_beam_writes_the_contract_json(tmp_path, capsys):
    path = tmp_path / "bench.json"
    result = run_benchmarks(path, quick=True, progress=False, scenes=(("tiny", (2, 2, 4), (0.02, 0.02, 0.04)),))
    written = json.loads(path.read_text())
    assert written == json.loads(json.dumps(result))
    (record,) = written["scenes"]
    assert KEYS <= set(record)
    assert record["tets"] == 5 * 2 * 2 * 4 and record["nodes"] == 3 * 3 * 5
    for key in KEYS - {"name", "tets", "nodes"}:
        assert record[key] > 0, key
    assert abs(record["speedup_vs_reference"] - record["reference_step_ms"] / record["step_ms"]) < 0.05 * \
        record["speedup_vs_reference"] + 0.01
    assert "tiny" in capsys.readouterr().out


def test_benchmark_checks_its_output_before_running(tmp_path, monkeypatch):
    import pytest

    import wcut.bench
    from wcut.errors import ExportError

    (tmp_path / "blocked").write_text("a file where a directory is needed")
    monkeypatch.setattr(wcut.bench, "bench_scene", lambda *a, **k: pytest.fail("benchmarked before the check"))
    with pytest.raises(ExportError, match="cannot write here"):
        run_benchmarks(tmp_path / "blocked" / "bench.json", progress=False)
